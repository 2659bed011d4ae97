"""When the fake camera's frames exist and where they go: the sensor's clock and the buffers.

The sensor runs on its own: frame k starts at SensorTimestamp ts(k) and completes one mode readout
later, whatever the application does. At each completion (processed in time order, lazily, before
any application action changes the state) the frame needs a buffer queued in libcamera, that is
one that neither the application nor picamera2's "latest request" slot holds; then it goes to the
oldest timed-out capture (picamera2 keeps those queued), else to a waiting capture, else (queue
True) it replaces the latest completed request, else it is recycled. Which frames an application
gets therefore depends only on the clock and on when it captures and releases, never on how long
hw_sim takes to render.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np


@dataclass(frozen=True)
class FrameSettings:
    """What one frame is made with."""
    crop: tuple[int, int, int, int]     # the effective ScalerCrop, native pixels
    exposure_us: int
    gain: float
    period_ns: int


@dataclass
class FrameCounts:
    """Frames of a SimWorld's cameras, by fate."""
    delivered: int = 0       # handed to the application by a capture
    dropped: int = 0         # completed, but replaced by a newer one or no buffer was free
    lost: int = 0            # never completed: stall, drop_prob, dropped_bursts
    orphaned: int = 0        # taken by a timed-out capture (picamera2 keeps it queued)
    rendered_late: int = 0   # pixels the consumer had to render: the camera thread was behind
    max_buffers_in_use: int = 0


class Timeline:
    """Frame k -> SensorTimestamp, as segments (first k, its timestamp, settings) of one duration."""

    def __init__(self, ts0: int, settings: FrameSettings):
        self.segs: list[tuple[int, int, FrameSettings]] = [(0, ts0, settings)]

    def seg(self, k: int) -> tuple[int, int, FrameSettings]:
        return next((s for s in reversed(self.segs) if s[0] <= k), self.segs[0])

    def settings(self, k: int) -> FrameSettings:
        return self.seg(k)[2]

    def ts(self, k: int) -> int:
        k0, ts0, st = self.seg(k)
        return ts0 + (k - k0) * st.period_ns

    def k_at(self, t_ns: int) -> int:
        """The newest frame whose SensorTimestamp is <= t_ns."""
        for k0, ts0, st in reversed(self.segs):
            if t_ns >= ts0:
                return k0 + int((t_ns - ts0) // st.period_ns)
        return self.segs[0][0] - 1

    def change(self, k: int, settings: FrameSettings, keep_from: int) -> None:
        """Frames from k on use `settings`; segments wholly before frame keep_from are forgotten."""
        segs = [s for s in self.segs if s[0] < k] + [(k, self.ts(k), settings)]
        while len(segs) > 1 and segs[1][0] <= keep_from:
            segs.pop(0)
        self.segs = segs

    def span(self, k: int, t_ns: int) -> np.ndarray:
        """Frames k, k+1, ... of k's segment whose SensorTimestamp is <= t_ns."""
        i = next(i for i in range(len(self.segs) - 1, -1, -1) if self.segs[i][0] <= k)
        k0, ts0, st = self.segs[i]
        last = k0 + (t_ns - ts0) // st.period_ns if t_ns >= ts0 else k - 1
        if i + 1 < len(self.segs):
            last = min(last, self.segs[i + 1][0] - 1)
        return np.arange(k, int(last) + 1)


@dataclass
class _Waiter:
    flush: int | None
    frame: int | None = None


@dataclass
class FrameQueue:
    """The buffers of one started camera: what completes, who holds what (see the module doc)."""
    timeline: Timeline
    latency_ns: int                     # SensorTimestamp -> the buffer is complete
    buffer_count: int
    queue: bool                         # picamera2 keeps the latest completed request
    lost: Callable[[np.ndarray, np.ndarray], np.ndarray]   # (frames, timestamps) -> never completed
    counts: FrameCounts
    next_k: int = 0                     # the first frame not yet completed (or lost)
    kept: int | None = None             # picamera2's latest completed request
    app_held: int = 0                   # requests the application (and orphans) hold
    orphans: int = 0                    # timed-out captures still queued
    waiters: list[_Waiter] = field(default_factory=list)

    def completion_ns(self, k: int) -> int:
        return self.timeline.ts(k) + self.latency_ns

    def exposed_after(self, k: int, flush: int | None) -> bool:
        return flush is None or self.timeline.ts(k) - 1000 * self.timeline.settings(k).exposure_us >= flush

    @property
    def in_use(self) -> int:
        return self.app_held + (self.kept is not None)

    def advance(self, now: int) -> None:
        """Complete, in order, every frame whose buffer is done by `now`."""
        while self.completion_ns(self.next_k) <= now:
            ks = self.timeline.span(self.next_k, now - self.latency_ns)
            ts = np.array([self.timeline.ts(int(ks[0]))]) + (ks - ks[0]) * self.timeline.settings(int(ks[0])).period_ns
            gone = self.lost(ks, ts)
            self.counts.lost += int(gone.sum())
            self._complete_all([int(k) for k in ks[~gone]])
            self.next_k = int(ks[-1]) + 1

    def _complete_all(self, good: list[int]) -> None:
        for i, k in enumerate(good):
            if not (self.orphans or self.waiters) and (self.kept is not None or not self.queue):
                rest = len(good) - i        # steady state: each replaces the last, or finds no buffer
                self.counts.dropped += rest - 1
                self._complete(good[-1])
                return
            self._complete(k)

    def _complete(self, k: int) -> None:
        if self.in_use >= self.buffer_count:
            self.counts.dropped += 1        # no buffer queued in libcamera: the frame is lost to us
            return
        if self.orphans:
            self.orphans -= 1
            self.app_held += 1
            self.counts.orphaned += 1
        else:
            w = next((w for w in self.waiters if self.exposed_after(k, w.flush)), None)
            if w is not None:
                w.frame = k
                self.waiters.remove(w)
                self.app_held += 1
            elif self.queue:
                if self.kept is not None:
                    self.counts.dropped += 1
                self.kept = k
            else:
                self.counts.dropped += 1
        self.counts.max_buffers_in_use = max(self.counts.max_buffers_in_use, self.in_use)

    def take_kept(self, flush: int | None) -> int | None:
        """The latest completed request, if it was exposed after `flush`: its buffer passes to the app."""
        k = self.kept
        if k is None or not self.exposed_after(k, flush):
            return None
        self.kept, self.app_held = None, self.app_held + 1
        return k

    def wait(self, flush: int | None) -> _Waiter:
        w = _Waiter(flush)
        self.waiters.append(w)
        return w

    def give_up(self, w: _Waiter) -> None:
        """A capture timed out: picamera2 leaves its job queued, to take the next frame for good."""
        if w in self.waiters:
            self.waiters.remove(w)
            self.orphans += 1

    def release(self) -> None:
        self.app_held -= 1

    def keep_from(self) -> int:
        """The oldest frame whose settings may still be asked for."""
        return self.next_k if self.kept is None else min(self.kept, self.next_k)
