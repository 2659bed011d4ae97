"""A wheel encoder with exact ground truth, and the hardware it is read through.

SimEncoder turns the true distance (any callable of time, e.g. Motion.distance) into quadrature edge
counts: a scale error (true counts per metre over nominal), slip intervals in which the wheel turns
`slip_gain` faster than the ground moves, and quantisation. It counts on the (injectable) clock, not
on reads, so it goes on counting while a daemon is down, as the kernel's driver does.

It is read through the same backends as the real wheel:
  FakeInputDevice  python-evdev's InputDevice as far as crawlerd uses it (absinfo, read_one, read,
                   fd, capabilities, name, path, close), with the kernel rotary-encoder driver's
                   position (absolute axis with rollover) or its relative events (lost while closed,
                   a 64-event buffer that overflows into SYN_DROPPED)
  QuadratureDriver drives gpiozero MockFactory pins with the A/B edge sequence (pulled up: active low)
VisionModel makes vision estimates (truth + noise, held through featureless stretches) for testing a
fusion without rendering. Shares no code with crawler/ (the instrument stays independent).
"""
from __future__ import annotations

import errno
import math
import os
import time
from typing import NamedTuple

import numpy as np

# linux/input-event-codes.h (a stable kernel ABI)
EV_SYN, EV_REL, EV_ABS = 0x00, 0x02, 0x03
SYN_REPORT, SYN_DROPPED = 0, 3

try:   # the real classes when python-evdev is there, so the fake hands out what evdev would
    from evdev import AbsInfo, InputEvent
except ImportError:   # pragma: no cover - exercised on the ARM yardstick, which has no evdev
    class AbsInfo(NamedTuple):
        value: int
        min: int
        max: int
        fuzz: int
        flat: int
        resolution: int

    class InputEvent:
        def __init__(self, sec, usec, type, code, value):
            self.sec, self.usec, self.type, self.code, self.value = sec, usec, type, code, value

        def timestamp(self):
            return self.sec + self.usec / 1e6


class SimEncoder:
    """Quadrature edges (4 per encoder period) of a wheel rolling along `distance(t)`.

    counts_per_m: nominal edges per metre (what [wheel] counts_per_m would say for an x4 decoder);
    scale: true edges per metre / nominal (a worn or loaded wheel); slip: (start_s, end_s) intervals.
    The count is 0 at t_boot (the kernel driver starts at 0 when it loads).
    """

    def __init__(self, distance, *, counts_per_m: float = 5000.0, scale: float = 1.0,
                 slip=(), slip_gain: float = 0.2, direction: int = 1, clock=time.monotonic,
                 t_boot: float | None = None, seed: int = 0):
        if not counts_per_m > 0 or not scale > 0:
            raise ValueError(f"counts_per_m = {counts_per_m}, scale = {scale} must be > 0")
        self.distance = distance
        self.counts_per_m, self.scale, self.slip_gain, self.direction = counts_per_m, scale, slip_gain, direction
        self.slip = tuple((float(a), float(b)) for a, b in slip)
        if any(not a < b for a, b in self.slip):
            raise ValueError(f"slip = {slip!r}: each interval needs start < end")
        self.clock = clock
        self.phase = float(np.random.default_rng(seed).uniform(0.0, 1.0))
        self.t_boot = clock() if t_boot is None else t_boot
        self._origin = 0
        self._origin = self.edges_at(self.t_boot)

    def wheel_m(self, t):
        """Metres the wheel's rim has rolled by time t: ground distance plus the slip's extra."""
        t = np.asarray(t, dtype=np.float64)
        out = np.asarray(self.distance(t), dtype=np.float64)
        for a, b in self.slip:
            out = out + self.slip_gain * (np.asarray(self.distance(np.clip(t, a, b))) - self.distance(a))
        return float(out) if out.ndim == 0 else out

    def edges_at(self, t) -> int:
        x = self.direction * self.counts_per_m * self.scale * self.wheel_m(t) + self.phase
        return int(math.floor(x)) - self._origin

    def edges(self) -> int:
        """The count now, on the clock."""
        return self.edges_at(self.clock())

    def reset(self, t_boot: float | None = None):
        """A reboot: the driver starts from 0 again."""
        self.t_boot = self.clock() if t_boot is None else t_boot
        self._origin = 0
        self._origin = self.edges_at(self.t_boot)


