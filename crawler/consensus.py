"""The statistics the odometer reduces its tracks with. Pure: no I/O, no state beyond a window.

robust_step: one step from many per-feature displacements (median/MAD, then the inliers' mean).
SpeedFilter: a least-squares speed over time, not frames, so dropped frames add noise, never bias.
FadingMean: a mean that is plain until its memory is full, then forgets the oldest at a fixed rate.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np

from .motionfit import remeasured

MAD_TO_SIGMA = 1.4826                  # a normal distribution's sigma per median absolute deviation
LATERAL_AXIAL = np.array([[-1.0], [1.0]])   # moved = keyframe wall - wall, signs per row (lateral, axial)


def robust_step(values: np.ndarray, floor: float, k: float):
    """Median/MAD consensus per row of values (rows: axial, lateral): (means, inlier mask, spreads).

    A feature is an inlier when it agrees with the median in every row.
    """
    mid = values.shape[1] // 2          # the upper median: partitioning beats np.median's overhead
    part = values.copy()
    part.partition(mid, axis=1)
    med = part[:, mid:mid + 1]
    dev = np.abs(values - med)
    part = dev.copy()
    part.partition(mid, axis=1)
    sigma = part[:, mid] * MAD_TO_SIGMA
    gate = np.maximum(sigma * k, floor)
    inl = np.logical_and.reduce(dev <= gate[:, None], axis=0)
    n_in = np.count_nonzero(inl)
    if not n_in:
        return med.ravel(), inl, sigma
    return values.dot(inl.astype(values.dtype)) / n_in, inl, sigma


def shutter_factors(camera, kf, idx, rows_px, t_s: float):
    """Each track's rolling-shutter factor: the frame interval over the time between the two
    exposures of its feature (rows read later moved for longer), as rolling_shutter scales them;
    None without a rolling shutter. `rows_px`: the tracks' frame rows now."""
    dt = t_s - kf.t_s
    if camera.readout_s <= 0 or dt <= 0:
        return None
    span = dt + camera.row_time(rows_px) - kf.row_t.take(idx)
    return dt / np.maximum(span, 0.2 * dt)


def rolling_shutter(moved, idx, pts, dt: float, row_t_now, row_t_kf, min_span_share: float):
    """Per-feature displacements at the frames' reference times: a feature's displacement spans
    dt plus its change of row time. A feature exposed over less than min_span_share of dt is
    dropped (its rescaling would amplify noise). Returns moved, idx, pts of those kept."""
    span = dt + row_t_now - row_t_kf[idx]
    keep = span > min_span_share * dt
    return moved[:, keep] * (dt / span[keep]), idx[keep], pts[keep]


def median(values) -> float:
    v = sorted(values)
    return v[len(v) // 2]


class FadingMean:
    """The mean of the values added: a plain mean for the first 1 / rate, then each new one weighs
    `rate` (a level that may drift, learned as fast as the values allow). `n`: how many so far."""

    def __init__(self, rate: float):
        self.rate, self.n, self.value = rate, 0, 0.0

    def add(self, x: float) -> float:
        self.n += 1
        self.value += max(1.0 / self.n, self.rate) * (x - self.value)
        return self.value


class SpeedFilter:
    """Least-squares slope of distance over the last window of seconds.

    Works on timestamps, not frame counts, so dropped frames change nothing but the noise. Running
    sums keep it to a few float operations per frame.
    """

    def __init__(self, window_s: float):
        self.window_s = window_s
        self.reset()

    def reset(self):
        self._hist: deque[tuple[float, float]] = deque()
        self._t0 = None
        self._n = self._st = self._sd = self._stt = self._std = 0.0

    def _add(self, t, d, sign):
        self._n += sign
        self._st += sign * t
        self._sd += sign * d
        self._stt += sign * t * t
        self._std += sign * t * d

    def update(self, t: float, d: float) -> float | None:
        if self._t0 is None:
            self._t0 = t
        t -= self._t0               # small numbers: the sums stay exact enough for hours
        self._hist.append((t, d))
        self._add(t, d, 1)
        while self._hist[0][0] < t - self.window_s:
            self._add(*self._hist.popleft(), -1)
        return self.value()

    def remeasured(self, gain_m: float, over_m: float = 0.0):
        """The distance gained gain_m from its steps (over_m of them) measured again (a better
        tilt): the window's samples gain it as motionfit.remeasured says, so it is not read as speed."""
        if not gain_m or len(self._hist) < 2:
            return
        hist, t0 = remeasured(list(self._hist), gain_m, over_m), self._t0
        self.reset()
        self._t0 = t0
        for t, d in hist:
            self._hist.append((t, d))
            self._add(t, d, 1)

    def value(self) -> float | None:
        n = self._n
        den = n * self._stt - self._st * self._st
        if n < 2 or den <= 1e-12 * max(1.0, n * self._stt):
            return None
        return (n * self._std - self._st * self._sd) / den


@dataclass
class Consensus:
    """The step the tracks of one frame agree on: axial, lateral, inliers, spread, spread per step."""

    step: float
    lat: float
    n_in: int
    sigma: float
    ratio: float
    pts: np.ndarray
    idx: np.ndarray
    tracks: tuple = ()    # (indices, ROI positions, displacements, inlier mask) of every track: the pose's
