"""What the crawler's drive was seen to do while the wall was measured, for the gap bridge (gaps.py).
Pure: no I/O, no clock.

A crawler's drive holds a speed (its cruise) and ramps between a stand and that speed at its
controller's rate. A start or a brake the camera does not see (a wet wall the encoder flattened, a
blackout) is likelier at the rate this drive's seen ones had than at any fixed guess: taken at the
middle of the rates a drive may have (0.4 m/s^2), a stop-and-go crawler that set off at 0.6 m/s^2
on a wet wall was carried 0.44 s late, 70 mm short over 2.2 s. So each whole ramp the frames show,
from a stand to a held speed or back, is fitted for its rate (`ramp_rate`), and the gap model takes
the last few's median (`DriveWatch.rates`). What the model allows for a rate it did not see (its
sigma) is not narrowed by it: an operator may still brake harder than the drive's ramp.
"""

from __future__ import annotations

import math
from collections import deque
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:                       # (gapmodel takes its rates from here)
    from .gapmodel import BridgeParams, Gap


STILL_M_S = 0.01          # an odometer speed within this is a stand (twice a measured speed's error)
MIN_RAMP_M_S = 0.05       # a cruise slower than this ramps too little to read a rate from
WINDOW_S = 4.0            # the frames kept for a ramp's fit
SIDE_S = 1.0              # ...of the stand and of the cruise, at most this much next to the ramp
KEPT = 3                  # the rates of the last few ramps of each kind; their median is the drive's
HARDEST = 1.2             # a rate beyond this share of hard_accel_m_s2 is no drive's (a jump in the distances)


