"""The watch loop: network queue -> FleetState -> record, Foxglove, plain lines or the live view.

One thread owns all state. Zenoh callbacks and the command workers (a mark typed in the live view, the
observations of a run the laptop joined late) only put items on the feed's queue.
"""

from __future__ import annotations

import collections
import json
import math
import os
import queue
import sys
import threading
import time

from ..signals import StopSignals
from .deps import require
from .fleet import Event, FleetState
from .keys import HELP, Keyboard, Mark, MarkPrompt, Quit
from .net import Feed, Received, command, open_session
from .record import open_record
from . import view

REDRAW_HZ = 5.0
COMMAND_TIMEOUT_S = 3.0
REFETCH_AFTER_S = 10.0


class Watch:
    """The loop and everything it feeds; sinks (record, Foxglove) open before zenoh does."""

    def __init__(self, args, out=None, live: bool | None = None, keyboard: Keyboard | None = None):
        self.args = args
        self.out = out or sys.stdout
        self.live = (self.out.isatty() and not args.plain) if live is None else live
        self.key = f"crawler/{args.name}"
        self.fleet = FleetState(args.silent_after)
        self.events = collections.deque(maxlen=6)
        self.prompt = MarkPrompt()
        self.keyboard = keyboard or Keyboard()
        self.sinks = []
        self.writer = self.foxglove = None
        if self.live:                           # before zenoh opens, like the record
            require("rich.live", "the live view", "--plain prints one line per update without it")
        try:
            if args.record:
                self.writer = open_record(args.record)
                self.sinks.append(self.writer)
            if getattr(args, "foxglove", False):
                from .foxglove_live import FoxgloveSink

                self.foxglove = FoxgloveSink(args.foxglove_host, args.foxglove_port)
                self.sinks.append(self.foxglove)
        except BaseException:
            self.close()
            raise
        self.bad_payloads = 0
        self.feed = self.session = self._live = None
        self.closed_pipe = False
        self.quit = False
        self._asked: dict[str, float] = {}      # crawler -> when its observation list was last asked for

    # -- the loop -----------------------------------------------------------------------------------

    def run(self, session, stop=lambda: False) -> int:
        self.session = session
        feed = self.feed = Feed(session, self.args.name)
        start = time.monotonic()
        end = start + self.args.duration if self.args.duration else math.inf
        period, next_tick = 1.0 / REDRAW_HZ, start
        try:
            with self.keyboard if self.live else _Nothing():
                self._open_screen()
                while not (stop() or self.closed_pipe or self.quit):
                    now = time.monotonic()
                    if now >= end:
                        break
                    self._drain(feed, max(0.0, min(next_tick, end) - now))
                    now = time.monotonic()
                    if now >= next_tick:
                        next_tick = max(next_tick + period, now)
                        self.emit(time.time(), self.fleet.tick(now))
                        if self.live:
                            self.keys()
                            self.draw(now, end)
        finally:
            feed.close()
            self._close_screen(end)
        return 0

    def _drain(self, feed, wait_s: float):
        try:
            self.handle(feed.queue.get(timeout=wait_s))
            for _ in range(10_000):     # a backlog, but never so long that the view freezes
                self.handle(feed.queue.get_nowait())
        except queue.Empty:
            pass

    def handle(self, item: Received):
        if item.topic == "alive":
            self.record(item.t_unix, item.name, "alive", {"alive": item.payload})
            self.plain(view.plain_line(item.t_unix, item.name, "alive", {"alive": item.payload}))
            self.emit(item.t_unix, self.fleet.liveliness(item.name, item.payload, item.t_mono))
            return
        if item.topic == "reply":
            self.answered(item)
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
        if item.topic == "status":
            self.fetch_observations(item.name, item.t_mono)

    def emit(self, t_unix, events):
        for e in events:
            self.events.append((t_unix, e))
            self.record(t_unix, e.name, "event", {"event": e.kind, "detail": e.detail})
            self.plain(view.plain_event(t_unix, e))

    def record(self, t_unix, name, topic, data):
        for sink in self.sinks:
            sink.write(t_unix, name, topic, data)

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

    # -- commands from the loop ---------------------------------------------------------------------

    def ask(self, name: str, verb: str, args: dict | None):
        """Send a command from a worker thread; its replies come back through the feed as `reply`."""
        def work():
            try:
                replies = command(self.session, name, verb, args, COMMAND_TIMEOUT_S)
            except Exception as exc:        # the session closed under us: say so, never raise here
                replies = [(name, {"ok": False, "error": str(exc)})]
            self.feed.put(Received(time.time(), time.monotonic(), name, "reply",
                                   {"verb": verb, "replies": replies}))
        threading.Thread(target=work, name=f"cmd-{verb}", daemon=True).start()

    def fetch_observations(self, name: str, now: float):
        """A status says the daemon holds observations this monitor has not seen: ask for the list."""
        c = self.fleet.crawlers.get(name)
        if c is None or not c.missing_observations() or now - self._asked.get(name, -math.inf) < REFETCH_AFTER_S:
            return
        self._asked[name] = now
        self.ask(name, "observations", None)

    def answered(self, item: Received):
        verb, replies = item.payload["verb"], item.payload["replies"]
        if not replies:
            self.emit(item.t_unix, [Event(item.name, "no-answer", f"{verb}: no reply within "
                                                                  f"{COMMAND_TIMEOUT_S:g} s")])
        for name, body in replies:
            if body.get("ok") is False:
                self.emit(item.t_unix, [Event(name, "refused", f"{verb}: {body.get('error', body)}")])
                continue
            found = body.get("observations") if verb == "observations" else [body.get("observation")]
            for obs in found or []:
                if isinstance(obs, dict):
                    self.observed(item.t_unix, name, obs)

    def observed(self, t_unix: float, name: str, obs: dict):
        """An observation from a reply: recorded and shown unless the feed brought it already."""
        events = []
        if self.fleet.observation(name, obs, events):
            self.record(t_unix, name, "observations", obs)
            self.emit(t_unix, events)

    def keys(self):
        names = [c.name for c in self.fleet.rows()]
        for action in self.prompt.feed(self.keyboard.read(), names):
            if isinstance(action, Quit):
                self.quit = True
            elif isinstance(action, Mark):
                self.ask(action.name, "mark", action.args)

    # -- the live view ------------------------------------------------------------------------------

    def _open_screen(self):
        if not self.live:
            return
        from rich.console import Console
        from rich.live import Live

        console = Console(file=self.out, force_terminal=True, no_color=bool(self.args.no_color))
        self._live = Live(console=console, auto_refresh=False, transient=False,
                               vertical_overflow="crop", redirect_stdout=False, redirect_stderr=False)
        self._live.start()

    def _close_screen(self, end):
        if self._live is not None:
            self.draw(time.monotonic(), end)
            self._live.stop()
            self._live = None

    def draw(self, now, end):
        if self._live is None:
            return
        notes = []
        if self.writer is not None:
            notes.append(f"recording -> {self.writer.path} ({self.writer.rows} rows)")
        if self.foxglove is not None:
            notes.append(f"foxglove -> {self.foxglove.url}")
        if math.isfinite(end):
            notes.append(f"stops in {max(0.0, end - now):.0f} s")
        if self.bad_payloads:
            notes.append(f"!! {self.bad_payloads} unreadable messages")
        if self.feed is not None and self.feed.dropped:
            notes.append(f"!! {self.feed.dropped} messages dropped (monitor too slow)")
        notes.append(HELP if self.keyboard.enabled else "Ctrl-C quits")
        self._live.update(view.render(self.fleet, now, key=self.key, events=list(self.events),
                                      note="   ".join(notes), prompt=self.prompt.line(),
                                      width=self._live.console.width), refresh=True)

    def close(self):
        for sink in self.sinks:
            sink.close()


class _Nothing:
    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False


def cmd_watch(args, prog: str) -> int:
    w = Watch(args)
    if w.foxglove is not None:
        print(f"{prog}: serving Foxglove on {w.foxglove.url} (in Foxglove: Open connection, Foxglove WebSocket)",
              file=sys.stderr, flush=True)
    try:
        with StopSignals() as stop:
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
    print(f"{prog}: {heard}", file=sys.stderr)
    return 0
