"""The wheel's readings on the frame clock: unwrapped, and interpolated to each frame's time. Pure.

A poll after the frame (kernel, gpiozero) puts the frame's exposure between two readings; a
controller's messages (Zenoh) may be older than the frame, which is then extrapolated at the
wheel's last rate (up to horizon_s). A frame before every reading is settled once the second
reading allows extrapolating back to it.
"""

from __future__ import annotations

from collections import deque


def _wrap(dp: float, period: float | None) -> float:
    if period:
        return (dp + 0.5 * period) % period - 0.5 * period
    return dp


class WheelTimeline:
    """Cumulative nominal wheel distance w(t) from WheelReadings."""

    def __init__(self):
        self.epoch = None
        self.raw = 0.0            # the last reading's position (wraps with period)
        self.period = None
        self.w = 0.0              # unwrapped, cumulative since this filter started
        self.ring: deque[tuple[float, float]] = deque(maxlen=8)
        self.mismatch = None      # (frame t, reading t) the first time they were > 1 s apart
        self.horizon_s = 0.25     # a frame this much after the newest reading is extrapolated to

    def resume(self, epoch: str, position_m: float, period_m: float | None):
        """Continue from a saved reading: the next one of the same epoch unwraps against it."""
        self.epoch, self.raw, self.period, self.w = epoch, position_m, period_m, 0.0
        self.ring.clear()

    def ingest(self, r) -> bool:
        """Add a reading; False if it comes from a counter that restarted (another epoch)."""
        same = r.epoch == self.epoch
        if same:
            self.w += _wrap(r.position_m - self.raw, r.period_m)
        else:
            self.epoch = r.epoch
            self.ring.clear()
        self.raw, self.period = r.position_m, r.period_m
        ring = self.ring
        if ring and r.t_s <= ring[-1][0]:
            if r.t_s == ring[-1][0]:
                ring[-1] = (r.t_s, self.w)
        else:
            ring.append((r.t_s, self.w))
        return same

    def at(self, t: float) -> tuple[float, bool]:
        """(w at frame time t, whether t came before every reading and took the first one's value)."""
        ring = self.ring
        t1, w1 = ring[-1]
        if t >= t1:
            if t - t1 > 1.0:
                if self.mismatch is None:
                    self.mismatch = (t, t1)
                return w1, False
            if len(ring) > 1 and t - t1 <= self.horizon_s:   # a reading older than the frame
                t0, w0 = ring[-2]
                return w1 + (w1 - w0) * (t - t1) / (t1 - t0), False
            return w1, False
        t0, w0 = ring[0]
        if t <= t0:
            if t0 - t > 1.0:
                if self.mismatch is None:
                    self.mismatch = (t, t0)
                return w1, False
            return w0, t < t0
        for i in range(len(ring) - 1, 0, -1):
            ta, wa = ring[i - 1]
            if ta <= t:
                tb, wb = ring[i]
                return wa + (wb - wa) * (t - ta) / (tb - ta), False
        return w0, False

    def extrapolate(self, t: float) -> float | None:
        """w at a time before every reading, from the first two; None until there are two."""
        if len(self.ring) < 2:
            return None
        (t0, w0), (t1, w1) = self.ring[0], self.ring[1]
        return w0 + (w1 - w0) * (t - t0) / (t1 - t0)

    def raw_at(self, w: float) -> float:
        """The reading's position at cumulative distance w (for saving the frame's position)."""
        return self.raw - (self.w - w)
