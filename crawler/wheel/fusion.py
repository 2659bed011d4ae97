"""Vision and wheel into one distance: the camera calibrates the wheel, the wheel bridges the camera.

Pure: no I/O, no logging, no clock (times come with the inputs). Per camera frame the daemon hands
over the vision estimate and the latest wheel reading; out comes the distance and where it came from:

  vision  vision measured this frame and the previous one; the wheel agrees (or there is none)
  fused   both measured and the wheel's share of this frame's step is above 1 − vision_share
  wheel   vision did not measure (a blind stretch, a restart): the wheel, times its learned scale
  model   nothing measured: vision's own bridging (or held distance), as without a wheel

The distance is built from per-frame steps, never from vision's absolute value, so a vision gap
(whose distance the odometer held or guessed) costs only what the wheel got wrong across it.
docs/wheel.md has the equations and the tuning.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass
from typing import NamedTuple

from ..estimate import finite_round
from .learn import ScaleLearner, SlipDetector
from .timeline import WheelTimeline


@dataclass(frozen=True)
class FusionParams:
    quantum_m: float = 2e-4           # one wheel count in nominal metres (1 / counts_per_m)
    noise: float = 0.02               # wheel noise per frame: share of the frame's wheel travel
    scale: float = 1.0                # prior wheel scale (true metres per nominal metre)
    scale_sigma: float = 0.05         # ...and its uncertainty
    scale_drift: float = 0.002        # scale random walk per square-root metre travelled
    chunk_m: float = 0.25             # scale measured over stretches of this much wheel travel
    slip_window_s: float = 0.3        # slip compares wheel and vision over this window
    slip_sigma: float = 4.0           # ...and needs the wheel this many sigma ahead
    slip_ratio: float = 0.05          # ...and at least this share of its travel ahead
    slip_release: float = 0.5         # slip ends below this share of the threshold
    max_slip_m: float = 2.0           # vision travel in one disagreement before the scale reopens
    vision_sigma_m: float = 3e-5      # a vision step's noise when the estimate gives none
    vision_share: float = 0.9         # source "vision" while vision carries at least this share
    speed_tau_s: float = 0.25         # speed smoothing time constant


class VisionFix(NamedTuple):
    """What the fusion needs of one vision estimate (the odometer's Estimate also fits).

    sigma_m: noise of this frame's vision distance that does not carry to the next frames (for a
    bridged frame: what the motion model adds this frame). bridged: vision carried the distance
    with a motion model because nothing could be measured. corrected_m: of distance_m, what a
    gap's settling moved the past by (crawler/gaps.py): no motion of this frame, and no part of the
    fused distance where the wheel carried that gap. across: its step spans a gap and is not
    checked yet (a step across dropped frames, a fresh start's guess): the wheel's to carry.
    """

    t_s: float
    distance_m: float
    sigma_m: float | None = None
    tracking: bool = True
    bridged: bool = False
    corrected_m: float = 0.0
    across: bool = False


class SlipEvent(NamedTuple):
    start_t: float      # when the wheel began to run ahead (estimated from the window)
    end_t: float        # when it agreed with vision again
    ahead_m: float      # how far the wheel ran ahead of the ground, in metres

    def as_dict(self) -> dict:
        return {"start_t": round(self.start_t, 3), "end_t": round(self.end_t, 3),
                "ahead_m": round(self.ahead_m, 5)}


class FusedEstimate(NamedTuple):
    t_s: float
    distance_m: float
    sigma_m: float
    speed_m_s: float
    source: str                      # vision | fused | wheel | model
    slip: bool
    wheel_distance_m: float | None   # what the wheel alone says (learned scale, slip included)
    wheel_scale: float | None        # true metres per nominal wheel metre
    event: SlipEvent | None          # a slip that ended at this frame

    def as_dict(self) -> dict:
        """The fields a distance message carries (rounded; never a non-finite number)."""
        return {"distance_m": finite_round(self.distance_m, 6), "sigma_m": finite_round(self.sigma_m, 6),
                "speed_m_s": finite_round(self.speed_m_s, 6), "source": self.source, "slip": self.slip,
                "wheel_distance_m": finite_round(self.wheel_distance_m, 6),
                "wheel_scale": finite_round(self.wheel_scale, 6)}


def _field(data: dict, key: str, lo: float = -math.inf, hi: float = math.inf) -> float:
    v = data.get(key)
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or not lo <= v <= hi:
        raise ValueError(f"wheel state: {key} = {v!r} must be a finite number in [{lo}, {hi}]")
    return float(v)


class WheelFusion:
    """The filter. State: distance, speed, wheel scale (and the wheel's last count and time)."""

    def __init__(self, params: FusionParams | None = None, *, distance_m: float = 0.0):
        p = self.p = params or FusionParams()
        self.scale = ScaleLearner(p.scale, p.scale_sigma, quantum_m=p.quantum_m, noise=p.noise,
                                  drift=p.scale_drift, chunk_m=p.chunk_m)
        self.slip = SlipDetector(p.slip_window_s, p.slip_sigma, p.slip_ratio, p.slip_release,
                                 p.quantum_m, p.noise)
        self.events: deque[SlipEvent] = deque(maxlen=20)   # the latest slips, for the status
        self.slip_count = 0
        self._notes: list[str] = []
        self.d = float(distance_m)
        self.speed = 0.0
        self._offset = None                  # d − vision distance while vision carries it
        self._v_prev = None
        self._sv2_prev = 0.0
        self._t_prev = None
        self._tracking_prev = False
        self._var = 0.0                      # variance of what wheel and model carried, closed gaps
        self._gap_sys = 0.0                  # the open gap: scale error (systematic, adds linearly)
        self._gap_var = 0.0                  # ...and its random part
        self._open = None                    # [start_t, ahead_m, vision travel, state] of a disagreement
        # the wheel: unwrapped nominal distance, readings for interpolation to frame times
        self.wheel = WheelTimeline()
        self._w_prev = None                  # unwrapped wheel at the last frame that used it
        self.wheel_distance = None
        self._mismatch_told = False
        self._held = False                   # this frame advanced nothing: the wheel anchor stays
        self._resuming = False               # restored by from_dict, the restart not yet bridged
        self._early = False                  # this frame came before every wheel reading
        self._w_prev_early = False
        self._source_prev = None
        self._wheel_carried = False          # the wheel carried a frame of the last unmeasured stretch
        self._in_gap = False                 # ...which goes on

    # -- public -------------------------------------------------------------------------------------

    def update(self, vision, wheel=None) -> FusedEstimate:
        """One camera frame: the vision estimate, the newest WheelReading (or None)."""
        t, v = vision.t_s, vision.distance_m
        sv = getattr(vision, "sigma_m", None) or self.p.vision_sigma_m
        tracking = bool(vision.tracking)
        bridged = bool(getattr(vision, "bridged", False))
        if not math.isfinite(v):             # never let a bad number into the distance
            v, tracking, bridged = (self._v_prev if self._v_prev is not None else 0.0), False, False
        w = None
        if wheel is not None:
            w = self._read_wheel(t, wheel)
        dw = None if w is None or self._w_prev is None else w - self._w_prev
        if self._offset is None:
            self._offset = self.d - v
        d_before = self.d
        self._held = False
        self._take_correction(getattr(vision, "corrected_m", 0.0))
        across = bool(getattr(vision, "across", False))
        if tracking and not across and self._tracking_prev and self._v_prev is not None:
            source, event = self._measured(t, v, sv, w, dw)
            self._in_gap = False
        else:
            if not self._in_gap:             # a new unmeasured stretch: who carries it starts afresh
                self._wheel_carried, self._in_gap = False, True
            source, event = self._unmeasured(t, v, sv, dw, tracking, bridged or across)
        self._source_prev = source
        if w is not None:
            self._w_prev, self._w_prev_early = w, self._early
        elif not self._held:
            self._w_prev = None              # vision covered this frame: the wheel restarts from here
        self._speed(t, self.d - d_before)
        self._v_prev, self._sv2_prev, self._tracking_prev = v, sv * sv, tracking
        sigma = math.sqrt(self._var + self._gap_sys ** 2 + self._gap_var + sv * sv)
        return FusedEstimate(t, self.d, sigma, self.speed, source, self.slip.state > 0,
                             self.wheel_distance, self.scale.k if self.wheel.epoch is not None else None,
                             event)

    def set_distance(self, distance_m: float, vision_m: float | None = None):
        """Count from distance_m now (an operator's reset); vision_m: the odometer's distance now."""
        self.d = float(distance_m)
        vision_m = self.d if vision_m is None else float(vision_m)
        self._offset = self.d - vision_m
        if self._v_prev is not None:
            self._v_prev = vision_m
        self._var = self._gap_sys = self._gap_var = 0.0
        if self.wheel_distance is not None:
            self.wheel_distance = self.d
        self.slip.clear()
        self.scale.drop()

    def to_dict(self) -> dict:
        """What a restart needs: distance, scale and its uncertainty, the wheel at the last frame.

        Save it with the distance of the same frame (the daemon's checkpoint): on restart the wheel's
        travel since then is added to it.
        """
        wheel = None
        tl = self.wheel
        if tl.epoch is not None and self._w_prev is not None:
            wheel = {"position_m": tl.raw_at(self._w_prev), "period_m": tl.period,
                     "epoch": tl.epoch, "t_s": self._t_prev}
        return {"version": 1, "distance_m": self.d,
                "var_m2": self._var + self._gap_sys ** 2 + self._gap_var,
                "scale": self.scale.k, "scale_sigma": self.scale.sigma,
                "wheel_distance_m": self.wheel_distance, "slips": self.slip_count, "wheel": wheel}

    @classmethod
    def from_dict(cls, data: dict, params: FusionParams | None = None) -> "WheelFusion":
        """Resume from to_dict(); a malformed state raises ValueError naming the field."""
        if not isinstance(data, dict) or data.get("version") != 1:
            raise ValueError(f"wheel state {str(data)[:60]!r} is not a version-1 WheelFusion state")
        f = cls(params, distance_m=_field(data, "distance_m"))
        f.scale.k = _field(data, "scale", 0.2, 5.0)
        f.scale.P = _field(data, "scale_sigma", 0.0, 1.0) ** 2
        f._var = _field(data, "var_m2", 0.0)
        if data.get("wheel_distance_m") is not None:
            f.wheel_distance = _field(data, "wheel_distance_m")
        f.slip_count = int(_field(data, "slips", 0))
        wheel = data.get("wheel")
        if wheel is not None:
            if not isinstance(wheel, dict) or not isinstance(wheel.get("epoch"), str):
                raise ValueError(f"wheel state: wheel = {str(wheel)[:60]!r} needs position_m and epoch")
            period = _field(wheel, "period_m", 0.0) if wheel.get("period_m") else None
            f.wheel.resume(wheel["epoch"], _field(wheel, "position_m"), period)
            f._w_prev = 0.0
            f._resuming = True
        return f

    def pop_notes(self) -> list[str]:
        """Things worth a log line (a counter that restarted, clocks that do not match, wiring)."""
        notes, self._notes = self._notes, []
        return notes

    def _take_correction(self, corrected: float):
        """The bridge settled a gap and moved its past by `corrected`: never a step of this frame
        (taken as one, a refused alias step read as a slip of the wheel); where the wheel carried
        any of that gap the fused distance never had the bridge's guess, so it stays. (A gap the
        model carried before the wheel's readings came back takes all of it: not split by time.)"""
        if not corrected or self._v_prev is None:
            return
        self._v_prev += corrected
        self.slip.shift(corrected)
        self.scale.shift(corrected)          # (a stretch that took it in read 0.19 m for 0.25: its k ran to 0.69)
        if self._wheel_carried:
            self._offset -= corrected
        else:
            self.d += corrected

    # -- the two kinds of frame ---------------------------------------------------------------------

    def _measured(self, t, v, sv, w, dw):
        """Vision measured this frame and the last: it carries; the wheel is checked and calibrated."""
        dv = v - self._v_prev
        var_v = sv * sv + self._sv2_prev
        sc = self.scale
        sc.travel(dv)
        self._close_gap()
        if w is None:
            event = self._end_disagreement(t)
            self.slip.clear()
            sc.drop()
            self.d = v + self._offset
            return "vision", event
        k = sc.k
        before = self.slip.state
        state = self.slip.update(t, v, w, k, sc.P, var_v)
        event = self._track_disagreement(t, before, state, dv, dw, var_v)
        if dw is not None:
            self.wheel_distance = (self.d if self.wheel_distance is None else self.wheel_distance) + k * dw
        if self.slip.state != 0 or dw is None:
            self.d = v + self._offset
            return "vision", event
        sc.extend(*self.slip.oldest[1:], var_v)
        kq = k * self.p.quantum_m
        var_w = kq * kq / 6.0 + sc.P * dw * dw + (self.p.noise * k * dw) ** 2
        share = var_w / (var_v + var_w)
        self.d += share * dv + (1.0 - share) * k * dw
        self._offset = self.d - v
        self._var += (1.0 - share) ** 2 * var_w
        return ("vision" if share >= self.p.vision_share else "fused"), event

    def _unmeasured(self, t, v, sv, dw, tracking, bridged):
        """Vision did not measure a step: the wheel carries it if it can, else vision's own value."""
        event = self._end_disagreement(t)
        newest = self.slip.newest
        if newest is not None:
            self.scale.close(newest[1], newest[2], 2 * self._sv2_prev)
        self.slip.clear()
        self._wheel_carried |= dw is not None
        if dw is not None:
            k = self.scale.k
            if self._resuming:
                self._notes.append(f"resumed: the wheel carried {k * dw:+.4f} m travelled while the "
                                   "daemon was down")
            if self.wheel_distance is None:
                self.wheel_distance = self.d
            self.wheel_distance += k * dw
            self.d += k * dw
            self._offset = self.d - v
            self._gap_sys += self.scale.sigma * abs(k * dw)
            kq = k * self.p.quantum_m
            self._gap_var += kq * kq / 6.0 + (self.p.noise * k * dw) ** 2
            self._resuming = False
            return "wheel", event
        if self._v_prev is not None:
            self.d = v + self._offset
            if bridged:
                self._gap_var += sv * sv
            self._held = not (tracking or bridged)
        else:
            self._offset = self.d - v        # a first frame (or a restart without a wheel): hold
            self._held = True
        return ("vision" if tracking else "model"), event

    # -- slip ---------------------------------------------------------------------------------------

    def _track_disagreement(self, t, before, state, dv, dw, var_v):
        """Open, extend and close disagreement stretches; a closed slip is returned as an event."""
        det, sc = self.slip, self.scale
        event = None
        if before != 0 and state != before:
            event = self._end_disagreement(det.agree_since_t(sc.k) if state == 0 else t)
            if state == 0:
                det.restart()
        if state != 0 and self._open is None:
            oldest = det.oldest
            sc.close(oldest[1], oldest[2], var_v)
            self._open = [det.onset_t(sc.k), det.ahead, 0.0, state]
        elif state != 0 and dw is not None:
            r = sc.k * dw - dv
            self._open[1] += r if dw > 0 else (-r if dw < 0 else -abs(r))
            self._open[2] += abs(dv)
            if self._open[2] > self.p.max_slip_m:
                (_, v0, w0), (_, v1, w1) = det.oldest, det.newest
                if (w1 - w0) * (v1 - v0) < 0:
                    self._notes.append("the wheel counts backwards while vision moves forwards: "
                                       "set [wheel] direction = -1")
                self._notes.append(f"wheel and vision disagreed for {self._open[2]:.1f} m "
                                   f"(wheel scale {sc.k:.4f}); taken as a change of wheel scale, "
                                   "relearning it")
                event = self._end_disagreement(t)
                sc.relearn()
                det.restart()
        return event

    def _end_disagreement(self, end_t):
        """Close an open stretch; a slip (wheel ahead) becomes an event, a lag only a count."""
        if self._open is None:
            return None
        start_t, ahead, _, state = self._open
        self._open = None
        if state < 0:
            return None
        ev = SlipEvent(start_t, max(end_t, start_t), ahead)
        self.events.append(ev)
        self.slip_count += 1
        return ev

    # -- the wheel's readings -----------------------------------------------------------------------

    def _read_wheel(self, t, wheel):
        """The wheel at frame time t (or None), after settling the last frame's early anchor."""
        tl = self.wheel
        if not tl.ingest(wheel) and self._w_prev is not None:
            self._notes.append(f"wheel counter restarted (epoch now {wheel.epoch}); the distance "
                               "moved meanwhile is not known")
            self._w_prev, self._resuming = None, False
        if self._w_prev_early and self._w_prev is not None:
            fixed = tl.extrapolate(self._t_prev)
            if fixed is not None:
                if self._source_prev == "wheel":
                    k = self.scale.k
                    self.d += k * (fixed - self._w_prev)
                    self._offset += k * (fixed - self._w_prev)
                    self.wheel_distance += k * (fixed - self._w_prev)
                self._w_prev, self._w_prev_early = fixed, False
        w, self._early = tl.at(t)
        if tl.mismatch is not None and not self._mismatch_told:
            self._mismatch_told = True
            self._notes.append(f"wheel reading at t={tl.mismatch[1]:.3f} s but frame at "
                               f"t={tl.mismatch[0]:.3f} s: the wheel port's clock is not the frame "
                               "clock; using the newest reading")
        return w

    # -- bookkeeping --------------------------------------------------------------------------------

    def _close_gap(self):
        if self._gap_sys or self._gap_var:
            self._var += self._gap_sys ** 2 + self._gap_var
            self._gap_sys = self._gap_var = 0.0

    def _speed(self, t, step):
        if self._t_prev is not None and t > self._t_prev:
            dt = t - self._t_prev
            self.speed += (step / dt - self.speed) * min(1.0, dt / self.p.speed_tau_s)
        self._t_prev = t
