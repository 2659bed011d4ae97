"""Never lose distance: carry it across what the camera cannot measure, and say how sure it is.

The odometer measures while it sees the wall and holds its distance while it does not (a blackout, a
featureless stretch, a camera stall, frames that never came). When it finds the wall again it either
measured across the gap (its distance includes the motion in the gap: `continuous`) or had to start
afresh (its distance does not). This stage turns that into a distance that never stops:

- while blind, the distance is carried by a motion model: the speed and acceleration measured just
  before the gap (a crawler that was braking is taken to stop, not to reverse); published `bridged`;
- after a fresh start, the gap's distance is settled once the speed after it is measured
  (crawler/gapmodel.py): the trapezoid of the two speeds, a ramp seen at one end carried at its
  rate, or, where the model stopped inside the gap, a brake and a start at the same rate after the
  middle of the stands possible; a gap long enough to stop and start in may hide a stand: its
  uncertainty spans down to braking and starting at the crawler's best. Measured too briefly for
  a speed and lost again, the gap is settled by that brief speed where the speed before it is known
  and it reads motion (0.05 m/s), not its sigma, which stays the model's; else the gap goes on from
  where it began (the frames after that short start are continuous with it); a fresh start that
  knows its motion over a few frames (`since`) counts them as measured, and the speed that settled
  a gap carries the next one if it opens at once;
- every estimate carries `sigma_m`, its 1-sigma uncertainty: the closed keyframe steps' (the tracks'
  spread over their number, and a scale term), the frame's jitter (what moves all tracks at once:
  the camera pitching on a bouncing car, compression; each frame's pose error cancels between the
  steps that end and start there, so it is the measured distance's scatter about a straight line),
  and every bridged gap's (the speed's error and the changes the model could not see, a random walk).
Pure: no I/O, no clock; fed one odometer estimate per frame.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

from .drive import DriveWatch, drive_rate
from .framenoise import FrameNoise
from .gapmodel import (BridgeParams, Gap, model_time, model_var, moving_speed, rate_range_var, rejoin,
                       see_stand, set_off, speed_to, stand_state, standing, start_rate_seen, stops,
                       travel, travel_to)
from .gapends import motion_before, speed_after
from .gapsettle import settled_travel
from .motionfit import TIME_EPS, could_go
from .motionfit import is_rescale as _is_rescale, remeasured as _remeasured


@dataclass
class Bridged:
    """What the stage adds to an estimate."""

    distance_m: float
    sigma_m: float                    # of the distance: everything carried so far
    bridged: bool                     # carried by the motion model, not measured
    step_sigma_m: float               # this frame's own noise, that does not carry on (for the wheel fusion)
    gap_s: float = 0.0                # how long the current (or just closed) gap is
    across: bool = False              # its step spans a gap, not checked yet (a wheel's is surer)
    corrected_m: float = 0.0          # of distance_m, what a gap's settling moved the past by (no motion now)


class GapBridge:
    """Vision distance in, a distance out that is measured where it can be and bridged where not."""

    def __init__(self, params: BridgeParams | None = None, distance_m: float = 0.0, sigma_m: float = 0.0):
        self.p = params or BridgeParams()
        self.offset_m = 0.0           # what the bridged gaps added to the odometer's own distance
        self.var_meas = sigma_m * sigma_m   # closed keyframe steps (and what a resumed run carried)
        self.var_gaps = 0.0           # closed gaps
        self._kf_vision = None        # the odometer's distance at the current keyframe
        self._hist: deque = deque()   # (t, published distance) of recent measured frames
        self._gap: Gap | None = None  # open (blind), or settling after a fresh start
        self._settling = None         # (t_start, vision distance samples) while the gap settles
        self._restarted = None        # (t, vision distance) of a fresh start inside the open gap: what
                                      # the odometer calls continuous after it is continuous with it only
        self._gap_prev_var = 0.0
        self._out_m, self.corrected_m = distance_m, 0.0
        self.noise = FrameNoise(self.p)   # the measured frame's own noise, not carried on (framenoise.py)
        self._last_settle = None      # (t, speed, brief) of the last gap settled: its last sample, the speed
                                      # after, and when a brief speed settled it, (rate on, its sigma, the
                                      # speed's): the next gap goes on from that brief speed
        self._remeasured_at = None    # when the odometer last measured its steps at a new tilt
        self._carried: list = []      # [t0, t1, metres] of the gaps the model settled, newest last
        self.drive = DriveWatch(self.p)   # the cruise and rates the drive was seen at (drive.py)
        self._blind_at, self._held = None, None   # the last blind frame's (t, distance); the stands shown at a close
        self._still, self._stood = None, None     # (since, until, distance) the output stands at; the last stand

    @property
    def sigma_m(self) -> float:
        return math.sqrt(self.var_meas + self.var_gaps)

    @property
    def sigma_meas_m(self) -> float:
        """Of the measured part only (closed keyframe steps), for a fusion that bridges gaps itself."""
        return math.sqrt(self.var_meas)

    def reset(self, distance_m: float = 0.0, vision_m: float | None = None):
        """The operator's reset: count from distance_m (the odometer from vision_m), no uncertainty
        carried over but a gap's open now: it is bridged on from the new count, and where the crawler
        was at the reset is its model's guess; where it is measured across, the model's travel since
        the odometer's last start (the gap's, or one inside it) comes off."""
        g, at, restart = (self._gap, self._blind_at, self._restarted) if self._settling is None else (None,) * 3
        if g is not None and at is not None:      # where the crawler was at the reset is the model's guess
            guess_var = self._model_var(g, at[0])[1]
        drive = self.drive                        # (the crawler's drive is the same one)
        self.__init__(self.p, distance_m)
        self.drive = drive
        drive.lost()
        self.offset_m = 0.0 if vision_m is None else distance_m - vision_m
        if g is not None and at is not None:
            self.var_gaps = guess_var             # (a phantom set-off before it: -437 mm at 0.8 sigma, not 3.5)
            pre = at[1] - g.d0
            g.before_reset_m = pre - (travel_to(self.p, g, restart[0]) if restart else 0.0)
            g.d0, g.vis0, self._gap, self._blind_at = (distance_m - pre, g.vis0 if vision_m is None else vision_m,
                                                       g, (at[0], distance_m))

    def update(self, est) -> Bridged:
        """One odometer estimate: t_s, distance_m, speed_m_s, tracking, keyframe, continuous,
        spread_mm, inliers."""
        self.corrected_m = 0.0
        return self._tracked(est) if est.tracking else self._blind(est)

    # -- the motion model ------------------------------------------------------------------------------

    def _open_gap(self, est=None) -> Gap:
        t0 = self._hist[-1][0]
        last = self._last_settle
        g = Gap(t0, self._out_m, *motion_before(self.p, self._hist, t0, last and last[:2], self._remeasured_at))
        if last is not None and last[2] is not None and last[0] >= t0 - TIME_EPS:   # on from the brief speed
            g.v0, g.a0, g.sa, g.up = (last[1], *last[2][:2], 0.0)   # that settled the last (a fit across its
            g.lag = max(g.lag, last[2][2])                           # hole reads the motion before that one)
        cruise, g.drive = self.drive.cruise, self.drive.rates()   # (a cruise older than the horizon: none)
        g.vis0 = self._out_m - self.offset_m
        g.cruise = cruise[1] if cruise is not None and cruise[0] >= t0 - self.p.max_bridge_s else None
        self._setting_off(g, t0, est.t_s if getattr(est, "changed", False) else None)
        return g

    def _setting_off(self, g: Gap, t0: float, changed_at: float | None):
        """A gap that opens as the crawler sets off out of a stand (it stood for min_stand_s up to
        SET_OFF_S before, and moves now slower than half its cruise the same way, or below it at a
        start's rate the frames showed): it drives on to its cruise at that rate or the drive's, as
        after a stand the frames showed (gapmodel.speed_after_stand).
        Carried at the speed of its first frames, an independent stress run's set-off onto a wet
        wall was bridged at 0.008 m/s for 2 s where it drove at 0.3. One that opens on a stand, as
        the lit picture changed (at `changed_at`, Estimate.changed: a standing crawler's does not), set
        off between the last still frame and that one (frames dropped between them: any time in the drop, so its
        middle), the way it is not seen: its cruise's, either way in its sigma (`either_way`)."""
        p, stood, c, v = self.p, self._stood, g.cruise, g.v0
        if stood is None or c is None or v is None or t0 - stood[1] > SET_OFF_S or standing(p, c):
            return
        late, seen = 0.0, start_rate_seen(p, g)     # when it set off, after t0; its rate, if the frames showed it
        if standing(p, v):
            if changed_at is None or t0 - stood[1] > TIME_EPS:
                return
            g.either_way, late = True, (changed_at - t0) / 2
        elif g.a0 * v < 0 or v * c <= 0 or abs(v) >= (max(abs(c) - p.ramp_dv_m_s, 0.5 * abs(c)) if seen else 0.5 * abs(c)):
            return
        rate = g.up if seen else drive_rate(p, g)
        g.resumed = (late + abs(c - v) / (2 * rate), c, math.inf)
        g.set_off_var = rate_range_var(p, abs(c - v), c) + (c * late) ** 2 / 3.0   # its rate, and when
        g.edges_var += g.set_off_var

    def _either_var(self, g: Gap, T: float) -> float:
        """A set-off whose way is not seen (`either_way`), carried for T: the other way is twice as far."""
        return (travel(self.p, g, T) - g.v0 * T) ** 2 if g.either_way else 0.0

    def _model_var(self, g: Gap, t: float) -> tuple[float, float]:
        """The model's time from the gap's start to t, and the variance of what it carried by then."""
        T, stands_var = model_time(g, t)
        return T, model_var(self.p, T, moving_speed(g), sa=g.sa, lag=g.lag) + stands_var + self._either_var(g, T)

    def _watch_still(self, t: float, out: float):
        """The published distance standing (within what a standing speed moves in min_stand_s): the
        last stand it showed for min_stand_s, for a gap that opens as the crawler sets off."""
        p, still = self.p, self._still
        if still is None or abs(out - still[2]) > p.speed_sigma_m_s * p.min_stand_s:
            self._still = (t, t, out)
            return
        self._still = (still[0], t, still[2])
        if t - still[0] >= p.min_stand_s - TIME_EPS:
            self._stood = (still[0], t)

    def _measured_again(self, est, gain: float, over: float):
        """Tilt auto measured its epoch's steps again at a better tilt (crawler/autotilt.py). A gap
        inside the epoch was carried at the speeds its steps gave, at the old tilt: it scales as
        the epoch did (a model whose speeds and rates all scale by s carries s times the metres).
        One from before the epoch (the camera was turned since) keeps its metres. A search that
        read the tilt off on the wet frames before a gap left the gap 7 % short (a lobe run).
        True: the gap open or settling now is inside the epoch, and has been scaled."""
        since, old = getattr(est, "rescaled_since_s", None), over - gain
        if since is None or abs(old) < _MIN_EPOCH_M or not 0.5 <= over / old <= 2.0:
            return False
        scale, since, g = over / old, since - TIME_EPS, self._gap
        for gap in self._carried:
            if gap[0] >= since:
                extra, gap[2] = gap[2] * (scale - 1.0), gap[2] * scale
                self.offset_m, self._out_m = self.offset_m + extra, self._out_m + extra
                if g is not None and g.t0 >= gap[1]:    # the gap open now starts after it: so does its
                    g.d0 += extra                        # distance (its close sets the offset from it)
                self._hist = deque((t, d + extra if t >= gap[1] else d) for t, d in self._hist)
        last = self._last_settle
        if last is not None and last[0] >= since:   # its speeds and rate: at the new tilt too
            self._last_settle = (last[0], last[1] * scale, last[2] and tuple(x * scale for x in last[2]))
        self.drive.rescaled(since, scale)
        if g is None or g.t0 < since:
            return False
        before = min(max((g.vis0 - (est.distance_m - over)) / old, 0.0), 1.0)   # the epoch's share before it
        restart, carried = self._restarted, travel_to(self.p, g, self._restarted[0]) if self._restarted else 0.0
        g.measured_again(scale, gain * before)
        if restart:                   # a fresh start inside it set the offset from the model (_close_gap):
            self.offset_m += travel_to(self.p, g, restart[0]) - carried   # that part scales too
            self._restarted = (restart[0], restart[1] + gain * before)
        return True

    # -- blind ----------------------------------------------------------------------------------------

    def _blind(self, est) -> Bridged:
        self.noise.lost()
        self.drive.lost()
        if self._settling is not None:    # the measurement since the gap was too short: it goes on
            self._settle_or_reopen()
        if self._gap is None:
            if not self._hist:            # never measured yet: nothing to carry
                return Bridged(self._out_m, self.sigma_m, False, self.p.step_floor_m)
            self._gap = self._open_gap(est)
            self._gap_prev_var = 0.0
        g = self._gap
        see_stand(self.p, g, getattr(est, "stand", None), est.t_s)     # (a plain estimate shows none)
        T, var = self._model_var(g, est.t_s)
        step = math.sqrt(max(var - self._gap_prev_var, 0.0))
        self._gap_prev_var = var
        out = g.d0 + travel(self.p, g, T)
        self._blind_at = (est.t_s, out)
        self._watch_still(est.t_s, out)
        return Bridged(out, math.sqrt(self.var_meas + self.var_gaps + var + self.noise.pose_var), True, step,
                       est.t_s - g.t0, corrected_m=self.corrected_m)

    # -- measured -------------------------------------------------------------------------------------

    def _tracked(self, est) -> Bridged:
        self._blind_at, gap_T, gain = None, 0.0, getattr(est, "rescaled_m", 0.0)   # (a plain estimate: none)
        over = getattr(est, "rescaled_over_m", 0.0)
        if self._settling is not None and not est.continuous:
            # another fresh start while the last one settles: what was measured since that one
            # settles the gap (or, too short, reopens it); this frame's motion is unknown again
            self._settle_or_reopen()
        if self._gap is None and self._hist and (not est.continuous or est.t_s - self._hist[-1][0] > self.p.across_s + TIME_EPS):
            self._gap = self._open_gap()      # a fresh start right after a measured frame: a gap of one;
                                              # or frames dropped, measured across: checked as a gap's
        # before the gap closes: its model is in the old metres. The samples after a gap inside the
        # epoch scale with it, as a plain scale even when it is a remount's (spread over their own
        # span, a 3 % remount read as a ramp: 0.54 m/s after a gap for 0.3)
        scaled = bool(gain) and self._measured_again(est, gain, over)
        if self._gap is not None and self._settling is None:
            gap_T = self._close_gap(est)
        elif self._settling is not None:
            _remeasured(self._settling[1], gain, over, as_scale=scaled, upto_m=est.distance_m - gain)
            self._settling[1].append((est.t_s, est.distance_m))
            if est.t_s - self._settling[0] >= self.p.settle_s:
                self._settle_or_reopen()
        if gain:                              # the motion model reads its speeds from the history
            self._hist = deque(_remeasured(list(self._hist), gain, over))
            self.drive.lost()                 # (a ramp's distances are not in one metre)
            if not _is_rescale(gain, over):   # ...a remount's re-measure has the shape of a ramp
                self._remeasured_at = est.t_s
        if self._kf_vision is None:
            self._kf_vision = est.distance_m
        self.noise.track(est)
        self.drive.update(est.t_s, est.distance_m, est.speed_m_s, est.continuous)
        step_var = self._step_var(est)
        if est.keyframe:              # the keyframe's step is closed: its error is carried from now on
            self.var_meas += step_var
            self._kf_vision = est.distance_m
        self._out_m = est.distance_m + self.offset_m
        if self._hist and self._hist[-1][0] >= est.t_s:
            self._hist.pop()              # a settled gap put this frame in already
        self._hist.append((est.t_s, self._out_m))
        while self._hist and self._hist[0][0] < est.t_s - 2 * self.p.history_s:
            self._hist.popleft()
        total = self.var_meas + self.var_gaps + (0.0 if est.keyframe else step_var) + self.noise.pose_var
        if self._settling is not None:    # the gap is not settled yet: its model uncertainty stands
            total += self._model_var(self._gap, self._settling[0])[1]
        self._watch_still(est.t_s, self._out_m)
        return Bridged(self._out_m, math.sqrt(total), False, self.noise.white(est), gap_T,
                       gap_T > 0 and self._settling is not None, self.corrected_m)

    def _step_var(self, est) -> float:
        """The current keyframe step's variance: the tracks' noise, and the scale over the step."""
        step = abs(est.distance_m - self._kf_vision)
        return self.noise.tracks(est) ** 2 + (self.p.scale_sigma * step) ** 2

    def _close_gap(self, est) -> float:
        g = self._gap
        g.open_at_close, self._held = g.stand is not None and g.confirmed, stand_state(g)
        see_stand(self.p, g, None)    # measured again: a stand still shown ends (one too short is none)
        T = est.t_s - g.t0
        restarted, self._restarted = self._restarted, None
        if est.continuous and restarted is None and T > self.p.across_s + TIME_EPS and g.v0 is not None and not g.before_reset_m:
            g.across = True           # measured across: the step stands unless the speed after says no
            self._settling = (est.t_s, [(est.t_s, est.distance_m)])
        elif est.continuous and restarted is None:   # measured across the gap: the odometer's distance
            self._keep_across(g)      # has it all
        elif est.continuous and g.v0 is not None:
            # measured since a fresh start inside the gap (the offset was set then): up to that
            # start the gap is the model's, at the speed before it, and so is its uncertainty
            self._gap = None
            T_model, var = self._model_var(g, restarted[0])
            self.var_gaps += var
            self._carry(g.t0, restarted[0], travel(self.p, g, T_model))
            self._hist.append((restarted[0], restarted[1] + self.offset_m))   # measured again: a speed
        else:                         # a fresh start: provisionally the model's, settled later
            samples = [(est.t_s, est.distance_m)]
            since = getattr(est, "since", None)
            if est.continuous:        # with a fresh start inside a gap the model cannot carry
                samples.insert(0, restarted)
            elif since is not None and g.t0 < since[0] < est.t_s:
                samples.insert(0, since)  # a fresh start that knows its motion over a few frames
            t1, d1 = samples[0]
            self.offset_m = g.d0 + travel_to(self.p, g, t1) - d1
            self._settling = (t1, samples)
        self._kf_vision = est.distance_m
        return T

    def _settle_or_reopen(self):
        """Settle the gap with the speed measured since it, or, measured too briefly for a speed
        (gapends.speed_after), reopen it: it goes on from where it began."""
        g, (t1, samples) = self._gap, self._settling
        self._settling = None
        if self._last_settle is not None:   # reopened or kept across: the speed stays, not its brief carry
            self._last_settle = (*self._last_settle[:2], None)
        T, stands_var = model_time(g, t1)
        v1, v_end, a1, brief = speed_after(self.p, g, t1, samples, T, self.noise.pose_var)
        if g.across and (v1 is None or brief is not None):   # measured across, and lost again too
            self._keep_across(g, samples[0][1])              # soon to check: it stands
            return
        if v1 is None:                # reopen: drop what the short measurement added to the history
            while self._hist and self._hist[-1][0] >= t1:
                self._hist.pop()
            self._out_m, self._restarted = g.d0, samples[0]
            if g.open_at_close:       # it stood on: the stand the measurement ended goes on
                rejoin(g, self._held, t1)
            return
        self._last_settle = (samples[-1][0], v1 if brief is None else brief[1], None)
        if g.across and self._reachable(g, T, samples[0][1], v_end):
            self._keep_across(g, samples[0][1])
            return
        after = set_off(self.p, g, t1, v_end, a1)          # (a stand shown, a start seen after it)
        corrected, unseen_var = (after, 0.0) if after is not None else settled_travel(self.p, g, T, v_end, a1)
        correction = g.d0 + corrected - (samples[0][1] + self.offset_m)
        # what the offset carries (measured across, the odometer's distance holds its own step, which
        # a re-measure scales itself: +31 mm leaked with an alias refused, a review's case)
        self._carry(g.t0, t1, corrected - (samples[0][1] - g.vis0 if g.across else 0.0))
        self.offset_m, self._out_m, self.corrected_m = (x + correction for x in (self.offset_m, self._out_m, self.corrected_m))
        # the samples the speed after was read from are the history now, also those a reopened gap
        # had dropped from it: a gap that opens at once is carried at that speed, not held
        self._hist = deque([(t, d) for t, d in self._hist if t < t1]
                           + [(t, d + self.offset_m) for t, d in samples])
        # both ends known: the trapezoid's residual; only the speed after, or a stop the model
        # guessed inside the gap: as unsure as while blind
        both = g.v0 is not None and stops(g, T, v_end, self.p.hard_accel_m_s2) is None
        var = model_var(self.p, T, 0.0 if g.v0 is None else g.v0, both, lag=g.lag) + unseen_var + stands_var
        if brief is not None:         # a brief speed may be a wall's edge misread: it moves the gap, not
            var = max(var, self._model_var(g, t1)[1])     # its sigma; the next gap goes on from it
            sigma, v_last, rate = brief                   # (braking on where it bore the brake out),
            t = samples[-1][0]                            # as unsure as it is off the model's speed
            off = abs(v_last - speed_to(self.p, g, t))
            self._last_settle = (t, v_last, (rate, g.sa if rate else 0.0, max(sigma, off)))
        self.var_gaps += var
        self._gap = None

    def _reachable(self, g: Gap, T: float, d1: float, v1: float) -> bool:
        """Could a crawler have gone the odometer's step across the gap (motionfit.could_go)? Not
        on a periodic wall's alias: a reversal inside 0.7 s of dropped frames read 0.20 m (two 102 mm
        periods) forward of the truth; nor where no part of the wall was in both frames and the
        tracks settled on the light's shading, which stays put (the same reversal on a wall that
        does not repeat read +8 mm for -159 mm). The motion model carries such a gap instead."""
        p = self.p
        return could_go(d1 + self.offset_m - g.d0, g.v0, v1, T, p.max_accel_m_s2, p.across_speed_m_s)

    def _keep_across(self, g: Gap, d1: float | None = None):
        """The step measured across the gap stands: as measured; the offset stays, less what came
        before a reset in it (in the epoch's metres: it scales with them). d1: the odometer's
        distance a long gap's step ended at, as the gap's close started the next step there: a
        keyframe step's scale error over it too (a short gap's is in its keyframe step's own)."""
        self._gap = None
        scaled = 0.0 if d1 is None else self.p.scale_sigma * (d1 - g.vis0)
        self.var_meas += self.p.step_floor_m ** 2 + scaled ** 2
        self.offset_m -= g.before_reset_m
        self._carry(g.t0, g.t0, -g.before_reset_m)

    def _carry(self, t0: float, t1: float, metres: float):
        self._carried.append([t0, t1, metres])
        del self._carried[:-_MAX_CARRIED]


_MIN_EPOCH_M = 0.02               # an epoch's scale is read from its metres: over less, from their noise
_MAX_CARRIED = 64                 # gaps remembered for that scale (tilt auto's epoch keeps 400 steps)
SET_OFF_S = 0.5                   # a gap that opens this soon after a stand may open on a set-off
