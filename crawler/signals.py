"""Stop signals as a flag the loop checks, for crawlerd and crawler-monitor alike.

SIGTERM (systemd stop), SIGINT (Ctrl-C) and SIGHUP (the terminal went away) all mean "finish the
current frame, then stop cleanly": lights off, checkpoint, summary, exit 0.
"""

from __future__ import annotations

import signal
import threading

STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)


class StopSignals:
    """`with StopSignals() as stop:` ... `if stop: break`. Handlers are installed only in the main
    thread (Python allows nothing else) and restored on exit."""

    def __init__(self, signals=STOP_SIGNALS):
        self.signals = signals
        self.signum: int | None = None
        self._old = {}

    def __enter__(self) -> "StopSignals":
        if threading.current_thread() is threading.main_thread():
            for s in self.signals:
                self._old[s] = signal.signal(s, self._handler)
        return self

    def _handler(self, signum, _frame):
        self.signum = signum

    def __bool__(self) -> bool:
        return self.signum is not None

    def __exit__(self, *exc):
        for s, h in self._old.items():
            signal.signal(s, h)
        self._old = {}
