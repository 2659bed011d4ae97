"""The camera's pose from the flow field: its tilt, and each frame's pitch and height. Pure: no I/O.

The odometer measures every frame against a keyframe with one mount (tilt, height below the crown).
The real camera moves about it: the car bounces (height), pitches (a rotation), and the operator may
turn the camera (the tilt itself). Each shows in the tracks as a pattern of its own, fixed by the
geometry (crawler/posefield.py gives, for every feature, how its wall position moves per radian of
tilt and per metre of height):

- pitch moves every row by about the same number of pixels, whatever the wall's distance, where
  travel moves them by the wall metres the row sees: the row profile of the flow tells them apart
  (weakly: a half-frame ROI sees little depth range);
- height scales the image about the point straight above the camera: it spreads the features
  across the image, which travel does not (well seen);
- the tilt shows as a profile that grows with the step itself: for a cylinder, the wall metres each
  row sees depend on the tilt, so a wrong tilt makes far and near features disagree on the step.

Per frame, the pitch and height of this frame and of its keyframe (a clone of the state when the
keyframe was taken) are one small Kalman filter, with the jitter and bounce as stationary priors.
The step the odometer reports is then corrected for the pose of both frames, so a bounce or a pitch
is not read as travel. The tilt is configured (FixedTilt) or estimated (crawler/autotilt.py).
docs/odometry.md, "Pose", has the math.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .autotilt import AutoTilt, AutoTiltParams, FixedTilt, Hop, far_apart
from .estimate import finite_round


@dataclass(frozen=True)
class PoseParams:
    auto_tilt: bool = False
    pitch_sigma_deg: float = 0.25     # the car's pitch jitter ([odometry] pitch_jitter_deg); 0: not estimated
    pitch_tau_s: float = 0.1          # ...how long a pitch lasts
    bounce_sigma_mm: float = 1.0      # the suspension's bounce ([odometry] bounce_mm); 0: not estimated
    bounce_tau_s: float = 0.3
    noise_scale: float = 4.0          # a feature's error persists over its keyframe's frames: count each ~1/16
    level_memory_s: float = 2.0       # how long the pitch and bounce the tracks show are remembered
    tilt: AutoTiltParams = AutoTiltParams()


@dataclass(frozen=True)
class PoseFix:
    """What the odometer applies to a frame: metres added to its step and lateral step, to the
    keyframe's distance (earlier steps measured again), and the projection to move to."""

    step_m: float = 0.0
    lat_m: float = 0.0
    base_m: float = 0.0
    remount: object = None


NO_FIX = PoseFix()


class NullPose:
    """The odometer without a pose estimate: the mount is what the configuration says."""

    active = False

    def __init__(self, tilt_deg: float | None = None):
        self.tilt_deg = tilt_deg

    def keyframe(self, kf, px, t_s):
        pass

    def measure(self, kf, c, t_s) -> PoseFix:
        return NO_FIX

    def status(self) -> dict:
        return {"tilt_deg": self.tilt_deg, "tilt_sigma_deg": None, "tilt_auto": False}

    def frame(self) -> dict:
        return {}

    def checkpoint(self) -> dict:
        return {}

    def resume(self, saved) -> None:
        return None


PITCH, HEIGHT, K_PITCH, K_HEIGHT = range(4)   # the state: this frame's pose, the keyframe's


