"""Arguments and main(): argparse stays here; the commands get parsed, typed values."""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

from .. import __version__
from ..errors import BadConfig, CrawlerError, fail
from ..zenoh_flags import add_zenoh_flags
from . import commands
from .fleet import SILENT_AFTER_S
from .foxglove_live import DEFAULT_PORT
from .net import NAME_RE
from .record import RecordError, read_records

PROG = "crawler-monitor"
PLOT_SUFFIXES = (".png", ".svg", ".pdf")
REPORT_SUFFIXES = (".html", ".csv")


class UsageError(CrawlerError, ValueError):
    """Bad arguments: one line on stderr, exit 2."""


class _Parser(argparse.ArgumentParser):
    """argparse, but its errors are one `crawler-monitor: error: ...` line (main prints it), no usage dump,
    and no abbreviated flags (a prefix of one flag must not silently mean another)."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **{"allow_abbrev": False, **kwargs})

    def error(self, message):
        raise UsageError(message)


# -- argument types ---------------------------------------------------------------------------------

def _checked(check, what: str = ""):
    """An argparse type from one of the commands' checks (ValueError -> argparse's error)."""
    def parse(text: str):
        try:
            return check(text)
        except ValueError as exc:
            raise argparse.ArgumentTypeError(str(exc)) from None
    parse.__name__ = what or check.__name__
    return parse


def _positive(text: str) -> float:
    try:
        x = float(text)
    except ValueError:
        raise ValueError(f"{text!r} is not a number of seconds") from None
    if not (x > 0 and math.isfinite(x)):
        raise ValueError(f"{text!r} must be more than 0 s")
    return x


def _port(text: str) -> int:
    if not text.isdigit() or not 0 <= int(text) <= 65535:
        raise ValueError(f"{text!r} is not a TCP port (0..65535, 0 picks a free one)")
    return int(text)


def _size(text: str) -> tuple[int, int]:
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise ValueError(f"{text!r} must look like 1200x800") from None
    if not (400 <= w <= 8000 and 300 <= h <= 8000):
        raise ValueError(f"{text!r}: width 400..8000, height 300..8000")
    return w, h


def _crawler_name(wildcard: bool):
    def parse(text: str) -> str:
        if text == "*" and wildcard:
            return text
        if not NAME_RE.match(text):
            allowed = "letters, digits, - and _" + (", or * for all" if wildcard else "")
            raise ValueError(f"crawler name {text!r}: {allowed}")
        return text
    return _checked(parse, "name")


# -- the parser -------------------------------------------------------------------------------------

def _watch_flags(p, suppress: bool):
    """The watch options. watch is the default command, so they go on the top-level parser too; on
    the subcommand their defaults are SUPPRESS, so values given before `watch` are kept."""
    d = (lambda v: argparse.SUPPRESS) if suppress else (lambda v: v)
    g = p.add_argument_group("watch (the default command)")
    g.add_argument("--name", type=_crawler_name(True), default=d("*"),
                   help="one crawler, or * for the fleet (default *)")
    g.add_argument("--record", metavar="FILE", default=d(None),
                   help="record every message to FILE.csv, .jsonl or .mcap")
    g.add_argument("--duration", type=_checked(_positive), metavar="S", default=d(None), help="stop after S seconds")
    g.add_argument("--silent-after", type=_checked(_positive), default=d(SILENT_AFTER_S), metavar="S",
                   help=f"mark a crawler SILENT after S seconds without a message ({SILENT_AFTER_S:g})")
    g.add_argument("--plain", action="store_true", default=d(False), help="line per update even on a terminal")
    g.add_argument("--no-color", action="store_true", default=d(False),
                   help="no colours in the live view (also NO_COLOR)")
    g.add_argument("--foxglove", action="store_true", default=d(False),
                   help="serve the fleet live to Foxglove (WebSocket)")
    g.add_argument("--foxglove-port", type=_checked(_port), default=d(DEFAULT_PORT), metavar="PORT",
                   help=f"the Foxglove WebSocket port ({DEFAULT_PORT})")
    g.add_argument("--foxglove-host", default=d("127.0.0.1"), metavar="HOST",
                   help="the address to serve on (127.0.0.1; 0.0.0.0 for other machines)")


def _watch_parser(sub):
    w = sub.add_parser("watch", help="live view (the default command)", description="Live view of crawlers.")
    _watch_flags(w, suppress=True)
    add_zenoh_flags(w, suppress=True)


def _file_parsers(sub):
    pl = sub.add_parser("plot", help="distance and speed over time from a record",
                        description="Distance and speed over time from a record, one line per crawler.")
    pl.add_argument("file", metavar="FILE", help="a record written by --record (.csv, .jsonl or .mcap)")
    pl.add_argument("-o", "--output", metavar="OUT", help="the image: .png, .svg or .pdf (default FILE.png)")
    pl.add_argument("--size", type=_checked(_size), default=(1200, 800), metavar="WxH",
                    help="pixels (1200x800)")
    pl.add_argument("--title", help="the title line (default: the record's file name)")
    rp = sub.add_parser("report", help="the inspection report: observations, distance and speed plots",
                        description="The observation table of a record with its distance and speed plots.")
    rp.add_argument("file", metavar="FILE", help="a record written by --record (.csv, .jsonl or .mcap)")
    rp.add_argument("-o", "--output", metavar="OUT", help="report.html (with the plots) or report.csv")
    rp.add_argument("--title", help="the report's title (default: the record's file name)")


def _command_parsers(sub):
    texts = {"reset": "distance to 0, new run", "led": "set the LED level", "zero": "footage counter to 0 here",
             "preset": "footage counter to DISTANCE here", "units": "footage in metres or feet",
             "direction": "survey direction", "mark": "stamp an observation at the current distance",
             "status": "print the daemon's status", "observations": "print the run's observations"}
    for verb, text in texts.items():
        wildcard = verb in ("status", "observations")
        c = sub.add_parser(verb, help=text, description=f"{text[0].upper()}{text[1:]} (crawler/NAME/"
                           f"{'status' if verb == 'status' else 'cmd/' + verb}).")
        c.add_argument("name", metavar="NAME", type=_crawler_name(wildcard),
                       help="the crawler's name" + (" (* asks every crawler)" if wildcard else ""))
        if verb == "led":
            c.add_argument("level", metavar="LEVEL", type=_checked(commands.level_arg), help="0 (off) .. 1 (full)")
        elif verb == "preset":
            c.add_argument("distance", metavar="DISTANCE", type=_checked(commands.distance_arg),
                           help="the footage here, in the crawler's unit (e.g. 12.40)")
            c.add_argument("--unit", choices=commands.UNITS, help="DISTANCE is in this unit instead")
        elif verb == "units":
            c.add_argument("unit", metavar="UNIT", choices=commands.UNITS, help="m or ft")
        elif verb == "direction":
            c.add_argument("direction", metavar="DIRECTION", choices=commands.DIRECTIONS,
                           help="downstream or upstream")
        elif verb == "mark":
            _mark_flags(c)
        c.add_argument("--timeout", type=_checked(_positive), default=3.0, metavar="S",
                       help="how long to wait for an answer (3)")
        add_zenoh_flags(c, suppress=True)


def _mark_flags(c):
    c.add_argument("code", metavar="CODE", type=_checked(commands.code_arg),
                   help="the observation code (PACP or EN 13508-2), e.g. FL, BAB")
    c.add_argument("--clock", type=_checked(commands.clock_arg), metavar="H", help="clock position 1..12")
    kind = c.add_mutually_exclusive_group()
    kind.add_argument("--start", action="store_true", help="a continuous defect starts here")
    kind.add_argument("--finish", action="store_true", help="a continuous defect ends here")
    c.add_argument("--note", type=_checked(commands.note_arg), metavar="TEXT", help="a remark")


def build_parser() -> argparse.ArgumentParser:
    from . import __doc__ as usage

    p = _Parser(prog=PROG, description=usage, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    add_zenoh_flags(p)
    _watch_flags(p, suppress=False)
    sub = p.add_subparsers(dest="command", metavar="COMMAND")
    _watch_parser(sub)
    _file_parsers(sub)
    _command_parsers(sub)
    return p


# -- plot and report --------------------------------------------------------------------------------

def _output(args, default_suffix: str, allowed: tuple) -> Path:
    out = Path(args.output) if args.output else Path(args.file).with_suffix(default_suffix)
    if out.suffix.lower() not in allowed:
        raise UsageError(f"-o {str(out)!r}: the output is {', '.join(allowed)}")
    if not out.parent.is_dir():
        raise UsageError(f"-o {str(out)!r}: no folder {str(out.parent)!r}")
    return out


def cmd_plot(args) -> int:
    from .plot import figure_summary, save_plot

    out = _output(args, ".png", PLOT_SUFFIXES)
    records = read_records(args.file)
    save_plot(records, out, args.size, args.title or Path(args.file).name)
    print(f"wrote {out}: {figure_summary(records)}")
    return 0


def cmd_report(args) -> int:
    from .report import write_report

    out = _output(args, ".html", REPORT_SUFFIXES)
    summary = write_report(read_records(args.file), out, args.title or Path(args.file).name)
    print(f"wrote {out}: {summary}")
    return 0


# -- main -------------------------------------------------------------------------------------------

def main(argv=None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    try:
        parser = build_parser()
        try:
            args = parser.parse_args(argv)
        except SystemExit as exc:           # --help, --version
            return int(exc.code or 0)
        args.command = args.command or "watch"
        if args.command == "watch":
            from .watch import cmd_watch

            return cmd_watch(args, PROG)
        run = {"plot": cmd_plot, "report": cmd_report}.get(args.command, commands.cmd_control)
        return run(args)
    except (UsageError, BadConfig, RecordError) as exc:
        return fail(PROG, exc, 2)
    except CrawlerError as exc:
        return fail(PROG, exc, 2 if isinstance(exc, ValueError) else 1)
    except KeyboardInterrupt:
        return 130
