"""The one-shot commands: arguments checked here, sent to `crawler/<name>/cmd/<verb>`, replies printed.

The checks are pure functions (also used by the live view's mark prompt), so nothing malformed leaves
the laptop; the daemon checks again.
"""

from __future__ import annotations

import json
import sys

from .net import DaemonError, NoAnswer, command, command_key, open_session, status

from ..inspection import (DIRECTIONS, KINDS, M_PER_FT, UNITS, clock_arg, code_arg,  # noqa: F401
                          distance_arg, note_arg)


def level_arg(text) -> float:
    try:
        level = float(text)
    except (TypeError, ValueError):
        raise ValueError(f"{text!r} is not a number (0..1)") from None
    if not 0.0 <= level <= 1.0:
        raise ValueError(f"{level:g} is outside 0..1")
    return level


def mark_args(code: str, clock=None, kind: str = "point", note: str = "") -> dict:
    """The `mark` arguments, checked: {"code", "kind", optional "clock", "note"}."""
    if kind not in KINDS:
        raise ValueError(f"kind {kind!r} must be one of {', '.join(KINDS)}")
    args = {"code": code_arg(code), "kind": kind}
    if clock is not None:
        args["clock"] = clock_arg(clock)
    if note:
        args["note"] = note_arg(note)
    return args


def preset_args(value: float, unit: str | None) -> dict:
    """`preset 12.40` is in the daemon's current unit; with --unit the laptop converts to metres."""
    if unit is None:
        return {"distance": value}
    return {"distance_m": round(value * (M_PER_FT if unit == "ft" else 1.0), 6)}


def request_of(args) -> tuple[str, dict | None]:
    """The verb and its arguments from the parsed command line."""
    verb = args.command
    if verb == "led":
        return verb, {"level": args.level}
    if verb == "preset":
        return verb, preset_args(args.distance, args.unit)
    if verb == "units":
        return verb, {"unit": args.unit}
    if verb == "direction":
        return verb, {"direction": args.direction}
    if verb == "mark":
        kind = "start" if args.start else "finish" if args.finish else "point"
        return verb, mark_args(args.code, args.clock, kind, args.note or "")
    return verb, None


def cmd_control(args, out=None) -> int:
    """reset, led, zero, preset, units, direction, mark, observations, status: ask, print each reply."""
    out = out or sys.stdout
    verb, request = request_of(args)
    session = open_session(args)
    try:
        if verb == "status":
            replies = status(session, args.name, args.timeout)
            key = f"crawler/{args.name}/status"
        else:
            replies = command(session, args.name, verb, request, args.timeout)
            key = command_key(args.name, verb)
    finally:
        session.close()
    if not replies:
        who = "no crawler" if args.name == "*" else f"no crawler named {args.name!r}"
        raise NoAnswer(f"{who} answered {verb} within {args.timeout:g} s on {key} "
                       "(is crawlerd running, and can this laptop reach it? try --connect tcp/IP:7447)")
    errors = []
    indent = 2 if out.isatty() else None
    for name, body in replies:
        if body.get("ok") is False:
            errors.append(f"crawler {name} refused {verb}: {body.get('error', body)}")
        else:
            print(json.dumps(body, indent=indent), file=out, flush=True)
    if errors:
        raise DaemonError("; ".join(errors))
    return 0
