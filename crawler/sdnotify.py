"""systemd's notify protocol in a few lines: READY, WATCHDOG pings, STATUS, STOPPING.

No dependency: a datagram to $NOTIFY_SOCKET. Outside systemd (no socket) every call is a no-op.
"""

from __future__ import annotations

import os
import socket
import time

from .ports import Output


class Notifier:
    def __init__(self, env=os.environ, clock=time.monotonic):
        self.address = env.get("NOTIFY_SOCKET")
        if self.address and self.address.startswith("@"):
            self.address = "\0" + self.address[1:]   # abstract namespace
        elif self.address and not self.address.startswith("/"):
            self.address = None                       # vsock: etc. need systemd >= 253
        usec, pid = env.get("WATCHDOG_USEC"), env.get("WATCHDOG_PID")
        mine = not pid or pid == str(os.getpid())     # an inherited watchdog belongs to our parent
        # ping at twice the rate systemd demands
        self.watchdog_s = int(usec) / 1e6 / 2 if usec and usec.isdigit() and mine else None
        self.clock = clock
        self._last_ping = None
        self._sock = None
        if self.address:
            self._sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM | socket.SOCK_CLOEXEC)

    @property
    def enabled(self) -> bool:
        return self._sock is not None

    def send(self, *lines: str):
        if self._sock is None:
            return
        try:
            self._sock.sendto("\n".join(lines).encode(), self.address)
        except OSError:
            pass   # systemd gone (shutdown): nothing to tell

    def ready(self, status: str = ""):
        self.send("READY=1", *([f"STATUS={status}"] if status else []))

    def watchdog(self):
        """Call once per frame: pings only as often as the watchdog interval needs."""
        if self._sock is None or self.watchdog_s is None:
            return
        now = self.clock()
        if self._last_ping is None or now - self._last_ping >= self.watchdog_s:
            self._last_ping = now
            self.send("WATCHDOG=1")

    def stopping(self):
        self.send("STOPPING=1")

    def close(self):
        if self._sock is not None:
            self._sock.close()
            self._sock = None


class WatchdogOutput(Output):
    """The notify protocol as the loop's output: READY at start, WATCHDOG per frame, STOPPING at the end.

    A loop that stops delivering frames stops the pings, and systemd restarts the daemon.
    """

    def __init__(self, notifier: Notifier, describe=lambda: ""):
        self.notifier = notifier
        self.describe = describe

    def start(self, run):
        self.notifier.ready(f"measuring from {self.describe()}")

    def write(self, frame, estimate, run):
        self.notifier.watchdog()

    def stop(self, run):
        self.notifier.stopping()

    def close(self):
        self.notifier.close()
