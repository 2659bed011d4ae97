"""Arguments, the watch loop and the one-shot commands: the only part that touches the terminal."""

from __future__ import annotations

import argparse
import collections
import json
import math
import os
import queue
import shutil
import signal
import sys
import threading
import time
from pathlib import Path

from .. import __version__
from ..errors import BadConfig, CrawlerError, fail
from ..zenoh_flags import ZENOH_MODES
from .fleet import SILENT_AFTER_S, Event, FleetState
from .net import NAME_RE, DaemonError, Feed, NoAnswer, control, open_session
from .record import RecordError, RecordWriter, read_records
from . import view

PROG = "crawler-monitor"
COMMANDS = ("watch", "plot", "reset", "led", "status")
REDRAW_HZ = 5.0


class UsageError(CrawlerError, ValueError):
    """Bad arguments: one line on stderr, exit 2."""


class _Parser(argparse.ArgumentParser):
    """argparse, but its errors are one `crawler-monitor: error: ...` line (main prints it), no usage dump."""

    def error(self, message):
        raise UsageError(message)


# -- arguments --------------------------------------------------------------------------------------

def _zenoh_flags(p, suppress: bool):
    """The crawlerd flags; on the subcommands with SUPPRESS defaults so either position works."""
    d = (lambda v: argparse.SUPPRESS) if suppress else (lambda v: v)
    g = p.add_argument_group("zenoh (as crawlerd)")
    g.add_argument("--connect", action="append", default=d([]), metavar="ENDPOINT",
                   help="e.g. tcp/192.168.1.10:7447, the crawler's listen endpoint (repeatable)")
    g.add_argument("--listen", action="append", default=d([]), metavar="ENDPOINT",
                   help="e.g. tcp/0.0.0.0:7447, for crawlers that connect to the laptop (repeatable)")
    g.add_argument("--zenoh-mode", choices=ZENOH_MODES, default=d(None),
                   help="zenoh mode (peer, or the --zenoh-config file's)")
    g.add_argument("--zenoh-config", metavar="FILE", default=d(None),
                   help="a full zenoh JSON5 config (TLS, access control)")
    g.add_argument("--no-multicast", action="store_true", default=d(False),
                   help="no multicast scouting (fixed endpoints only)")


def _level(text: str) -> float:
    try:
        level = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number (0..1)") from None
    if not 0.0 <= level <= 1.0:
        raise argparse.ArgumentTypeError(f"{level:g} is outside 0..1")
    return level


def _positive():
    def parse(text: str) -> float:
        try:
            x = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not a number of seconds") from None
        if not (x > 0 and math.isfinite(x)):
            raise argparse.ArgumentTypeError(f"{text!r} must be more than 0 s")
        return x
    return parse


def _size(text: str) -> tuple[int, int]:
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} must look like 1200x800") from None
    if not (400 <= w <= 8000 and 300 <= h <= 8000):
        raise argparse.ArgumentTypeError(f"{text!r}: width 400..8000, height 300..8000")
    return w, h


def _crawler_name(wildcard: bool):
    def parse(text: str) -> str:
        if text == "*" and wildcard:
            return text
        if not NAME_RE.match(text):
            allowed = "letters, digits, - and _" + (", or * for all" if wildcard else "")
            raise argparse.ArgumentTypeError(f"crawler name {text!r}: {allowed}")
        return text
    return parse


