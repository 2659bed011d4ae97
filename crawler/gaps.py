"""Never lose distance: carry it across what the camera cannot measure, and say how sure it is.

The odometer measures while it sees the wall and holds its distance while it does not (a blackout, a
featureless stretch, a camera stall, frames that never came). When it finds the wall again it either
measured across the gap (its distance includes the motion in the gap: `continuous`) or had to start
afresh (its distance does not). This stage turns that into a distance that never stops:

- while blind, the distance is carried by a motion model (the speed before the gap) and published
  as `bridged`;
- when tracking returns on a fresh start, the gap's distance is the trapezoid of the speed before
  and the speed after (a constant acceleration over the gap), the latter measured over the first
  moments of tracking, and the bridged stretch is corrected by that;
- every estimate carries `sigma_m`, its 1-sigma uncertainty: the measurement's own (closed keyframe
  steps: the spread of the tracks over their number, and a scale term) and, for every bridged gap,
  the motion model's (the speed's error and an acceleration that was not constant).

Pure: no I/O, no clock; fed one odometer estimate per frame.
"""

from __future__ import annotations

import math
from dataclasses import dataclass


@dataclass(frozen=True)
class BridgeParams:
    scale_sigma: float = 5e-4         # relative scale uncertainty of the geometry (FOV, height): per metre
    step_floor_m: float = 2e-5        # a keyframe step is never known better than this (LK, compression)
    accel_sigma_m_s2: float = 0.1     # 1-sigma acceleration the model cannot see over a gap
    speed_sigma_m_s: float = 0.005    # 1-sigma error of a measured speed (0.25 s least squares)
    settle_s: float = 0.25            # after a fresh start, measure the speed this long before correcting
    max_bridge_s: float = 30.0        # beyond this the model is a guess: the speed fades to 0 over it


@dataclass
class Bridged:
    """What the stage adds to an estimate."""

    distance_m: float
    sigma_m: float                    # of the distance: everything carried so far
    bridged: bool                     # carried by the motion model, not measured
    step_sigma_m: float               # this frame's own noise, that does not carry on (for the wheel fusion)
    gap_s: float = 0.0                # how long the current (or just closed) gap is