class PoseEstimator:
    """Tilt, pitch and height of the camera, from the odometer's keyframe features and their tracks."""

    active = True

    def __init__(self, camera, projection, roi, params: PoseParams | None = None):
        self.p = params or PoseParams()
        self.camera = camera
        self._offset = np.array(roi[:2], np.float64)
        self.tilt = (AutoTilt(camera, projection, roi, self.p.tilt) if self.p.auto_tilt
                     else FixedTilt(camera, projection, roi))
        self._limit = np.array([math.radians(self.p.pitch_sigma_deg), self.p.bounce_sigma_mm / 1000.0])
        self._sig = self._limit.copy()             # the levels the tracks show, at most the configured
        self._level = np.zeros((2, 2))             # running sums: excess square, expected per unit variance
        self._tau = np.array([self.p.pitch_tau_s, self.p.bounce_tau_s])
        self.s = np.zeros(4)
        self.P = np.tile(np.diag(self._sig ** 2), (2, 2))
        self._t = None
        self._serial = 0
        self._end = None                           # the last measured frame's d(step)/d(pitch, height)
        self._closing = None                       # ...when that frame is the keyframe now

    @property
    def projection(self):
        return self.tilt.projection

    # -- the odometer's hooks ---------------------------------------------------------------------

    def keyframe(self, kf, px, t_s):
        """A new keyframe (its features at frame pixels px): their fields, and its pose is this
        frame's (a clone of the state)."""
        xy = self.camera.normalise(px)
        self._serial += 1
        kf.pose = (self.tilt.field.at(xy), xy, self._serial)
        continuous = self._t is None or t_s == self._t    # the run's first, or on the frame just measured
        self._closing = self._end if continuous else None
        self._predict(t_s)
        self.s[2:] = self.s[:2]
        self.P[2:, :] = self.P[:2, :]
        self.P[:, 2:] = self.P[:, :2]
        self.tilt.closed(continuous, t_s)

    def measure(self, kf, c, t_s) -> PoseFix:
        """One measured frame: the odometer's consensus c (crawler/odometry.py) gives the keyframe's
        inlier indices, their positions now (normalised), their displacements (rows lateral, axial,
        metres), its robust spread (metres), and the same for every track. The tilt reads every
        track: the consensus chose its inliers at the tilt it has, and would hide a wrong one."""
        idx = c.idx
        if kf.pose is None or len(idx) < 3:
            return NO_FIX
        t_idx, t_pts, t_moved, both = c.tracks
        t_xy = self.camera.normalise(t_pts + self._offset)
        xy, moved = t_xy.compress(both, 0), t_moved.compress(both, 1)
        self._predict(t_s)
        jk, jc, xy_k = kf.pose[0].take(idx, 0), self.tilt.field.at(xy), kf.pose[1].take(idx, 0)
        moved_px = abs(float(moved[1].mean())) / (self.projection.mount.height_m / self.camera.fy)
        base = self.tilt.update(kf.pose[2], kf.pose[1].take(t_idx, 0), t_xy, moved_px, t_s,
                                self._shutter(kf, t_idx, t_pts, t_s))
        if self._limit.any():                      # pitch or height estimated at all
            base += self._filter(jk, jc, moved, c.sigma, t_s - kf.t_s)
        step, lat, sens = self._correction(jk, jc, self.tilt.tau)
        if self.tilt.auto:
            self.tilt.record(Hop(t_s, self.projection, xy_k, xy, moved[1].copy(), tuple(self.s),
                                 float(moved[1].mean()) + step, sens))
        old = self.projection
        remount, extra = self.tilt.remount()
        if remount is not None and far_apart(old, remount, self.p.tilt.found_sigma_deg):
            self._forget()                         # its pitch and height were the tilt's error
        c.step, c.lat, kf.distance = c.step + step, c.lat + lat, kf.distance + base + extra
        return PoseFix(step, lat, base + extra, remount)

    def _shutter(self, kf, idx, pts, t_s):
        """Each track's rolling-shutter factor: the frame interval over the time between the two
        exposures of its feature (rows read later moved for longer), as the odometer scales them."""
        dt = t_s - kf.t_s
        if self.camera.readout_s <= 0 or dt <= 0:
            return None
        span = dt + self.camera.row_time(pts[:, 1] + self._offset[1]) - kf.row_t.take(idx)
        return dt / np.maximum(span, 0.2 * dt)

    def checkpoint(self) -> dict:
        """What a restarted daemon starts from: tilt auto's estimate once found."""
        if not self.tilt.auto or self.tilt.track is None:
            return {}
        return {"tilt": {"deg": round(self.tilt_deg, 4), "sigma_deg": round(math.degrees(self.tilt.sigma_rad), 4)}}

    def resume(self, saved):
        """The checkpoint's tilt (crawler/checkpoint.py checked it), for tilt auto: the projection
        the odometer measures with from the first frame, or None."""
        if not self.tilt.auto or not saved:
            return None
        return self.tilt.resume(math.radians(saved["deg"]))

    def status(self) -> dict:
        """What the daemon's status says of the pose (docs/topics.md)."""
        auto = self.tilt.auto
        return {**self.frame(), "tilt_sigma_deg": finite_round(math.degrees(self.tilt.sigma_rad), 3) if auto else None,
                "tilt_auto": auto, "tilt_steps": self.tilt.steps}

    def frame(self) -> dict:
        """What each published estimate says of the pose: the camera's tilt, pitch and height now."""
        return {"tilt_deg": finite_round(self.tilt_deg, 3), "pitch_deg": finite_round(math.degrees(self.s[PITCH]), 3),
                "camera_height_m": finite_round(self.height_m, 5)}

    @property
    def tilt_deg(self) -> float:
        return math.degrees(self.projection.mount.tilt_rad + self.tilt.tau)

    @property
    def height_m(self) -> float:
        return self.projection.mount.height_m + float(self.s[HEIGHT])

    # -- the filter -------------------------------------------------------------------------------

    def _filter(self, jk, jc, moved, sigma, since_kf) -> float:
        """This frame's tracks into the pitch and height: the metres the keyframe's better known
        pose gives the step before it."""
        H, z = self._model(jk, jc, moved, self.tilt.tau)
        self._learn_levels(H, z, sigma, since_kf)
        var = self._noise_var(sigma)
        before = self.s[2:].copy()
        self._update(H.T.dot(H) / var, H.T.dot(z) / var)
        return self._refined(self.s[2:] - before)

    def _forget(self):
        """Back to the prior: no pitch or height known."""
        self.s[:] = 0.0
        self.P = np.tile(np.diag(self._sig ** 2), (2, 2))

    def _predict(self, t_s):
        dt = 0.0 if self._t is None else max(t_s - self._t, 0.0)
        self._t = t_s
        phi = np.exp(-dt / self._tau)
        self.s[:2] *= phi
        self.P[:2, :] *= phi[:, None]
        self.P[:, :2] *= phi[None, :]
        self.P[:2, :2] += np.diag(self._sig ** 2 * (1 - phi ** 2))

    def _learn_levels(self, H, z, sigma, since_kf):
        """How much the car really pitches and bounces, from this frame's own (prior-free) reading of
        its pose against the keyframe's: its square, less what its noise alone would give, against
        what an AR(1) level of unit variance would give over this interval. A smooth run then gets no
        pitch or height it does not show (each would add its noise to every step), a shaky one up to
        the configured level."""
        g = H[:, :2]
        a = g.T.dot(g)
        try:
            cov = np.linalg.inv(a) * max(sigma, 1e-9) ** 2
            d = np.linalg.solve(a, g.T.dot(z))
        except np.linalg.LinAlgError:
            return
        keep = math.exp(-1.0 / (30.0 * self.p.level_memory_s))      # per frame, at ~30 fps
        unit = 2.0 * (1.0 - np.exp(-max(since_kf, 0.0) / self._tau))
        self._level *= keep
        self._level[0] += d * d - np.diag(cov)
        self._level[1] += unit
        with np.errstate(divide="ignore", invalid="ignore"):
            level = np.where(self._level[1] > 0, self._level[0] / self._level[1], 0.0)
        self._sig = np.minimum(self._limit, np.sqrt(np.clip(level, 0.0, None)))

    def _model(self, jk, jc, moved, tau):
        """The linear model z = H s of the centred displacements (stacked axial, lateral): where each
        feature was and is, a tilt or a pitch moves its wall position differently, so the keyframe's
        pitch has a pattern of its own; its height counts only as the shift it explains (the level
        of the height is not observable)."""
        d = jc - jk
        hk = self.s[K_HEIGHT]
        z = np.concatenate([_c(moved[1] - d[:, 1] * tau - d[:, 3] * hk),
                            _c(-moved[0] - d[:, 0] * tau - d[:, 2] * hk)])
        H = np.empty((len(z), 4))
        H[:, PITCH] = np.concatenate([_c(jc[:, 1]), _c(jc[:, 0])])
        H[:, HEIGHT] = np.concatenate([_c(jc[:, 3]), _c(jc[:, 2])])
        H[:, K_PITCH] = -np.concatenate([_c(jk[:, 1]), _c(jk[:, 0])])
        H[:, K_HEIGHT] = -H[:, HEIGHT]
        return H, z

    def _update(self, info, eta):
        """The Kalman update in information form, P' = (I + P info)^-1 P; a pose the prior holds at
        zero variance (not estimated) stays at zero."""
        keep = np.diag(self.P) > 0
        if not keep.any():
            return
        k = np.ix_(keep, keep)
        p, s = self.P[k], self.s[keep]
        try:
            p_new = np.linalg.solve(np.eye(len(p)) + p.dot(info[k]), p)
        except np.linalg.LinAlgError:
            return
        self.s[keep] = s + p_new.dot(eta[keep] - info[k].dot(s))
        self.P[k] = 0.5 * (p_new + p_new.T)

    def _noise_var(self, sigma):
        """The per-feature noise: the consensus's spread, persistent errors counted in (noise_scale)."""
        floor = 0.05 * self.projection.mount.height_m / self.camera.fy     # 0.05 px: never tighter
        return (max(sigma, floor) * self.p.noise_scale) ** 2

    # -- distance ----------------------------------------------------------------------------------

    def _refined(self, change) -> float:
        """The keyframe's pose, better known now, also ends the step before it: that step again."""
        if self._closing is None:
            return 0.0
        return -float(self._closing[0] * change[0] + self._closing[1] * change[1])

    def _correction(self, jk, jc, tau):
        """Metres to add to the step and the lateral step, and d step/d tilt. Tilt and pitch count
        where each feature was and is; the height only as this frame's less the keyframe's (the
        scale it causes): its level is not observable, and a level that wandered would scale every
        step (docs/odometry.md, "Pose")."""
        mk, mc = jk.mean(axis=0), jc.mean(axis=0)
        self._end = (mc[1], mc[3])
        pc, pk, dh = self.s[PITCH], self.s[K_PITCH], self.s[HEIGHT] - self.s[K_HEIGHT]
        step = (mk[1] - mc[1]) * tau + mk[1] * pk - mc[1] * pc - mc[3] * dh
        lat = (mc[0] - mk[0]) * tau + mc[0] * pc - mk[0] * pk + mc[2] * dh
        return float(step), float(lat), float(mk[1] - mc[1])


def _c(a: np.ndarray) -> np.ndarray:
    return a - a.mean()