class DriveWatch:
    """The drive's cruise (the odometer's speed held within 5 % or 1 cm/s for history_s) and the
    rates it was seen to set off and brake at. Fed each measured frame; `lost` at each blind one
    (a ramp is read only where all of it was measured)."""

    def __init__(self, p: BridgeParams):
        self.p = p
        self.cruise = None                  # (t, speed) of the last speed held for history_s
        self._since = None                  # (t, speed) the speed has been held from
        self._held = None                   # (from, to) of the last speed held, not yet braked from
        self._still = None                  # (first, last) frame times of the stand going on
        self._stood = None                  # (first, last) of the last stand held, not yet set off from
        self._frames: deque = deque()       # (t, distance) measured in a row, the last WINDOW_S
        self._period = None                 # the interval between the last two frames measured in a row
        self._first_t = None                # the first frame's time (rates restored belong to its epoch)
        self._rates = {True: deque(maxlen=KEPT), False: deque(maxlen=KEPT)}   # start, brake: (t, rate)

    def rates(self) -> tuple:
        """(start, brake): the median rate of the last ramps seen of each kind (None: none seen)."""
        return tuple(float(np.median([r for _, r in self._rates[k]])) if self._rates[k] else None
                     for k in (True, False))

    def to_dict(self) -> dict:
        """What a restarted daemon keeps (the checkpoint): the rates, not the frames."""
        start, brake = self.rates()
        return {"start_m_s2": start, "brake_m_s2": brake}

    def restore(self, saved: dict):
        """The rates a checkpoint kept (to_dict's); ValueError naming the bad value, rates unchanged."""
        if not isinstance(saved, dict):
            raise ValueError(f"drive = {saved!r} is not a table of rates")
        kept, top = {}, HARDEST * self.p.hard_accel_m_s2
        for key, start in (("start_m_s2", True), ("brake_m_s2", False)):
            r = saved.get(key)
            try:
                ok = r is None or (not isinstance(r, bool) and isinstance(r, (int, float)) and 0 < float(r) <= top)
            except OverflowError:                 # an integer beyond any float
                ok = False
            if not ok:
                raise ValueError(f"drive {key} = {r!r} is no drive's rate (0 to {top:g} m/s^2)")
            kept[start] = r
        for start, r in kept.items():
            self._rates[start].clear()
            if r is not None:
                self._rates[start].append((-math.inf, float(r)))

    def lost(self):
        """A frame not measured: no ramp is read across it (the cruise held is the odometer's
        speed's: it holds across a gap measured across)."""
        self._frames.clear()
        self._held, self._still, self._stood = None, None, None

    def rescaled(self, since: float, scale: float):
        """Tilt auto measured the steps since `since` again: their speeds and rates scale."""
        if self.cruise is not None and self.cruise[0] >= since:
            self.cruise, self._since = (self.cruise[0], self.cruise[1] * scale), None
        for kind in self._rates.values():
            for i, (t, r) in enumerate(kind):
                at = t if t > -math.inf else self._first_t      # (restored: the resumed run's first epoch)
                kind[i] = (t, r * scale if at is not None and at >= since else r)

    def update(self, t: float, d: float, v: float | None, continuous: bool):
        """One measured frame: its time, the odometer's distance and speed. Frames that never came
        (a hole longer than across_s and than one and a half frame periods) are lost frames too."""
        hole = False
        if self._frames:
            dt = t - self._frames[-1][0]
            hole = dt > self.p.across_s + 1e-6 and (self._period is None or dt > 1.5 * self._period)
            self._period = dt
        if not continuous or hole:
            self.lost()
        self._first_t = t if self._first_t is None else self._first_t
        self._frames.append((t, d))
        while self._frames[0][0] < t - WINDOW_S:
            self._frames.popleft()
        if self._track_cruise(t, v if continuous else None) and self._stood is not None:
            self._learn(True, self._stood, self._held)        # a start: from the stand to this speed
            self._stood = None
        if v is None or abs(v) > STILL_M_S:
            self._still = None
            return
        self._still = (t, t) if self._still is None else (self._still[0], t)
        if t - self._still[0] < self.p.history_s:
            return
        if self._held is not None and self._held[1] < self._still[0]:
            self._learn(False, self._still, self._held)       # a brake: from the speed to this stand
        self._stood, self._held = self._still, None

    def _track_cruise(self, t: float, v: float | None) -> bool:
        """Follow the speed held; True: a speed has just been held for history_s."""
        since = self._since
        if v is None or abs(v) < _MIN_CRUISE_M_S:
            self._since = None
        elif since is None or abs(v - since[1]) > max(0.01, 0.05 * abs(since[1])):
            self._since = (t, v)
        elif t - since[0] >= self.p.history_s:
            new = self._held is None or self._held[0] != since[0]
            self.cruise, self._held = (t, v), (since[0], t)
            return new
        return False

    def _learn(self, start: bool, stand: tuple, held: tuple):
        """A ramp between a stand and a held speed (each (first, last) frame times), all measured:
        the SIDE_S of each next to it. Not one ramp where the two are further apart than the
        gentlest drive ramps (a creep between: a stand, 1 s at 0.015 m/s, then a start at 0.6 read
        0.37, a review's case), or where the ramp fits the frames worse than twice their scatter."""
        if start:
            stand, ramp_at = (max(stand[0], stand[1] - SIDE_S), stand[1]), stand[1]
        else:
            held, ramp_at = (max(held[0], held[1] - SIDE_S), held[1]), held[1]
        t = np.array([f[0] for f in self._frames])
        d = np.array([f[1] for f in self._frames])
        lo, hi = min(stand[0], held[0]), max(stand[1], held[1])
        on_stand, on_line = (t >= stand[0]) & (t <= stand[1]), (t >= held[0]) & (t <= held[1])
        if t[0] > lo + 0.1 or on_stand.sum() < 3 or on_line.sum() < 3:
            return
        v, line = np.polyfit(t[on_line], d[on_line], 1)
        between = held[0] - stand[1] if start else stand[0] - held[1]
        if between > abs(v) / self.p.min_drive_accel_m_s2 + self.p.history_s:
            return
        level = float(np.median(d[on_stand]))
        scatter = max(float(np.std(d[on_stand] - level)), float(np.std(d[on_line] - line - v * t[on_line])))
        span = (t >= lo) & (t <= hi)
        rate = ramp_rate(t[span], d[span], level, float(v), float(line), start, self.p, 2 * max(scatter, 5e-4))
        if rate is not None:
            self._rates[start].append((ramp_at, rate))


