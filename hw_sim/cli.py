"""hw_sim: render simulated pipe-crawler camera runs with exact ground truth.

Usage:
  python -m hw_sim render --out DIR --name NAME [--tilt DEG] [--speed M_PER_S] [--duration S] [...]
  python -m hw_sim params            # every parameter as a Markdown table

`render` writes DIR/NAME.h264, NAME.pts, NAME.csv and NAME.json and prints a one-line JSON summary
on stdout. Defaults are the thesis camera (960x720, 37.16/53.50 deg, 30 fps) and car (0.151 m wide,
camera 0.054 m above the wheels) in a 0.30 m pipe. Bad values exit 2 with `hw_sim: error: ...`;
HW_SIM_DEBUG=1 shows the traceback of other failures.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
from typing import Any, Callable, Sequence

from .config import BadValue, ConfigError, SimConfig, SimError, field_docs

PROG = "hw_sim"


class _Usage(Exception):
    """A command-line mistake: exit 2."""


class _Parser(argparse.ArgumentParser):
    def error(self, message: str):  # one line, no usage dump
        raise _Usage(message)


def _floats(n: int | None, what: str) -> Callable[[str], tuple[float, ...]]:
    def parse(s: str) -> tuple[float, ...]:
        try:
            v = tuple(float(x) for x in s.replace("x", ",").split(","))
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {what}, got {s!r}") from None
        if n is not None and len(v) != n:
            raise argparse.ArgumentTypeError(f"expected {what}, got {s!r}")
        return v
    return parse


def _ints(n: int, what: str) -> Callable[[str], tuple[int, ...]]:
    fl = _floats(n, what)

    def parse(s: str) -> tuple[int, ...]:
        v = fl(s)
        if any(x != int(x) for x in v):
            raise argparse.ArgumentTypeError(f"expected {what}, got {s!r}")
        return tuple(int(x) for x in v)
    return parse


def _pairs(s: str) -> tuple[tuple[float, float], ...]:
    """'1.0:1.3,2.0:2.2' -> ((1.0, 1.3), (2.0, 2.2)): intervals a:b or keyframes key:value."""
    out = []
    for part in filter(None, s.split(",")):
        try:
            a, b = part.split(":")
            out.append((float(a), float(b)))
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected A:B[,A:B...], got {s!r}") from None
    return tuple(out)


def _none_or(parse: Callable[[str], Any]) -> Callable[[str], Any]:
    return lambda s: None if s.lower() == "none" else parse(s)


_TYPES: dict[str, tuple[Callable[[str], Any], str]] = {
    "int": (int, "N"),
    "float": (float, "X"),
    "float | None": (_none_or(float), "X"),
    "str": (str, "S"),
    "str | None": (_none_or(str), "S"),
    "tuple[float, float]": (_floats(2, "A,B"), "A,B"),
    "tuple[float, float] | None": (_none_or(_floats(2, "U,V")), "U,V"),
    "tuple[int, int, int, int] | None": (_none_or(_ints(4, "X0,Y0,W,H")), "X0,Y0,W,H"),
    "tuple[int, int] | None": (_none_or(_ints(2, "W,H or WxH")), "W,H"),
    "tuple[float, float, float, float, float] | None": (_none_or(_floats(5, "K1,K2,P1,P2,K3")), "K1,K2,P1,P2,K3"),
    "tuple[tuple[float, float], ...]": (_pairs, "A:B[,A:B]"),
}


def build_parser() -> argparse.ArgumentParser:
    p = _Parser(prog=PROG, description=__doc__,
                formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = p.add_subparsers(dest="cmd", metavar="{render,params}", parser_class=_Parser)
    r = sub.add_parser("render", help="render a run into DIR/NAME.{h264,pts,csv,json}")
    r.add_argument("--out", required=True, metavar="DIR", help="output folder (created if missing)")
    r.add_argument("--name", required=True, help="base name of the four files")
    r.add_argument("--quiet", action="store_true", help="no progress on stderr")
    for d in field_docs():
        unit = f" [{d['unit']}]" if d["unit"] else ""
        help_ = f"{d['help']}{unit} (default {d['default']!r})".replace("%", "%%")
        if d["type"] == "bool":
            r.add_argument(d["flag"], dest=d["name"], action=argparse.BooleanOptionalAction,
                           default=d["default"], help=help_)
        else:
            typ, metavar = _TYPES[d["type"]]
            metavar = d["metavar"] or metavar
            r.add_argument(d["flag"], dest=d["name"], type=typ, default=d["default"], metavar=metavar,
                           help=help_)
    sub.add_parser("params", help="print every parameter as a Markdown table")
    return p


def params_table() -> str:
    rows = ["| field | CLI flag | default | unit | meaning |", "|---|---|---|---|---|"]
    for d in field_docs():
        flag = f"`{d['flag']}`" + (f" / `--no-{d['flag'][2:]}`" if d["type"] == "bool" else "")
        rows.append(f"| `{d['name']}` | {flag} | `{d['default']!r}` | {d['unit']} | {d['help']} |")
    return "\n".join(rows)


def _flag_of(name: str) -> str:
    return next((d["flag"] for d in field_docs() if d["name"] == name), name)


def _progress(name: str) -> Callable[[int, int], None]:
    def show(done: int, total: int) -> None:
        sys.stderr.write(f"\r{PROG}: {name}: frame {done}/{total}")
        if done == total:
            sys.stderr.write("\n")
        sys.stderr.flush()
    return show


def render(args: argparse.Namespace) -> dict[str, Any]:
    """Build the config from parsed flags, write the run, return the summary."""
    from .io import write_run   # PyAV loads only when rendering
    names = {d["name"] for d in field_docs()}
    cfg = SimConfig(**{k: v for k, v in vars(args).items() if k in names})
    show = None if args.quiet or not sys.stderr.isatty() else _progress(args.name)
    paths = write_run(cfg, args.out, args.name, progress=show)
    meta = json.loads(paths["json"].read_text())
    return {**{k: str(v) for k, v in paths.items()}, "frames": meta["frames"],
            "true_distance_m": meta["true_distance_m"]}


def main(argv: Sequence[str] | None = None) -> int:
    try:
        args = build_parser().parse_args(argv)
        if args.cmd is None:
            raise _Usage("a command is required: render or params (see --help)")
        if args.cmd == "params":
            print(params_table())
            return 0
        print(json.dumps(render(args)))
        return 0
    except _Usage as e:
        print(f"{PROG}: error: {e}", file=sys.stderr)
        return 2
    except ConfigError as e:
        print(f"{PROG}: error: {e} ({_flag_of(e.field)})", file=sys.stderr)
        return 2
    except BadValue as e:
        print(f"{PROG}: error: {e}", file=sys.stderr)
        return 2
    except BrokenPipeError:      # e.g. `params | head`: stop quietly
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 1
    except (SimError, OSError) as e:
        if os.environ.get("HW_SIM_DEBUG"):
            raise
        print(f"{PROG}: error: {e}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print(f"{PROG}: interrupted", file=sys.stderr)
        return 130
