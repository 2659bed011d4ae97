"""Wheel distance from the crawler's own controller over Zenoh, for crawlers that already measure it.

The controller puts JSON on `crawler/<name>/wheel` (the [wheel] key):
  {"counts": 123456}  or  {"distance_m": 12.345}
with optionally "t_s" (when it was measured, on the controller's clock) and "epoch" (any string that
changes when the controller's counter starts again from zero). The controller's clock is mapped onto
ours by the smallest (arrival − t_s) seen, which is its offset plus the fastest network delay.
"""

from __future__ import annotations

import json
import logging
import math
import threading
import time

from .port import WheelReading, WheelUnavailable

_log = logging.getLogger(__name__)


class ZenohWheel:
    def __init__(self, key: str, *, counts_per_m: float | None = None, direction: int = 1,
                 timeout_s: float = 0.5, clock=time.monotonic, session=None, zenoh_config=None):
        self.key, self.counts_per_m, self.direction = key, counts_per_m, direction
        self.timeout_s, self.clock = timeout_s, clock
        self._session, self._config, self._own = session, zenoh_config, False
        self._sub = None
        self._latest = None           # (arrival time, WheelReading)
        self._offset = None           # controller clock -> ours
        self._last_arrival = None
        self._lock = threading.Lock()
        self.received = self.rejected = 0
        self.last_error = None
        self.description = f"zenoh wheel {key!r}"

    @classmethod
    def from_settings(cls, s, *, clock=time.monotonic, session=None, zenoh_config=None):
        return cls(s.key, counts_per_m=s.counts_per_m, direction=s.direction, timeout_s=s.timeout_s,
                   clock=clock, session=session, zenoh_config=zenoh_config)

    def __enter__(self):
        return self.open()

    def __exit__(self, *exc):
        self.close()

    def open(self):
        """Subscribe on the given session, or open one from zenoh_config (and close it at the end)."""
        if self._session is None:
            import zenoh

            try:
                self._session = zenoh.open(self._config if self._config is not None else zenoh.Config())
            except Exception as exc:     # zenoh raises its own ZError
                raise WheelUnavailable(f"[wheel] backend = \"zenoh\": no session ({exc}); check [zenoh]") from None
            self._own = True
        self._sub = self._session.declare_subscriber(self.key, self._on_sample)
        return self

    def _on_sample(self, sample):
        """Runs on a zenoh thread: parse, stamp, keep the newest; a bad message is counted, not raised."""
        now = self.clock()
        try:
            reading = self._parse(sample.payload.to_string(), now)
        except ValueError as exc:
            self.rejected += 1
            if self.rejected == 1:
                _log.warning("%s: message rejected (%s); expected {\"counts\": N} or "
                             "{\"distance_m\": x}", self.description, exc)
            self.last_error = str(exc)
            return
        with self._lock:
            self._latest = (now, reading)
            self.received += 1

    def _parse(self, text: str, now: float) -> WheelReading:
        try:
            msg = json.loads(text)
        except ValueError:
            raise ValueError(f"not JSON: {text[:60]!r}") from None
        if not isinstance(msg, dict):
            raise ValueError(f"not a JSON object: {text[:60]!r}")
        if "counts" in msg:
            if not self.counts_per_m:
                raise ValueError("counts given but [wheel] counts_per_m is not set")
            position = _finite(msg, "counts") / self.counts_per_m
        elif "distance_m" in msg:
            position = _finite(msg, "distance_m")
        else:
            raise ValueError(f"neither counts nor distance_m in {text[:60]!r}")
        t = now
        if "t_s" in msg:
            t = self._map_time(_finite(msg, "t_s"), now)
        epoch = str(msg.get("epoch", f"zenoh:{self.key}"))
        return WheelReading(t, self.direction * position, None, epoch)

    def _map_time(self, t_sender: float, now: float) -> float:
        """Sender time on our clock: the lower envelope of arrival − t_s (drift up to 100 ppm)."""
        seen = now - t_sender
        if self._offset is None or self._last_arrival is None:
            self._offset = seen
        else:
            self._offset = min(self._offset + 1e-4 * max(now - self._last_arrival, 0.0), seen)
        self._last_arrival = now
        return t_sender + self._offset

    def read(self) -> WheelReading | None:
        """The newest reading, or None if none came within timeout_s."""
        with self._lock:
            latest = self._latest
        if latest is None or self.clock() - latest[0] > self.timeout_s:
            return None
        return latest[1]

    def close(self):
        sub, self._sub = self._sub, None
        if sub is not None:
            try:
                sub.undeclare()
            except Exception:
                _log.debug("undeclare failed", exc_info=True)
        if self._own and self._session is not None:
            self._session.close()
            self._session, self._own = None, False


def _finite(msg: dict, key: str) -> float:
    v = msg[key]
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        raise ValueError(f"{key} = {v!r} is not a finite number")
    return float(v)