def ramp_rate(t: np.ndarray, d: np.ndarray, level: float, v: float, line: float, start: bool,
              p: BridgeParams, worst_m: float = np.inf) -> float | None:
    """The rate of a ramp at a constant rate between a stand at distance `level` and a cruise
    d = line + v t (a start: the stand before; a brake: after), fitted to the distances d at t by
    least squares over rates from min_drive_accel_m_s2 to twice hard_accel_m_s2. The cruise's line
    meets the stand's level at the ramp's middle whatever its rate, so the rate is the one unknown.
    None: too slow a cruise to read, the best rate at either end of the range (not resolved) or
    beyond a crawler's (hard_accel_m_s2: a jump), or a fit worse than worst_m r.m.s. (no one ramp)."""
    if abs(v) < MIN_RAMP_M_S:
        return None
    mid = (level - line) / v
    rates = np.geomspace(p.min_drive_accel_m_s2, 2 * p.hard_accel_m_s2, 80)[:, None]
    half = abs(v) / (2 * rates)
    sign = np.sign(v)
    if start:       # still, then up to the line
        into = np.maximum(t - (mid - half), 0.0)
        model = np.where(t < mid + half, level + sign * 0.5 * rates * into * into, line + v * t)
    else:           # the line, then down to a stand
        left = np.maximum(mid + half - t, 0.0)
        model = np.where(t > mid - half, level - sign * 0.5 * rates * left * left, line + v * t)
    sse = ((model - d) ** 2).sum(axis=1)
    best = int(np.argmin(sse))
    if best in (0, len(sse) - 1) or rates[best, 0] > HARDEST * p.hard_accel_m_s2 or sse[best] > len(t) * worst_m ** 2:
        return None
    lo, mid_, hi = sse[best - 1:best + 2]       # the parabola's vertex through the three, in log rate
    curve = lo - 2 * mid_ + hi
    step = 0.5 * (lo - hi) / curve if curve > 0 else 0.0
    return float(rates[best, 0] * (rates[1, 0] / rates[0, 0]) ** step)


def drive_rate(p: BridgeParams, g: Gap, start: bool = True) -> float:
    """The rate a start (or a brake) the frames do not show is taken at: the one this crawler's drive
    was seen at (g.drive, crawler/drive.py; a start's for a brake not seen, and back), else the middle
    of the times the allowed rates take (min_drive_accel_m_s2 to max_accel_m_s2)."""
    seen = seen_rate(g, start)
    return seen if seen is not None else 2.0 / (1.0 / p.max_accel_m_s2 + 1.0 / p.min_drive_accel_m_s2)


def seen_rate(g: Gap, start: bool = True) -> float | None:
    """The rate this drive was seen to start (or brake) at, or else the other (None: neither seen)."""
    seen = [r for r in (g.drive if start else g.drive[::-1]) if r is not None]
    return seen[0] if seen else None


def blurred(seen: float | None, fitted: float) -> bool:
    """Is a rate fitted over the few frames after a gap this drive's ramp (`seen`, of that kind),
    read rough? Those frames move with the car's pitch, and a fit over a ramp's end blurs it weaker:
    down to a third of it, or a quarter harder. A fit harder than that is an operator braking
    harder than the drive's ramp (read at the drive's, a brake at 1.0 m/s^2 lost 52 mm)."""
    return bool(seen) and seen / 3 <= abs(fitted) <= 1.25 * seen


def edge_time(p: BridgeParams, v: float, g: Gap, start: bool = True) -> float:
    """Half the time a start to v (or a brake from it) takes at the drive's rate: what it covers."""
    return abs(v) / (2 * drive_rate(p, g, start))


_MIN_CRUISE_M_S = 0.02            # a speed below this is a crawl or a stand's noise, no cruise