class FakeInputDevice:
    """/dev/input/eventN of the kernel's rotary-encoder driver on a SimEncoder.

    absolute: the kernel's position, counts mod steps (rollover=1), readable at any time (EVIOCGABS);
    else relative: REL events of the steps made while this device is open, into a 64-event buffer.
    steps_per_period: the overlay's steps-per-period (4 counts every edge, 1 every full period).
    """

    BUFFER = 64

    def __init__(self, encoder: SimEncoder, *, absolute: bool = True, steps: int = 1 << 30,
                 steps_per_period: int = 4, axis: int = 0, name: str = "rotary@11",
                 path: str = "/dev/input/event0"):
        if steps_per_period not in (1, 2, 4):
            raise ValueError(f"steps_per_period = {steps_per_period} must be 1, 2 or 4")
        self.encoder, self.absolute, self.steps, self.axis = encoder, absolute, int(steps), axis
        self.steps_per_period = steps_per_period
        self.name, self.path = name, path
        self.fd = os.open(os.devnull, os.O_RDONLY)
        self._closed = self._unplugged = False
        self._seen = self._count()        # relative events start when the device is opened
        self._queue: list = []

    def _count(self) -> int:
        return (self.encoder.edges() * self.steps_per_period) // 4

    def _check(self):
        if self._unplugged:
            raise OSError(errno.ENODEV, "No such device")
        if self._closed:
            raise OSError(errno.EBADF, "Bad file descriptor")

    def capabilities(self, verbose: bool = False, absinfo: bool = True):
        self._check()
        if self.absolute:
            return {EV_SYN: [SYN_REPORT, EV_ABS],
                    EV_ABS: [(self.axis, self.absinfo(self.axis)) if absinfo else self.axis]}
        return {EV_SYN: [SYN_REPORT, EV_REL], EV_REL: [self.axis]}

    def absinfo(self, axis_num: int):
        self._check()
        if not self.absolute or axis_num != self.axis:
            raise OSError(errno.EINVAL, "Invalid argument")
        return AbsInfo(self._count() % self.steps, 0, self.steps, 0, 0, 0)

    def _refill(self):
        """Queue the events of the steps since the last look, as the kernel would (newest kept)."""
        count = self._count()
        n, self._seen = count - self._seen, count
        if n == 0:
            return
        now = time.time()
        sec, usec = int(now), int((now % 1) * 1e6)
        sign, keep = (1 if n > 0 else -1), min(abs(n), self.BUFFER // 2)
        start = count - sign * keep
        for i in range(1, keep + 1):
            if self.absolute:
                ev = InputEvent(sec, usec, EV_ABS, self.axis, (start + sign * i) % self.steps)
            else:
                ev = InputEvent(sec, usec, EV_REL, self.axis, sign)
            self._queue += [ev, InputEvent(sec, usec, EV_SYN, SYN_REPORT, 0)]
        if keep < abs(n) or len(self._queue) > self.BUFFER:
            self._queue = [InputEvent(sec, usec, EV_SYN, SYN_DROPPED, 0)] + self._queue[-(self.BUFFER - 2):]

    def read_one(self):
        """The next event, or None (non-blocking, as InputDevice opens the node)."""
        self._check()
        self._refill()
        return self._queue.pop(0) if self._queue else None

    def read(self):
        """All pending events; BlockingIOError when there are none."""
        self._check()
        self._refill()
        if not self._queue:
            raise BlockingIOError(errno.EAGAIN, "Resource temporarily unavailable")
        events, self._queue = self._queue, []
        return iter(events)

    def unplug(self):
        """The device goes away (a loose connector, the module unloaded)."""
        self._unplugged = True

    def close(self):
        if not self._closed:
            self._closed = True
            os.close(self.fd)


class QuadratureDriver:
    """Drives two MockFactory pins with the SimEncoder's edges up to the clock's now.

    Channels pulled up and switched to ground, as gpiozero's RotaryEncoder expects: a channel is
    active (low) for half its period, B a quarter period behind A when moving forward. Build it
    after the RotaryEncoder: its pull-up drives the pins high when it claims them.
    """

    _PHASES = ((0, 0), (1, 0), (1, 1), (0, 1))      # (A, B) active, per quarter period forward

    def __init__(self, encoder: SimEncoder, pin_a, pin_b):
        self.encoder, self.pins = encoder, (pin_a, pin_b)
        self.position = encoder.edges()
        for pin, active in zip(self.pins, self._PHASES[self.position % 4]):
            pin.drive_low() if active else pin.drive_high()

    def sync(self) -> int:
        """Emit every edge between the last sync and now; returns how many."""
        target = self.encoder.edges()
        n = abs(target - self.position)
        step = 1 if target > self.position else -1
        phases = self._PHASES
        while self.position != target:
            before = phases[self.position % 4]
            self.position += step
            after = phases[self.position % 4]
            for pin, a, b in zip(self.pins, before, after):
                if a != b:
                    pin.drive_low() if b else pin.drive_high()
        return n


class SimVisionFix(NamedTuple):
    t_s: float
    distance_m: float
    sigma_m: float | None
    tracking: bool
    bridged: bool


class VisionModel:
    """Vision estimates like the odometer's: keyframe-relative noise, held through blind stretches.

    While tracking, the distance follows the truth times (1 + scale_error) plus white noise sigma_m
    and a random walk of keyframe_sigma at each keyframe (every keyframe_every frames). In a
    featureless interval (seconds) it reports tracking=False and holds (or, with bridge=True,
    extrapolates the last speed); the first frame after it is a new keyframe, still reported lost.
    """

    def __init__(self, distance, *, sigma_m: float = 3e-5, keyframe_every: int = 10,
                 keyframe_sigma: float = 2e-5, scale_error: float = 0.0, featureless=(),
                 bridge: bool = False, seed: int = 1):
        self.distance, self.sigma_m, self.keyframe_every = distance, sigma_m, keyframe_every
        self.keyframe_sigma, self.scale_error, self.bridge = keyframe_sigma, scale_error, bridge
        self.featureless = tuple(featureless)
        self.rng = np.random.default_rng(seed)
        self._base = None           # (reported distance, true distance) at the current keyframe
        self._walk = 0.0
        self._frames = 0
        self._last = None           # (t, distance, speed) of the last estimate

    def blind(self, t: float) -> bool:
        return any(a <= t < b for a, b in self.featureless)

    def estimate(self, t: float) -> SimVisionFix:
        s = float(self.distance(t))
        if self.blind(t):
            self._base = None
            if self._last is None:
                return SimVisionFix(t, 0.0, None, False, False)
            t0, d0, v0 = self._last
            d = d0 + v0 * (t - t0) if self.bridge else d0
            return SimVisionFix(t, d, (0.2 * abs(v0) + 1e-3) * (t - t0) if self.bridge else None,
                                False, self.bridge)
        if self._base is None:     # a new keyframe: counting from the held distance
            first = self._last is None
            d0 = 0.0 if first else self._last[1]
            self._base, self._frames = (d0, s), 0
            self._last = (t, d0, 0.0)
            # the run's first frame tracks (its keyframe has features); after a blind stretch the
            # odometer renews its keyframe on a frame it reports as lost
            return SimVisionFix(t, d0, self.sigma_m if first else None, first, False)
        self._frames += 1
        if self._frames % self.keyframe_every == 0:
            self._walk += self.rng.normal(0.0, self.keyframe_sigma)
        d = (self._base[0] + (1 + self.scale_error) * (s - self._base[1]) + self._walk
             + self.rng.normal(0.0, self.sigma_m))
        t0, d0, _ = self._last
        self._last = (t, d, (d - d0) / (t - t0) if t > t0 else 0.0)
        return SimVisionFix(t, d, self.sigma_m, True, False)