def build_parser() -> argparse.ArgumentParser:
    from . import __doc__ as usage

    p = _Parser(prog=PROG, description=usage, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    _zenoh_flags(p, suppress=False)
    sub = p.add_subparsers(dest="command", metavar="COMMAND")

    w = sub.add_parser("watch", help="live view (the default command)", description="Live view of crawlers.")
    w.add_argument("--name", type=_crawler_name(True), default="*",
                   help="one crawler, or * for the fleet (default *)")
    w.add_argument("--record", metavar="FILE", help="append every message to FILE.csv or FILE.jsonl")
    w.add_argument("--duration", type=_positive(), metavar="S", help="stop after S seconds")
    w.add_argument("--silent-after", type=_positive(), default=SILENT_AFTER_S, metavar="S",
                   help=f"mark a crawler SILENT after S seconds without a message ({SILENT_AFTER_S:g})")
    w.add_argument("--plain", action="store_true", help="line per update even on a terminal")
    w.add_argument("--no-color", action="store_true", help="no ANSI colours in the live view (also NO_COLOR)")
    _zenoh_flags(w, suppress=True)

    pl = sub.add_parser("plot", help="PNG of distance and speed from a record",
                        description="Distance and speed over time from a record, one line per crawler.")
    pl.add_argument("file", metavar="FILE", help="a record written by --record (.csv or .jsonl)")
    pl.add_argument("-o", "--output", metavar="OUT.png", help="the image (default: FILE with .png)")
    pl.add_argument("--size", type=_size, default=(1200, 800), metavar="WxH", help="pixels (1200x800)")
    pl.add_argument("--title", help="the title line (default: the record's file name)")

    for cmd, text in (("reset", "distance to 0, new run"), ("led", "set the LED level"),
                      ("status", "print the daemon's status")):
        c = sub.add_parser(cmd, help=text, description=f"{text[0].upper()}{text[1:]} through "
                           f"crawler/NAME/{'status' if cmd == 'status' else 'cmd/' + cmd}.")
        c.add_argument("name", metavar="NAME", type=_crawler_name(cmd == "status"),
                       help="the crawler's name" + (" (* asks every crawler)" if cmd == "status" else ""))
        if cmd == "led":
            c.add_argument("level", metavar="LEVEL", type=_level, help="0 (off) .. 1 (full)")
        c.add_argument("--timeout", type=_positive(), default=3.0, metavar="S",
                       help="how long to wait for an answer (3)")
        _zenoh_flags(c, suppress=True)
    return p


def with_default_command(argv: list[str], parser: argparse.ArgumentParser) -> list[str]:
    """Put `watch` in front unless a command is given: the first word that is no option's value."""
    takes_value = {s for a in _all_actions(parser) if a.nargs != 0 for s in a.option_strings}
    i = 0
    while i < len(argv):
        word = argv[i]
        if word in ("-h", "--help", "--version"):
            return argv
        if word.startswith("-"):
            i += 2 if (word in takes_value and "=" not in word) else 1
            continue
        return argv                         # a command, or a typo argparse will name
    return ["watch"] + argv


def _all_actions(parser):
    for a in parser._actions:
        yield a
        if isinstance(a, argparse._SubParsersAction):
            for sp in a.choices.values():
                yield from sp._actions


# -- watch ------------------------------------------------------------------------------------------

class _Stop:
    """SIGTERM/SIGINT set a flag the loop checks at least 5 times a second (main thread only)."""

    def __init__(self):
        self.signum = None
        self._old = {}

    def __enter__(self):
        if threading.current_thread() is threading.main_thread():
            for s in (signal.SIGINT, signal.SIGTERM):
                self._old[s] = signal.signal(s, self._handler)
        return self

    def _handler(self, signum, _frame):
        self.signum = signum

    def __bool__(self):
        return self.signum is not None

    def __exit__(self, *exc):
        for s, h in self._old.items():
            signal.signal(s, h)


class Watch:
    """The watch loop: queue -> FleetState -> record / plain lines / live view."""

    def __init__(self, args, out=None, live: bool | None = None):
        self.args = args
        self.out = out or sys.stdout
        self.live = (self.out.isatty() and not args.plain) if live is None else live
        self.color = self.live and not args.no_color and not os.environ.get("NO_COLOR")
        self.key = f"crawler/{args.name}"
        self.fleet = FleetState(args.silent_after)
        self.events = collections.deque(maxlen=6)
        self.writer = RecordWriter(args.record) if args.record else None    # fails before zenoh opens
        self.bad_payloads = 0
        self.feed = None
        self.closed_pipe = False

    def run(self, session, stop=lambda: False) -> int:
        feed = self.feed = Feed(session, self.args.name)
        start = time.monotonic()
        end = start + self.args.duration if self.args.duration else math.inf
        period = 1.0 / REDRAW_HZ
        next_tick = start
        if self.live:
            self.out.write(view.HIDE_CURSOR + view.CLEAR_SCREEN)
        try:
            while not stop() and not self.closed_pipe:
                now = time.monotonic()
                if now >= end:
                    break
                try:
                    self.handle(feed.queue.get(timeout=max(0.0, min(next_tick, end) - now)))
                    for _ in range(10_000):     # a backlog, but never so long that the view freezes
                        self.handle(feed.queue.get_nowait())
                except queue.Empty:
                    pass
                now = time.monotonic()
                if now >= next_tick:
                    next_tick = max(next_tick + period, now)
                    self.emit(time.time(), self.fleet.tick(now))
                    if self.live:
                        self.draw(now, end)
        finally:
            feed.close()
            if self.live:
                self.draw(time.monotonic(), end)
                self.out.write(view.SHOW_CURSOR)
                self.out.flush()
        return 0

    def handle(self, item):
        if item.topic == "alive":
            self.record(item.t_unix, item.name, "alive", {"alive": item.payload})
            self.plain(view.plain_line(item.t_unix, item.name, "alive", {"alive": item.payload}))
            self.emit(item.t_unix, self.fleet.liveliness(item.name, item.payload, item.t_mono))
            return
        try:
            payload = json.loads(item.payload)
            if not isinstance(payload, dict):
                raise ValueError("not a JSON object")
        except ValueError:
            self.bad_payloads += 1
            self.emit(item.t_unix, [Event(item.name, "bad-payload",
                                          f"{item.topic}: {item.payload[:60]!r} is not a JSON object")])
            return
        self.record(item.t_unix, item.name, item.topic, payload)
        if item.topic != "speed":            # the distance line carries the speed already
            self.plain(view.plain_line(item.t_unix, item.name, item.topic, payload))
        self.emit(item.t_unix, self.fleet.ingest(item.name, item.topic, payload, item.t_mono))

    def emit(self, t_unix, events):
        for e in events:
            self.events.append((t_unix, e))
            self.record(t_unix, e.name, "event", {"event": e.kind, "detail": e.detail})
            self.plain(view.plain_event(t_unix, e))

    def record(self, t_unix, name, topic, data):
        if self.writer is not None:
            self.writer.write(t_unix, name, topic, data)

    def plain(self, line: str):
        if not self.live and not self.closed_pipe:
            try:
                self.out.write(line + "\n")
                self.out.flush()
            except BrokenPipeError:         # `crawler-monitor | head`: the reader is gone; so are we
                self.closed_pipe = True
                try:
                    os.dup2(os.open(os.devnull, os.O_WRONLY), self.out.fileno())
                except (OSError, ValueError, AttributeError):
                    pass

    def draw(self, now, end):
        notes = []
        if self.writer is not None:
            notes.append(f"recording -> {self.writer.path} ({self.writer.rows} rows)")
        if math.isfinite(end):
            notes.append(f"stops in {max(0.0, end - now):.0f} s")
        if self.bad_payloads:
            notes.append(f"!! {self.bad_payloads} unreadable messages")
        if self.feed is not None and self.feed.dropped:
            notes.append(f"!! {self.feed.dropped} messages dropped (monitor too slow)")
        notes.append("Ctrl-C quits")
        text = view.render(self.fleet, now, key=self.key, events=list(self.events), note="   ".join(notes),
                           color=self.color)
        lines = text.splitlines()
        height = shutil.get_terminal_size().lines
        if len(lines) > height - 1:         # a scrolled screen cannot be redrawn in place
            lines = lines[:height - 2] + [f"... {len(lines) - height + 2} more lines (a taller window shows them)"]
            text = "\n".join(lines) + "\n"
        self.out.write(view.HOME + text.replace("\n", view.CLEAR_EOL + "\n") + view.CLEAR_EOS)
        self.out.flush()

    def close(self):
        if self.writer is not None:
            self.writer.close()


def cmd_watch(args) -> int:
    w = Watch(args)
    try:
        with _Stop() as stop:
            session = open_session(args)
            try:
                w.run(session, stop=lambda: bool(stop))
            finally:
                session.close()
    finally:
        w.close()
    names = sorted(w.fleet.crawlers)
    heard = f"heard {len(names)} crawler(s): {', '.join(names)}" if names else (
        f"heard no crawler on {w.key}/* (is crawlerd running? check --connect, or multicast on this network)")
    if w.writer is not None:
        heard += f"; recorded {w.writer.rows} rows to {w.writer.path}"
    print(f"{PROG}: {heard}", file=sys.stderr)
    return 0


# -- control ----------------------------------------------------------------------------------------

def cmd_control(args) -> int:
    request = {"cmd": args.command}
    if args.command == "led":
        request["level"] = args.level
    session = open_session(args)
    try:
        replies = control(session, args.name, request, args.timeout)
    finally:
        session.close()
    if not replies:
        who = "no crawler" if args.name == "*" else f"no crawler named {args.name!r}"
        raise NoAnswer(f"{who} answered {args.command} within {args.timeout:g} s on crawler/{args.name}/{'status' if args.command == 'status' else 'cmd/' + args.command} "
                       "(is crawlerd running, and can this laptop reach it? try --connect tcp/IP:7447)")
    errors = []
    indent = 2 if sys.stdout.isatty() else None
    for name, body in replies:
        if body.get("ok") is False:
            errors.append(f"crawler {name} refused {args.command}: {body.get('error', body)}")
        else:
            print(json.dumps(body, indent=indent), flush=True)
    if errors:
        raise DaemonError("; ".join(errors))
    return 0


# -- plot -------------------------------------------------------------------------------------------

def cmd_plot(args) -> int:
    import cv2

    from .plot import NothingToPlot, plot_records, series_from_records

    records = read_records(args.file)
    out = Path(args.output) if args.output else Path(args.file).with_suffix(".png")
    if out.suffix.lower() != ".png":
        raise UsageError(f"-o {str(out)!r}: the plot is a .png")
    try:
        img = plot_records(records, args.size, args.title or Path(args.file).name)
    except NothingToPlot as exc:
        raise NothingToPlot(f"nothing to plot in {args.file}: {exc}") from None
    try:
        ok = cv2.imwrite(str(out), img)
    except cv2.error:
        ok = False
    if not ok:
        raise UsageError(f"cannot write {str(out)!r} (does its folder exist?)")
    t0, series = series_from_records(records)
    span = max(max(s.t) for s in series.values())
    print(f"wrote {out} ({img.shape[1]}x{img.shape[0]}): {len(series)} crawler(s) "
          f"{', '.join(sorted(series))}, {span:.1f} s")
    return 0


# -- main -------------------------------------------------------------------------------------------

def main(argv=None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    try:
        parser = build_parser()
        try:
            args = parser.parse_args(with_default_command(argv, parser))
        except SystemExit as exc:           # --help, --version
            return int(exc.code or 0)
        run = {"watch": cmd_watch, "plot": cmd_plot}.get(args.command, cmd_control)
        return run(args)
    except (UsageError, BadConfig, RecordError) as exc:
        return _fail(exc, 2)
    except CrawlerError as exc:
        return _fail(exc, 2 if isinstance(exc, ValueError) else 1)
    except KeyboardInterrupt:
        return 130


def _fail(exc, code: int) -> int:
    return fail(PROG, exc, code)
