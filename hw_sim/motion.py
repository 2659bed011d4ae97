"""Ground-truth motion: analytic distance(t) and speed(t), and the disturbance signals.

Profiles are sums of trapezoids (rest -> cruise -> rest at a fixed acceleration), so distance and
speed are exact closed forms that accept arrays; nothing is integrated numerically.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Trapezoid:
    """From rest at t0 to signed cruise speed v at accel a, then braking to rest at t0 + T.

    If T is too short to reach |v|, the peak is lower (a triangle).
    """
    t0: float
    T: float
    v: float
    a: float

    @property
    def ramp(self) -> float:
        return min(abs(self.v) / self.a, self.T / 2) if self.a > 0 else 0.0

    @property
    def peak(self) -> float:
        return math.copysign(self.a * self.ramp, self.v) if self.a > 0 else self.v

    @property
    def length(self) -> float:
        """Signed distance covered."""
        return self.peak * (self.T - self.ramp)

    def distance(self, t: np.ndarray) -> np.ndarray:
        tau = np.clip(t - self.t0, 0.0, self.T)
        ta, vp, T = self.ramp, self.peak, self.T
        acc = vp / ta if ta > 0 else 0.0
        up = 0.5 * acc * tau**2
        cruise = 0.5 * vp * ta + vp * (tau - ta)
        down = self.length - 0.5 * acc * (T - tau) ** 2
        return np.where(tau < ta, up, np.where(tau <= T - ta, cruise, down))

    def speed(self, t: np.ndarray) -> np.ndarray:
        tau = t - self.t0
        ta, vp, T = self.ramp, self.peak, self.T
        acc = vp / ta if ta > 0 else 0.0
        v = np.where(tau < ta, acc * tau, np.where(tau <= T - ta, vp, acc * (T - tau)))
        return np.where((tau < 0) | (tau > T), 0.0, v)


class Motion:
    """distance(t), speed(t) of one profile; t may be a scalar or an array, before 0 or after the end.

    constant: v from before t = 0 on (so blur at t = 0 is consistent); the others start and end at
    rest, and stay at rest outside [0, duration].
    """

    def __init__(self, profile: str, speed: float, duration: float, accel: float = 0.5,
                 stopgo_period: float = 2.0, stopgo_dwell: float = 0.5):
        self.profile, self.v, self.duration = profile, speed, duration
        self.segments: list[Trapezoid] = []
        if profile == "constant":
            return
        if profile == "accel":
            self.segments = [Trapezoid(0.0, duration, speed, accel)]
        elif profile == "stopgo":
            t = 0.0
            while t < duration - 1e-12:
                go = min(stopgo_period - stopgo_dwell, duration - t)
                self.segments.append(Trapezoid(t, go, speed, accel))
                t += stopgo_period
        elif profile == "reverse":
            # forward for 40 % of the run, back for 60 %: ends behind the start
            t1 = 0.4 * duration
            self.segments = [Trapezoid(0.0, t1, speed, accel), Trapezoid(t1, duration - t1, -speed, accel)]
        else:
            raise ValueError(f"profile={profile!r} is unknown")
        # segments are disjoint and in time order: a long live run (a day of stop-and-go is 43200
        # segments) must evaluate only the ones around t
        self._starts = np.array([s.t0 for s in self.segments])
        self._ends = self._starts + np.array([s.T for s in self.segments])
        self._before = np.concatenate([[0.0], np.cumsum([s.length for s in self.segments])])

    def _around(self, t: np.ndarray):
        """(distance of the segments finished before t.min(), the segments overlapping t)."""
        i0 = int(np.searchsorted(self._ends, t.min(), "left"))
        i1 = int(np.searchsorted(self._starts, t.max(), "right"))
        return self._before[i0], self.segments[i0:max(i0, i1)]

    def distance(self, t):
        t = np.asarray(t, dtype=np.float64)
        if self.profile == "constant":
            out = self.v * t
        else:
            done, active = self._around(t)
            out = sum((s.distance(t) for s in active), np.full_like(t, done))
        return float(out) if out.ndim == 0 else out

    def speed(self, t):
        t = np.asarray(t, dtype=np.float64)
        if self.profile == "constant":
            out = np.full_like(t, self.v)
        else:
            _, active = self._around(t)
            out = sum((s.speed(t) for s in active), np.zeros_like(t))
        return float(out) if out.ndim == 0 else out

    @property
    def max_speed(self) -> float:
        if self.profile == "constant":
            return abs(self.v)
        return max((abs(s.peak) for s in self.segments), default=0.0)

    def path_length(self) -> float:
        """Distance travelled counting both directions, over [0, duration]."""
        if self.profile == "constant":
            return abs(self.v) * self.duration
        return sum(abs(s.length) for s in self.segments)


def sine(t, amp: float, hz: float, phase: float = 0.0):
    """amp * sin(2 pi hz t + phase); zero when amp is 0."""
    return amp * np.sin(2 * np.pi * hz * np.asarray(t, dtype=np.float64) + phase)


def jitter(t, peak: float, hz: float, seed: int, salt: int):
    """Smooth quasi-random signal with |x| <= peak: three incommensurate sines, seeded phases."""
    if peak == 0:
        return np.zeros_like(np.asarray(t, dtype=np.float64))
    ph = np.random.default_rng([seed, salt]).uniform(0, 2 * np.pi, 3)
    w = (1.0, 0.6, 0.35)
    f = (1.0, 1.618034, 2.414214)
    x = sum(wi * np.sin(2 * np.pi * hz * fi * np.asarray(t, dtype=np.float64) + p)
            for wi, fi, p in zip(w, f, ph))
    return peak * x / sum(w)
