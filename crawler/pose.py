"""The camera's pose from the flow field: its tilt, and each frame's pitch, height and sway. Pure: no I/O.

The odometer measures every frame against a keyframe with one mount (tilt, height below the crown).
The real camera moves about it: the car bounces (height), pitches, and the operator may turn it (the
tilt). Each shows in the tracks as a pattern of its own (crawler/posefield.py: how each feature's
wall position moves per radian of tilt and per metre of height or sway):

- pitch moves every row by about the same pixels, where travel moves them by the wall metres the
  row sees: the row profile of the flow tells them apart (weakly: a half-frame ROI sees little depth);
- height scales the image about the point above the camera: it spreads the features, travel does not;
- sway (the car weaving across the pipe) shifts the view along the arc and, in a cylinder, bends it:
  an axial pattern that, left out, reads as pitch (at 40 deg 2 mm of it: 0.2 deg in every reading);
- the tilt shows as a profile that grows with the step: a wrong tilt makes far and near features
  disagree on it (the wall metres each row sees depend on the tilt).

Per frame, the pitch, height and sway of this frame and of its keyframe (a clone of the state when
the keyframe was taken) are one small Kalman filter, with the jitter, bounce and weave as
stationary priors; the step is corrected for the pose of both frames. The tilt is configured
(FixedTilt) or estimated (crawler/autotilt.py). docs/odometry.md, "Pose", has the math.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from .autotilt import AutoTilt, AutoTiltParams
from .camturn import turn_pitch
from .consensus import shutter_factors
from .estimate import finite_round
from .posemodel import (HEIGHT, K_HEIGHT, K_PITCH, K_SWAY, MODEL, MODEL_FLAT, N_POSE, PITCH, SWAY, height_change,
                        prior_free)
from .poseport import NO_FIX, PoseFix
from .ride import RideHeight
from .tiltfit import far_apart
from .tiltport import FixedTilt, Hop


@dataclass(frozen=True)
class PoseParams:
    auto_tilt: bool = False
    pitch_sigma_deg: float = 0.25     # the car's pitch jitter ([odometry] pitch_jitter_deg); 0: not estimated
    pitch_tau_s: float = 0.1          # ...how long a pitch lasts
    bounce_sigma_mm: float = 1.0      # the suspension's bounce ([odometry] bounce_mm); 0: not estimated
    bounce_tau_s: float = 0.3
    sway_sigma_mm: float = 2.0        # the car's weave across the pipe ([odometry] sway_mm); 0: not estimated
    sway_tau_s: float = 1.0
    ride_height: bool = False         # the ride height's level from the height changes ([odometry] ride_height)
    ride_max_tilt_deg: float = math.inf   # ...only at a tilt found up to this (tilt auto's default: ride.MAX_TILT_DEG)
    correct_pose: bool = True         # False: pitch, height and sway only read, for the ride height (tilt auto)
    noise_scale: float = 4.0          # a feature's error persists over its keyframe's frames: count each ~1/16
    level_memory_s: float = 2.0       # how long the pitch and bounce the tracks show are remembered
    warm_up_s: float = 0.5            # ...and how long they are learned before they correct the distance
    tilt: AutoTiltParams = AutoTiltParams()


class PoseEstimator:
    """Tilt, pitch, height and sway of the camera, from the odometer's keyframe features and their tracks."""

    active = True

    def __init__(self, camera, projection, roi, params: PoseParams | None = None):
        self.p = params or PoseParams()
        self.camera = camera
        self._offset = np.array(roi[:2], np.float64)
        self.tilt = (AutoTilt(camera, projection, roi, self.p.tilt) if self.p.auto_tilt
                     else FixedTilt(camera, projection, roi))
        # a sway is only seen on the cylinder: to a plane it is a shift along the arc
        sway = self.p.sway_sigma_mm / 1000.0 if projection.name == "cylinder" else 0.0
        self._limit = (math.radians(self.p.pitch_sigma_deg), self.p.bounce_sigma_mm / 1000.0, sway)
        self._sig = list(self._limit)              # the levels the tracks show, at most the configured
        self._level = [[0.0] * N_POSE, [0.0] * N_POSE]   # running sums: excess square, expected per unit variance
        self._tau = (self.p.pitch_tau_s, self.p.bounce_tau_s, self.p.sway_tau_s)
        self._keep = [lim > 0 for lim in self._limit] * 2   # not estimated at all: held at zero
        self._kept = [i for i in range(N_POSE) if self._keep[i]]
        self._decay = (None,)                      # (dt, its decay of s and P, of the variances)
        self._forget()
        self._t = None
        self._warm_until = None                    # the first measured frame's time + warm_up_s
        self._found = False                        # tilt auto: the tilt found (the search done)
        self._riding = False                       # ...and the ride height read and applied at it
        self._serial = 0
        self._end = None                           # the last measured frame's d(step)/d(pitch, height, sway)
        self._closing = None                       # ...when that frame is the keyframe now
        self.ride = RideHeight(projection.mount.height_m) if self.p.ride_height else None
        self._ride_read = [i for i in _RIDE_READ if self._keep[i]]   # what its height change is read with
        self._read_dh = None                       # the last measured frame's information: its height change
        self._kf_at = None                         # the last keyframe's (distance, time)
        self.pitch_shown_rad = 0.0                 # the pitch the tracks show, beyond the configured too
        self._pitch_read = None                    # this frame's prior-free pitch and its variance

    @property
    def projection(self):
        return self.tilt.projection

    # -- the odometer's hooks ---------------------------------------------------------------------

    def keyframe(self, kf, px, t_s):
        """A new keyframe (its features at frame pixels px): their fields, and its pose is this
        frame's (a clone of the state)."""
        xy = self.camera.normalise(px) if self.tilt.auto else None    # tilt auto's readings need them
        self._serial += 1
        kf.pose = (self.tilt.field.at_roi(kf.pts), xy, self._serial)
        continuous = self._t is None or t_s == self._t    # the run's first, or on the frame just measured
        self._closing = self._end if continuous else None
        if self.ride and continuous and self._read_dh is not None and self._kf_at is not None and self._rides():
            change = height_change(*self._read_dh, self._ride_read)
            if change is not None:
                self.ride.handover(*change, kf.distance - self._kf_at[0], t_s - self._kf_at[1],
                                   self._sig[HEIGHT], self.p.bounce_tau_s)
        self._read_dh, self._kf_at = None, (kf.distance, t_s)
        self._predict(t_s)
        self.s[N_POSE:] = self.s[:N_POSE]
        self.P[N_POSE:, :] = self.P[:N_POSE, :]
        self.P[:, N_POSE:] = self.P[:, :N_POSE]
        self.tilt.closed(continuous, t_s)

    def new_count(self, delta_m: float = 0.0):     # the operator's reset: no step before it measured again,
        self.tilt.new_count()                      # and the ride's keyframe counted in the new count too
        if self._kf_at is not None:
            self._kf_at = (self._kf_at[0] + delta_m, self._kf_at[1])

    def measure(self, kf, c, t_s) -> PoseFix:
        """One measured frame: the odometer's consensus c (crawler/odometry.py): the keyframe's inlier
        indices, their positions now, displacements (lateral, axial, metres) and spread, and every
        track's. The tilt reads every track: the inliers, chosen at its tilt, would hide a wrong one."""
        idx = c.idx
        if kf.pose is None or len(idx) < 3:
            return NO_FIX
        t_idx, t_pts, t_moved, both = c.tracks
        self._pitch_read = None                    # this frame's prior-free pitch, once read
        moved = t_moved.compress(both, 1)
        self._predict(t_s)
        if self.tilt.auto:
            t_xy = self.camera.normalise(t_pts + self._offset)
            xy = t_xy.compress(both, 0)
            moved_px = abs(float(moved[1].mean())) / (self.projection.mount.height_m / self.camera.fy)
            base = self.tilt.update(kf.pose[2], kf.pose[1].take(t_idx, 0), t_xy, moved_px, t_s,
                                    shutter_factors(self.camera, kf, t_idx, t_pts[:, 1] + self._offset[1], t_s))
        else:                                      # a configured tilt reads the inliers only
            xy, base = None, 0.0
        rescaled = base
        jc = self.tilt.field.at_roi(c.pts)
        hh, hz, zz, means = self._information(kf.pose[0].take(idx, 0), jc, moved, self.tilt.tau)
        if self.tilt.auto and self.tilt.turn.on:   # a turn of the camera followed: solved, not filtered
            fix = self._turn_frame(kf, c, t_idx, t_xy, None, base, t_s)
            if fix is not None:
                return fix
        found = self._found_now(t_s)
        if any(self._limit):                       # pitch, height or sway estimated at all
            base += self._filter(hh, hz, zz, c.sigma, 2 * len(idx), t_s - kf.t_s,
                                 learn_only=t_s < self._warm_until or not found or not self.p.correct_pose)
            if not found:                          # read at a tilt searched for, a pitch is the tilt's
                self.pitch_shown_rad = 0.0         # error, which its own sigma counts
        if found and self.tilt.auto:               # a pitch that is a turn of the camera? (the filter's
            read = turn_pitch(self._pitch_read, hh, hz, zz, 2 * len(idx), means, self._kept)   # refinement: the car's)
            fix = self._turn_frame(kf, c, t_idx, t_xy, read, rescaled, t_s) if read else None
            if fix is not None:
                return fix
        turn = self.tilt.keyframe_offset(t_s - kf.t_s)     # a camera turning: its keyframe at another tilt
        step, lat, sens = self._correction(means, self.tilt.tau, turn)
        scale = 0.0
        if self.ride and self.ride.level_m and self._rides():    # a ride height scales the whole step
            scale = self.ride.level_m / self.projection.mount.height_m
            step, lat = step + (c.step + step) * scale, lat + (c.lat + lat) * scale
        if self.tilt.auto:
            self.tilt.level_m = scale * self.projection.mount.height_m
            pose = tuple((self.s.take(_TILT_POSE) + (0.0, 0.0, turn, 0.0)).tolist())   # keyframe's at the turn's tilt
            self.tilt.record(Hop(t_s, self.projection, kf.pose[1].take(idx, 0), xy, moved[1].copy(), pose,
                                 float(moved[1].mean()) + step, sens * (1.0 + scale), scale, turn, kf.t_s))
        old = self.projection
        remount, extra = self.tilt.remount()
        if remount is not None and far_apart(old, remount, self.p.tilt.found_sigma_deg):
            self._forget()                         # its pitch and height were the tilt's error
        c.step, c.lat, kf.distance = c.step + step, c.lat + lat, kf.distance + base + extra
        return PoseFix(step, lat, base + extra, remount, rescaled + extra, *(self.tilt.epoch if rescaled + extra else ()))

    def _found_now(self, t_s) -> bool:
        """Is the tilt known (configured, or found)? Read at a tilt not yet found, the pose takes up
        its error: learnt afresh from when it is. The ride height is decided once per tilt found (a
        bank's rise moves the estimate by ~1 deg, and a gate on the estimate closed on the climb and
        lost it: 29.5 deg, +1.55 %), and again once a turn of the camera is over."""
        found = not self.tilt.auto or self.tilt.track is not None
        if self._warm_until is None or (found and not self._found):
            self._warm_until = t_s + self.p.warm_up_s
            self._relearn()
            self._riding = None
        if self.tilt.turning:
            self._riding = None
        elif self._riding is None:
            self._riding = found and abs(self.tilt_deg) <= self.p.ride_max_tilt_deg
        self._found = found
        return found

    def _turn_frame(self, kf, c, t_idx, t_xy, read, base, t_s):
        """A frame of a camera turned at a stand (crawler/camturn.py): its step solved with the turn,
        nothing filtered (the pitch is the turn's), or None: no turn."""
        rows = ((kf.row_t.take(t_idx), self.camera.row_time(c.tracks[1][:, 1] + self._offset[1]))
                if self.camera.readout_s > 0 else None)   # a rolling shutter: each track's exposure time
        solved = self.tilt.follow_turn(kf.pose[2], kf.pose[1].take(t_idx, 0), t_xy, read, t_s, rows)
        if solved is None:
            return None
        step, lat = solved[0] - c.step, solved[1] - c.lat
        base += solved[2]                          # the step before, where the turn began, solved again
        self._riding, self._end, self.pitch_shown_rad = None, None, 0.0   # the pitch is the turn's
        if not self.tilt.turn.on:                  # over: the pose learnt afresh at the tilt reached
            self._relearn()
            self._warm_until = t_s + self.p.warm_up_s
        remount, extra = self.tilt.remount()
        c.step, c.lat, kf.distance = solved[0], solved[1], kf.distance + base + extra
        return PoseFix(step, lat, base + extra, remount, base + extra, *(self.tilt.epoch if base + extra else ()))

    def _rides(self) -> bool:
        """The ride height is read and applied: at a tilt found (tilt auto) and, when it was found,
        not beyond where its readings hold (at 40 deg they drift alike and the chain sums them)."""
        return self._found and bool(self._riding)

    def checkpoint(self) -> dict:
        """What a restarted daemon starts from: tilt auto's estimate once found."""
        return self.tilt.checkpoint()

    def resume(self, saved):
        """The checkpoint's tilt (crawler/checkpoint.py checked it), for tilt auto: the projection
        the odometer measures with from the first frame, or None."""
        return self.tilt.resume(saved) if saved else None

    def status(self) -> dict:
        """What the daemon's status says of the pose (docs/topics.md)."""
        auto = self.tilt.auto
        return {**self.frame(), "tilt_sigma_deg": finite_round(math.degrees(self.tilt.sigma_rad), 3) if auto else None,
                "tilt_auto": auto, "tilt_steps": self.tilt.steps, "tilt_turning": self.tilt.turning}

    def frame(self) -> dict:
        """What each published estimate says of the pose: the camera's tilt, pitch and height now."""
        return {"tilt_deg": finite_round(self.tilt_deg, 3), "pitch_deg": finite_round(math.degrees(self.s[PITCH]), 3),
                "camera_height_m": finite_round(self.height_m, 5)}

    @property
    def tilt_deg(self) -> float:
        return math.degrees(self.projection.mount.tilt_rad + self.tilt.tau)

    @property
    def scale_sigma_m(self) -> float:
        """What the tilt's uncertainty (crawler/autotilt.py) and the ride height's leave in the distance."""
        return math.hypot(self.tilt.distance_sigma_m, self.ride.spent_sigma_m if self.ride else 0.0)

    @property
    def height_m(self) -> float:
        if self.ride:                              # the ride's level at the keyframe, and the change since
            level = self.ride.level_m if self._rides() else 0.0
            return self.projection.mount.height_m + level + float(self.s[HEIGHT] - self.s[K_HEIGHT])
        return self.projection.mount.height_m + float(self.s[HEIGHT])

    # -- the filter -------------------------------------------------------------------------------

    def _filter(self, hh, hz, zz, sigma, rows, since_kf, learn_only=False) -> float:
        """This frame's tracks (the model's information H'H, H'z) into the pitch and height: the
        metres the keyframe's better known pose gives the step before it. While the levels are
        still the prior's (learn_only, warm_up_s) the state stays at zero: nothing is corrected,
        and the estimate begins later as from a fresh start, with the levels the tracks showed."""
        sigma = self._learn_levels(hh, hz, zz, rows, since_kf) or sigma
        if learn_only:
            return 0.0
        var = self._noise_var(sigma)
        before = self.s[N_POSE:].tolist()
        self._update(hh / var, hz / var)
        return self._refined([a - b for a, b in zip(self.s[N_POSE:].tolist(), before)])

    def _relearn(self):
        """A tilt just found: what was learnt at the tilt before, levels and state, is its error."""
        self._sig = list(self._limit)
        self._level = [[0.0] * N_POSE, [0.0] * N_POSE]
        self._forget()

    def _forget(self):
        """Back to the prior: no pitch, height or sway known."""
        d = np.diag(np.square(self._sig))
        self.s = np.zeros(2 * N_POSE)
        self.P = np.block([[d, d], [d, d]])

    def _predict(self, t_s):
        dt = 0.0 if self._t is None else max(t_s - self._t, 0.0)
        self._t = t_s
        if dt == 0.0:
            return
        if dt != self._decay[0]:                   # a camera's frame interval repeats: its decay too
            rho = [math.exp(-dt / tau) for tau in self._tau]
            phi = np.array(rho + [1.0] * N_POSE)
            self._decay = (dt, phi, np.outer(phi, phi), [1 - r * r for r in rho])
        _, phi, phi2, q = self._decay
        self.s *= phi
        self.P *= phi2
        flat = self.P.reshape(-1)
        for at, sig, qi in zip(_DIAG, self._sig, q):    # P[i, i] of this frame's pose
            flat[at] += sig * sig * qi

    def _learn_levels(self, hh, hz, zz, rows, since_kf) -> float | None:
        """How much the car really pitches, bounces and sways: this frame's prior-free reading of its
        pose against the keyframe's, squared, less what its noise alone gives, against what an AR(1)
        level of unit variance gives over this interval. A smooth run gets no pitch or height it does
        not show, a shaky one up to the configured level. Returns the features' noise, their scatter
        about that reading (the consensus's spread holds the pose's own pattern: as noise it hid the
        pitch), or None where the reading cannot be had."""
        k = self._kept
        solved = prior_free(hh, hz, zz, rows, k)
        if solved is None:
            return None
        d, cov, sigma = solved
        memory = math.exp(-1.0 / (30.0 * self.p.level_memory_s))    # per frame, at ~30 fps
        since = max(since_kf, 0.0)
        (e, u), shown = self._level, []
        for i, tau in enumerate(self._tau):
            e[i] = e[i] * memory + d[i] * d[i] - cov[i]
            u[i] = u[i] * memory + 2.0 * (1.0 - math.exp(-since / tau))
            level = e[i] / u[i] if u[i] > 0 else 0.0
            shown.append(math.sqrt(max(level, 0.0)))
        self._sig = [min(limit, s) for limit, s in zip(self._limit, shown)]
        self.pitch_shown_rad = shown[PITCH]
        if PITCH in k:
            self._pitch_read = (d[PITCH], cov[PITCH])
        if self.ride:
            self._read_dh = (hh, hz, zz, rows)
        return sigma

    def _information(self, jk, jc, moved, tau):
        """H'H and H'z of the linear model z = H s of the centred displacements, and the means of
        H's and z's columns. Stacked axial, lateral: where each feature was and is, a tilt or a
        pitch moves its wall position differently, so the keyframe's pitch has a pattern of its
        own; its height counts only as the shift it explains (the level of the height is not
        observable). Each row of H and z is a fixed combination of a feature's (jc, jk, moved)
        (posemodel.MODEL), so all of it is one product and one Gram matrix: on the Pi the cost is the
        number of numpy calls, not the arithmetic."""
        a = np.dot((1.0, tau, float(self.s[K_HEIGHT])), MODEL_FLAT).reshape(MODEL.shape[1:])
        y = np.concatenate([jc, jk, moved.T], axis=1).dot(a)    # (n, 14): axial H, z | lateral H, z
        mean = np.add.reduce(y, 0) * (1.0 / len(y))
        y -= mean
        y = y.reshape(-1, 2 * N_POSE + 1)          # each feature's axial row, then its lateral row
        g = y.T.dot(y)
        n = 2 * N_POSE
        return g[:n, :n], g[:n, n], float(g[n, n]), mean.tolist()

    def _update(self, info, eta):
        """The Kalman update in information form, P' = (I + P info)^-1 P; a pose the prior holds at
        zero variance (not estimated) stays at zero. (cv2.solve: a quarter of numpy.linalg's cost
        on the Pi for these small matrices.)"""
        keep = self._keep
        if not any(keep):
            return
        full = all(keep)                           # all estimated: no sub-matrices to cut
        k = None if full else np.ix_(keep, keep)
        p, s, info, eta = (self.P, self.s, info, eta) if full else (self.P[k], self.s[keep], info[k], eta[keep])
        ok, p_new = cv2.solve(_EYE[len(p)] + p.dot(info), p, flags=cv2.DECOMP_LU)
        if not ok:
            return
        s_new = s + p_new.dot(eta - info.dot(s))
        cv2.completeSymm(p_new)                    # symmetric but for rounding
        if full:
            self.s, self.P = s_new, p_new
        else:
            self.s[keep], self.P[k] = s_new, p_new

    def _noise_var(self, sigma):
        """The per-feature noise: their scatter about the pose read (_learn_levels), persistent errors
        counted in (noise_scale)."""
        floor = 0.05 * self.projection.mount.height_m / self.camera.fy     # 0.05 px: never tighter
        return (max(sigma, floor) * self.p.noise_scale) ** 2

    # -- distance ----------------------------------------------------------------------------------

    def _refined(self, change) -> float:
        """The keyframe's pose, better known now, also ends the step before it: that step again."""
        if self._closing is None:
            return 0.0
        return -sum(j * c for j, c in zip(self._closing, change))

    def _correction(self, means, tau, turn=0.0):
        """Metres to add to the step and the lateral step, and d step/d tilt. Tilt and pitch count
        where each feature was and is; the height only as this frame's less the keyframe's (the
        scale it causes): its level is not observable, and a level that wandered would scale every
        step (docs/odometry.md, "Pose")."""
        m = means       # of H's columns: axial jc1, jc3, jc5, -jk1, -jc3, -jk5, z | lateral jc0, jc2, jc4, -jk0, ...
        mc, mk = (m[7], m[0], m[8], m[1]), (-m[10], -m[3])
        xc, xk = m[2], -m[5]                       # dy/dsway where the features are and were
        self._end = (mc[1], mc[3], xc)
        pc, hc, sc, pk, hk, sk = self.s.tolist()
        pk += turn                                 # a turning camera's keyframe: at the tilt it had then
        dh = hc - hk
        step = (mk[1] - mc[1]) * tau + mk[1] * pk - mc[1] * pc - mc[3] * dh + xk * sk - xc * sc
        lat = (mc[0] - mk[0]) * tau + mc[0] * pc - mk[0] * pk + mc[2] * dh
        return step, lat, mk[1] - mc[1]


_EYE = [np.eye(n) for n in range(2 * N_POSE + 1)]
_DIAG = [i * (2 * N_POSE + 1) for i in range(N_POSE)]   # P's flat indices of this frame's variances
_RIDE_READ = [PITCH, HEIGHT, SWAY, K_PITCH, K_SWAY]     # the height change read with all but the keyframe's height
_TILT_POSE = [PITCH, HEIGHT, K_PITCH, K_HEIGHT]         # what tilt auto's re-measure corrects for
