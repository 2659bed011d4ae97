"""Operator commands: parsed off the network, answered by the frame loop, every query ends at once.

A command arrives as a query on `crawler/<name>/cmd/<verb>` with its arguments as selector
parameters (`?level=0.4`) or a JSON object payload. The link's worker thread parses it (a malformed
one is refused there and then) and hands the rest to the frame loop through a CommandQueue; the
loop runs it between two frames, where all state lives, and the worker replies.
"""

from __future__ import annotations

import json
import threading
from concurrent.futures import Future, TimeoutError as FutureTimeout


class CommandRefused(ValueError):
    """A command that cannot be run as asked; the message says why and what would work."""


def parse_arguments(parameters: str, payload: str | None) -> dict:
    """Arguments from selector parameters (`level=0.3;x=1` or `&`-separated) and a JSON object payload."""
    args = {}
    for part in parameters.replace(";", "&").split("&"):
        if part:
            key, _, value = part.partition("=")
            args[key.strip()] = value.strip()
    if payload is not None and payload.strip():
        try:
            body = json.loads(payload)
        except ValueError:
            raise CommandRefused(f"payload {payload[:60]!r} is not JSON") from None
        if not isinstance(body, dict):
            raise CommandRefused(f"payload {payload[:60]!r} must be a JSON object")
        args.update(body)
    return args


def number(args: dict, key: str, lo: float, hi: float) -> float:
    """A numeric argument in [lo, hi]; text that reads as a number is fine, `true` is not."""
    value = args.get(key)
    if value is None:
        raise CommandRefused(f"missing {key}; give {key}={lo:g}..{hi:g}")
    if isinstance(value, bool):
        raise CommandRefused(f"{key} {value!r} must be a number {lo:g}..{hi:g}, not true/false")
    try:
        x = float(value)
    except (TypeError, ValueError):
        raise CommandRefused(f"{key} {value!r} must be a number {lo:g}..{hi:g}") from None
    if not lo <= x <= hi:               # also refuses NaN
        raise CommandRefused(f"{key} {x:g} must be between {lo:g} and {hi:g}")
    return x


class CommandQueue:
    """Hands requests from the link's worker thread to the frame loop and waits for its answer."""

    def __init__(self, timeout_s: float = 2.0):
        self.timeout_s = timeout_s
        self._items: list[tuple[dict, Future]] = []
        self._lock = threading.Lock()

    def submit(self, request: dict, timeout_s: float | None = None) -> dict:
        fut: Future = Future()
        with self._lock:
            self._items.append((request, fut))
        wait = self.timeout_s if timeout_s is None else timeout_s
        try:
            return fut.result(wait)
        except FutureTimeout:
            with self._lock:            # never run later what the caller was told failed
                self._items = [(r, f) for r, f in self._items if f is not fut]
            raise TimeoutError(f"crawler busy: no answer within {wait:g} s "
                               "(is the camera delivering frames?)") from None

    def drain(self, handle):
        """Frame loop: answer every pending request with handle(request) -> dict (or its exception)."""
        with self._lock:
            items, self._items = self._items, []
        for request, fut in items:
            try:
                fut.set_result(handle(request))
            except Exception as exc:
                fut.set_exception(exc)