class GapBridge:
    """Vision distance in, a distance out that is measured where it can be and bridged where not."""

    def __init__(self, params: BridgeParams | None = None, distance_m: float = 0.0, sigma_m: float = 0.0):
        self.p = params or BridgeParams()
        self.offset_m = 0.0           # what the bridged gaps added to the odometer's own distance
        self.var_meas = sigma_m * sigma_m   # closed keyframe steps (and what a resumed run carried)
        self.var_gaps = 0.0           # closed gaps
        self._kf_vision = None        # the odometer's distance at the current keyframe
        self._last = None             # (t, vision distance, speed) of the last tracked frame
        self._gap = None              # (t0, distance out at t0, speed before) while blind
        self._gap_prev_var = 0.0      # the open gap's variance at the previous blind frame
        self._settle = None           # after a fresh start: (t_start, gap_T, v_before, samples)
        self._out_m = distance_m

    @property
    def sigma_m(self) -> float:
        return math.sqrt(self.var_meas + self.var_gaps)

    @property
    def sigma_meas_m(self) -> float:
        """Of the measured part only (closed keyframe steps), for a fusion that bridges gaps itself."""
        return math.sqrt(self.var_meas)

    def reset(self, distance_m: float = 0.0):
        """The operator's reset: count from here, with no uncertainty carried over."""
        self.__init__(self.p, distance_m)

    def update(self, est) -> Bridged:
        """One odometer estimate: t_s, distance_m, speed_m_s, tracking, keyframe, continuous,
        spread_mm, inliers."""
        return self._tracked(est) if est.tracking else self._blind(est)

    # -- blind: the motion model ---------------------------------------------------------------------

    def _blind(self, est) -> Bridged:
        if self._gap is None:
            if self._last is None:    # never tracked yet: nothing to carry
                return Bridged(self._out_m, self.sigma_m, False, self.p.step_floor_m)
            t0, _, v0 = self._last
            self._gap, self._gap_prev_var = (t0, self._out_m, v0), 0.0
            self._settle = None       # a gap inside the settling: its speed estimate is void
        t0, d0, v0 = self._gap
        T = est.t_s - t0
        var = self._model_var(T, 0.0)
        step = math.sqrt(max(var - self._gap_prev_var, 0.0))
        self._gap_prev_var = var
        out = d0 + self._travel(v0, T)
        return Bridged(out, math.sqrt(self.var_meas + self.var_gaps + var), True, step, T)

    def _travel(self, v0: float, T: float) -> float:
        """Distance at constant speed v0 over T, the speed fading out beyond max_bridge_s."""
        m = self.p.max_bridge_s
        return v0 * (T if T <= m else m + (T - m) * max(0.0, 1 - (T - m) / m) / 2)

    def _model_var(self, T: float, dv: float) -> float:
        """Variance of a gap of T bridged at a measured speed: the speed's error, and an acceleration
        the model does not see (larger when the speed before and after differ by dv)."""
        accel = math.hypot(self.p.accel_sigma_m_s2, dv / max(T, 1e-3))
        return (self.p.speed_sigma_m_s * T) ** 2 + (0.5 * accel * T * T) ** 2

    # -- tracking: the measurement ----------------------------------------------------------------------

    def _tracked(self, est) -> Bridged:
        gap_T = self._close_gap(est) if self._gap is not None else 0.0
        if self._kf_vision is None:
            self._kf_vision = est.distance_m
        if self._settle is not None:
            self._settle_speed(est)
        step_var = self._step_var(est)
        if est.keyframe:              # the keyframe's step is closed: its error is carried from now on
            self.var_meas += step_var
            self._kf_vision = est.distance_m
        v = est.speed_m_s if est.speed_m_s is not None else (self._last[2] if self._last else 0.0)
        self._last = (est.t_s, est.distance_m, v)
        self._out_m = est.distance_m + self.offset_m
        noise = self._frame_noise(est)
        total = self.var_meas + self.var_gaps + (0.0 if est.keyframe else step_var)
        return Bridged(self._out_m, math.sqrt(total), False, noise, gap_T)

    def _frame_noise(self, est) -> float:
        spread = (est.spread_mm or 0.0) / 1000.0
        return max(spread / math.sqrt(max(est.inliers, 1)), self.p.step_floor_m)

    def _step_var(self, est) -> float:
        """The current keyframe step's variance: the tracks' noise, and the scale over the step."""
        step = abs(est.distance_m - self._kf_vision)
        return self._frame_noise(est) ** 2 + (self.p.scale_sigma * step) ** 2

    def _close_gap(self, est) -> float:
        t0, d0, v0 = self._gap
        self._gap = None
        T = est.t_s - t0
        if est.continuous:            # measured across the gap: the odometer's distance has it all,
            self.var_meas += self.p.step_floor_m ** 2      # the offset stays as it was before the gap
        else:                         # a fresh start: the gap's distance is the model's, corrected later
            self.offset_m = d0 + self._travel(v0, T) - est.distance_m
            self.var_gaps += self._model_var(T, 0.0)
            self._settle = (est.t_s, T, v0, [(est.t_s, est.distance_m)])
        self._kf_vision = est.distance_m
        return T

    def _settle_speed(self, est):
        """After a fresh start: once the speed after the gap is measured, the trapezoid replaces the
        constant speed over the gap, and its variance the constant speed's."""
        t_start, T, v0, samples = self._settle
        samples.append((est.t_s, est.distance_m))
        if est.t_s - t_start < self.p.settle_s:
            return
        self._settle = None
        v1 = _slope([t for t, _ in samples], [d for _, d in samples])
        if v1 is None:
            return
        self.offset_m += 0.5 * (v1 - v0) * T
        self.var_gaps += -self._model_var(T, 0.0) + self._model_var(T, v1 - v0) / 4.0


def _slope(ts, ds) -> float | None:
    n = len(ts)
    if n < 2:
        return None
    mt, md = sum(ts) / n, sum(ds) / n
    den = sum((t - mt) ** 2 for t in ts)
    return None if den <= 0 else sum((t - mt) * (d - md) for t, d in zip(ts, ds)) / den
