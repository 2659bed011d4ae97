"""How the tilt estimate moves: a mount that creeps, and an operator who turns the camera. Pure.

crawler/pose.py keeps the tilt in its Kalman state (a random walk: tape and clamps creep). A turn of
the camera is a step, which a random walk slow enough to average the noise would take seconds to
follow. So every frame's own tilt reading (the tilt that would make its far and near features agree,
with nothing but this frame) is compared with the estimate, and a two-sided CUSUM of the normalised
differences finds a step within a few frames of motion. It also says when the step began (the last
time the sums stood at zero), so the distance measured since then can be measured again at the new
tilt (docs/odometry.md, "Pose").
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class TiltParams:
    start_sigma_deg: float = 20.0      # "auto" from a cold start: anything from looking up to far ahead
    step_sigma_deg: float = 5.0        # after a detected step the new tilt is this uncertain
    cusum_slack: float = 1.0           # readings within this many sigmas are noise...
    cusum_limit: float = 12.0          # ...and this much summed excess is a step
    jump_deg: float = 3.0              # two keyframes' readings in a row this far off, the same way
    jump_sigmas: float = 4.0           # ...and this many times the readings' scatter: a step at once,
    own_sigmas: float = 2.0            # ...and this many times each reading's own sigma (AutoTilt._reading)
    outlier_sigmas: float = 3.0        # a reading this far off feeds the step detector only
    converged_deg: float = 0.1         # the estimate counts as found below this sigma
    memory: float = 0.98               # weight a keyframe's reading keeps per later reading (a creeping mount)


class StepDetector:
    """Two-sided CUSUM of normalised tilt innovations."""

    def __init__(self, params: TiltParams | None = None):
        self.p = params or TiltParams()
        self.steps = 0
        self.reset()

    def reset(self):
        self._up = self._down = 0.0
        self._quiet_since = None        # when the sums last stood at zero: a step began after it

    def update(self, nu: float, t_s: float) -> float | None:
        """One normalised innovation at t_s; a step returns the time it began."""
        k = self.p.cusum_slack
        self._up = max(0.0, self._up + nu - k)
        self._down = max(0.0, self._down - nu - k)
        if (self._up == 0.0 and self._down == 0.0) or self._quiet_since is None:
            self._quiet_since = t_s
        if max(self._up, self._down) <= self.p.cusum_limit:
            return None
        return self.jumped(t_s)

    def jumped(self, t_s: float) -> float:
        """A step: when it began (the last time the sums stood at zero, or now)."""
        began = t_s if self._quiet_since is None else self._quiet_since
        self.steps += 1
        self.reset()
        return began


class TiltTrack:
    """The tilt once found. Each keyframe gives the parabola of its features' disagreement about the
    estimate; the parabolas are summed, forgetting slowly (a mount that creeps), and the sum's
    least is the tilt: a keyframe counts as its parabola says (crawler/autotilt.py weighs it by
    travel). Each keyframe's own least, against the estimate, feeds the step detector and the
    estimate's scatter. The estimate's variance is the readings' long-run variance over their
    count: consecutive readings share a frame (one's close is the next one's start), so a pitch
    there pushes them apart by as much, and the errors of their mean cancel: the scatter plus twice
    the lag-one covariance, but at least a tenth of the scatter (the covariance is itself read from
    few readings)."""

    def __init__(self, value: float, params: TiltParams | None = None, sigma: float = 0.0, checked: bool = False):
        self.p = params or TiltParams()
        self._checked = checked               # the value is known (a sweep's line): a jump counts from
                                              # the first reading (two in a row beyond it: a step)
        self.detector = StepDetector(self.p)
        self.ref = self.value = value
        self._a = self._b = 0.0               # summed parabola, in (tilt - ref)
        self._scatter = sigma * sigma         # of one keyframe's least about the estimate
        self._lag = 0.0                       # ...and the mean product of two consecutive readings' deviations
        self._dev = None                      # the last reading's deviation
        self._jumped = (0, 0.0)               # the last reading beyond a jump: its side and time
        self._n = 0.0

    @property
    def var(self) -> float:
        return max(self._scatter + 2.0 * self._lag, 0.1 * self._scatter) / max(self._n, 1.0)

    def add(self, a: float, slope: float, at: float, t_s: float, sigma: float = 0.0) -> float | None:
        """A keyframe's parabola: curvature a (per rad^2) and slope at tilt `at`, and the reading's
        own sigma; a step returns when it began. A reading beyond a jump but within own_sigmas of
        its own sigma says nothing (a wet edge's: 4 deg off at 4-7 deg of its own, two in a row
        took a still camera for a turn, and the keyframe the new tilt forced read a stand: -29.9 %)."""
        if not (math.isfinite(a) and math.isfinite(slope) and a > 0):
            return None
        raw = at - slope / (2 * a)
        jump = max(math.radians(self.p.jump_deg), self.p.jump_sigmas * math.sqrt(self._scatter))
        least = float(np.clip(raw, self.value - jump, self.value + jump))
        if self._n >= 3 or self._checked:
            side = 0 if abs(raw - self.value) <= jump else (1 if raw > self.value else -1)
            if side:                               # no mount creeps this far in a keyframe: a turn, if
                if abs(raw - self.value) <= self.p.own_sigmas * sigma:
                    return None                    # (unless the reading is too unsure of itself)
                if side == self._jumped[0]:        # the next keyframe says so too (one shake does not)
                    return self.detector.jumped(self._jumped[1])
                self._jumped = (side, t_s)
                return None
            self._jumped = (0, t_s)
        if self._n >= 3:
            nu = (least - self.value) / math.sqrt(self._scatter + self.var)
            began = self.detector.update(nu, t_s)
            if began is not None:
                return began
            if abs(nu) > self.p.outlier_sigmas:    # a step in the making is not averaged in
                return None
        keep = self.p.memory
        u = at - self.ref
        self._a = keep * self._a + a
        self._b = keep * self._b + slope - 2 * a * u
        self._n = keep * self._n + 1.0
        dev, rate = least - self.value, min(self._n + 1.0, 1.0 / (1.0 - keep))
        self._scatter += (dev * dev - self._scatter) / rate
        if self._dev is not None:
            self._lag += (dev * self._dev - self._lag) / rate
        self._dev = dev
        self.value = self.ref - self._b / (2 * self._a)
        return None


class SweepWatch:
    """A camera turned slowly (a sweep: too slow for a step, too fast for a mount's creep). The
    readings of the last `window_s` (at least `min_readings`, over up to twice that, none
    `max_hole_s` apart: a stand or a gap between readings is no turn) trend along a line beyond
    `t_sweep` of its own standard error and `min_rate_deg_s`: the tilt is moving, and is the line's
    value now. It stops once the trend is within `t_still` of its error, or two plain readings in a
    row leave the line by max(4 of its sigmas, `off_line_deg`). On a still or shaking car
    the trend's t stays under 3.5 (docs/odometry.md, "Sweeps"); a clean sweep at 0.75 deg/s reads 18."""

    def __init__(self, window_s: float = 1.0, min_readings: int = 5, t_sweep: float = 8.0, t_still: float = 3.0,
                 min_rate_deg_s: float = 0.3, floor_deg: float = 0.05, max_own_deg: float = 1.0,
                 min_span_s: float = 0.5, max_hole_s: float = 0.5, off_line_deg: float = 0.5):
        self.window_s, self.min_readings, self.min_span_s = window_s, min_readings, min_span_s
        self.max_own, self.max_hole_s = math.radians(max_own_deg), max_hole_s
        self.t_sweep, self.t_still = t_sweep, t_still
        self.min_rate, self.floor = math.radians(min_rate_deg_s), math.radians(floor_deg)
        self.readings: list = []          # (t, tilt, level) of recent readings
        self.moving = False
        self.off_line = math.radians(off_line_deg)
        self._misses = 0                  # plain readings in a row off the line while moving
        self.line = None                  # (t, tilt then, rate, its sigma) while moving

    def add(self, t_s: float, tilt: float, level: float | None = None, own_sigma: float = 0.0) -> bool:
        """One reading; True while the camera moves (then `line` holds its fit). `level`: the same
        reading with the keyframe at the tilt the line gave it (the rate is read from the plain
        readings, whose lag a steady turn keeps nearly constant: read from the corrected ones, the
        correction fed back, and the rate ran away). A reading unsure of itself beyond
        `max_own_deg` says nothing, and a trend over less than `min_span_s` is none: at CRF 40 five
        keyframes of 0.14 s, each 3 deg unsure, read 25.6 to 29.8 deg on a still camera."""
        if own_sigma > self.max_own:
            return self.moving
        if self.moving and self._off_line(t_s, tilt):   # the turn stopped (or jumped): over
            self._misses += 1
            if self._misses >= 2:
                self.readings = self.readings[-1:]
                self.moving, self.line, self._misses = False, None, 0
        else:
            self._misses = 0
        self.readings.append((t_s, tilt, tilt if level is None else level))
        while len(self.readings) > self.min_readings and t_s - self.readings[0][0] > self.window_s:
            self.readings.pop(0)
        while t_s - self.readings[0][0] > 2.0 * self.window_s:
            self.readings.pop(0)
        t = [r[0] for r in self.readings]
        if (len(t) < self.min_readings or t[-1] - t[0] < self.min_span_s
                or max(b - a for a, b in zip(t, t[1:])) > self.max_hole_s):   # a stand or a gap between: none
            self.moving, self.line = False, None
            return False
        t, y, lv = np.array(self.readings).T
        tc = t - t.mean()
        sxx = float(tc.dot(tc))
        rate = float(tc.dot(y)) / sxx
        fit = y.mean() + rate * tc
        s2 = max(float(np.sum((y - fit) ** 2)) / (len(y) - 2), self.floor ** 2)
        t_stat = abs(rate) / math.sqrt(s2 / sxx)
        if t_stat >= self.t_sweep and abs(rate) >= self.min_rate:
            self.moving = True
        elif t_stat < self.t_still:
            self.moving = False
        self.line = (t_s, float(lv.mean() + rate * tc[-1]), rate, math.sqrt(s2)) if self.moving else None
        return self.moving

    def _off_line(self, t_s: float, tilt: float) -> bool:
        """A plain reading beyond max(4 of the line's sigmas, 0.5 deg) off the line through the plain
        readings: a turn that has stopped (the fitted rate rose as the lag went, and the tilt ran
        on past the end: 43.5 deg for 40) or jumped."""
        t, y = np.array([r[0] for r in self.readings]), np.array([r[1] for r in self.readings])
        rate, s = self.line[2], self.line[3]
        return abs(tilt - (y.mean() + rate * (t_s - t.mean()))) > max(4.0 * s, self.off_line)

    def reset(self):
        self.readings, self.moving, self.line, self._misses = [], False, None, 0


class TiltSearch:
    """Where the tilt is when nothing is known yet (a cold start, a step). Each keyframe offers the
    frame on which its features moved farthest; once `keyframes` have, the features' disagreement
    on their step is summed over those frames at every tilt of a coarse grid, then of a fine one
    about the best (one frame's pitch and bounce bias it; over keyframes they average out)."""

    STAGES = ((3.0, 60.0), (0.5, 4.0))      # (grid step, half width) in degrees

    def __init__(self, centre_rad: float, half_rad: float, keyframes: int = 2, limit_deg: float = 75.0):
        self.centre, self.half = centre_rad, half_rad
        self.keyframes, self.limit = keyframes, math.radians(limit_deg)
        self.samples: dict = {}          # keyframe -> (moved px, sample)

    def offer(self, key, moved_px: float, sample) -> bool:
        """A frame of keyframe `key` whose features moved moved_px; True once enough keyframes have."""
        if key not in self.samples or moved_px > self.samples[key][0]:
            self.samples[key] = (moved_px, sample)
        return len(self.samples) > self.keyframes     # the current keyframe's may still grow

    def solve(self, disagreement) -> float:
        """The tilt (radians) where disagreement(tilt, sample) summed over the samples is least."""
        samples = [s for _, s in self.samples.values()]
        centre, half = self.centre, min(self.half, math.radians(self.STAGES[0][1]))
        for step_deg, half_deg in self.STAGES:
            step = math.radians(step_deg)
            n = max(2, int(math.ceil(half / step)))
            grid = centre + step * np.arange(-n, n + 1)
            grid = grid[np.abs(grid) <= self.limit]
            cost = np.array([sum(disagreement(float(t), s) for s in samples) for t in grid])
            centre = _parabola_min(grid, np.nan_to_num(cost, nan=np.inf))
            half = math.radians(half_deg)
        return centre


def _parabola_min(grid: np.ndarray, cost: np.ndarray) -> float:
    """The grid's minimum, refined by a parabola through it and its neighbours."""
    i = int(np.clip(np.argmin(cost), 1, len(cost) - 2))
    c0, c1, c2 = cost[i - 1:i + 2]
    den = c0 - 2 * c1 + c2
    shift = 0.5 * (c0 - c2) / den if np.isfinite(den) and den > 0 else 0.0
    return float(grid[i] + np.clip(shift, -1.0, 1.0) * (grid[1] - grid[0]))
