"""From grey frames and their times to distance along the pipe. Pure: no I/O, no logging.

Each feature is measured against the keyframe it was found in, not the previous frame: LK on
compressed video is biased toward zero motion on every image pair, and one long baseline carries
that bias once instead of once per frame. The previous frame only supplies the starting guess (a
phase-correlation shift turned into a wall displacement, so the guess follows the geometry of every
row). Per-feature axial displacements, corrected for rolling shutter, make one median/MAD step.

A frame is measured only when it can be (gates.py): without texture it gets the dense shift
(dense.py) or nothing; a consensus no crawler's acceleration allows is refused. Frames not
measured are reported as lost; gaps.py carries the distance across them and says so.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from . import flow
from .consensus import LATERAL_AXIAL, Consensus, SpeedFilter, robust_step, rolling_shutter
from .dense import DenseShift
from .densegrid import centre_jacobian, dense_conversion
from .estimate import Estimate
from .gates import FrameGates, SpreadGate, reacquired
from .geometry import Camera, Projection
from .keyframe import Keyframe, keyframe_features, motion_model, track_visible
from .odometry_params import OdometryParams
from .poseport import NullPose


class Odometer:
    """Turns a stream of grey frames into distance, speed, lateral motion and a quality figure."""

    def __init__(self, camera: Camera, projection: Projection, roi, params: OdometryParams | None = None,
                 tracker=track_visible, pose=None):
        self.camera = camera
        self.pose = pose or NullPose()     # crawler/pose.py: the camera's tilt, pitch and height
        self.roi = tuple(int(v) for v in roi)
        self.params = params or OdometryParams()
        x, y, w, h = self.roi
        self._offset = np.array([x, y], np.float64)
        self._border = b = self.params.flow.win_px // 2 + 1
        # where a guess must fall for the feature to be tracked, as a box's centre and half-size
        mid = np.float32([(w - 1) / 2.0, (h - 1) / 2.0])
        self.view, self._views = (mid, mid - b), {}    # ...and tiled for n points (cheaper numpy)
        self._dense = DenseShift((h, w), self.params.dense)
        self.remount(projection)
        lvl = self.params.flow.coarse_level
        self._coarse_scale = float(2 ** lvl)
        small = (math.ceil(h / 2 ** lvl), math.ceil(w / 2 ** lvl))
        self._window = cv2.createHanningWindow(small[::-1], cv2.CV_32F)
        self._rs = camera.readout_s > 0
        self.reference_seq = 0     # counts new references, so a writer knows when to save one
        self.tracker = tracker     # keyframe.track_visible here, or what crawler/workers.py tracked
        self.reset()

    # -- public -------------------------------------------------------------------------------------

    def reset(self, distance: float = 0.0, lateral: float = 0.0):
        """Forget the keyframe and start counting from the given distance."""
        self.distance, self.lateral = distance, lateral
        self.frame, self.lost_frames = -1, 0
        self._kf = self._kf_last = None   # Keyframes: the one measured against; the last, while dense
        self._good_coarse = None   # (flat, quarter-size ROI of the last tracked frame), for the guess
        self._good_roi, self._good_at = None, (distance, lateral)   # ...and its distance, lateral
        self._prev_t = None
        self._last_good_t = 0.0
        self._prev_pts = None      # last tracked positions of the keyframe's features (ROI px)
        self._prev_origin = None   # ...and where they were found: (keyframe, indices)
        self._last_step = 0.0      # the tracks' step since the keyframe at the previous frame (before the pose fix)
        self._last_lat = 0.0
        self._velocity = 0.0       # the guess's speed (m/s)
        self._gates = FrameGates(self.params)
        self._motion_v = 0.0       # image rows the wall moved in the last tracked frame
        self._jv = 0.0
        self._unmeasured_since = None   # the first frame not measured since the last measurement
        self._after_dense = False  # the last measurement was dense: a new keyframe misses a frame's motion
        self._dense.reset()
        self._dense.stands.reset()
        self._speed = SpeedFilter(self.params.speed_window_s)
        self._spread = SpreadGate(self.params, self.m_per_px)
        self._blind_restart, self._resumed = False, False   # _resumed: the keyframe is a saved one (a clear match)
        self._copy = False         # this frame is, inside a gap, the encoder's copy of the last (gates.py)
        self._energy = math.inf    # this frame's fine texture (flow.texture_energy)

    def set_distance(self, distance: float = 0.0):
        """Count from `distance` now, without losing track (an operator's reset mid-run)."""
        delta, self.distance = distance - self.distance, distance
        if self._kf is not None:
            self._kf.distance += delta
        self._speed.reset()
        self.pose.new_count(delta)  # tilt auto measures no step from before it again into the new count

    def update(self, frame: np.ndarray, t_s: float, intra: bool = False) -> Estimate:
        """Process one full grey frame (only its ROI is read) taken at t_s s (`intra`: an I-frame)."""
        self.frame += 1
        if intra:                  # coded anew: the stand watch compares nothing across it
            self._dense.stands.recoded()
        x, y, w, h = self.roi
        roi = frame[y:y + h, x:x + w]
        try:
            self._energy = energy = flow.texture_energy(roi)
            self._copy = self._gates.copied(roi, self._unmeasured_since is not None, energy)
            if not self._gates.textured(energy) or self._gates.dark(roi):   # (a blackout's noise is texture)
                return self._untextured(roi, t_s, energy)
            self._dense.reset()
            est = self._start(roi, t_s) if self._kf is None else self._measure(roi, t_s)
            if est.tracking:
                self._gates.remember(roi, energy)
                self._dense.stands.measured()
                est.texture_dn = energy
            else:
                est.stand = self._dense.watch(roi, t_s)
            return est
        finally:
            self._prev_t = t_s

    @property
    def reference(self):
        """(ROI image, distance, lateral) of the last tracked frame (the odometer's own copy), or None."""
        return None if self._good_roi is None else (self._good_roi, *self._good_at)

    def resume_from(self, img: np.ndarray, distance: float, lateral: float, t_s: float) -> bool:
        """Start from a saved reference (a restart): its image is the keyframe, at its distance. The next
        frames are measured against it with the wide search; not overlapping, it starts afresh (continuous)."""
        self.reset(distance, lateral)
        if img.shape != (self.roi[3], self.roi[2]) or not self._new_keyframe(img, t_s):
            self.reset(distance, lateral)
            self._blind_restart = True
            return False
        self.lost_frames = 1          # the frames while the daemon was down are lost ones
        self._resumed = True
        return True

    @property
    def keyframe(self) -> Keyframe | None:
        """The keyframe frames are measured against now (None: none yet, or lost)."""
        return self._kf

    def guess(self, t_s: float) -> tuple[float, float]:
        """(step, lateral) from the keyframe that constant velocity predicts at t_s: tracking starts there."""
        return self._last_step + self._velocity * (t_s - self._last_good_t), self._last_lat

    @property
    def tracked_points(self) -> np.ndarray:
        """Current positions (frame pixels) of the features in use, for drawing."""
        return np.empty((0, 2)) if self._prev_pts is None else self._prev_pts + self._offset

    @property
    def track_origins(self) -> np.ndarray:
        """Where the features in tracked_points were found in their keyframe (frame pixels)."""
        if self._prev_origin is None or self._prev_pts is None:
            return np.empty((0, 2))
        kf, idx = self._prev_origin
        return kf.pts[idx] + self._offset

    # -- internals ----------------------------------------------------------------------------------

    def remount(self, projection: Projection):
        """Measure with this projection (a new tilt): the gates' unit and the shift's Jacobians."""
        self.projection = projection
        self._jac, self.m_per_px = centre_jacobian(self._wall, self.roi)
        self._dense_jac, maps = dense_conversion(self._wall, self._pixels, self.roi, self.params.dense.level, self._jac)
        self._dense.resample(maps)

    def _wall(self, px: np.ndarray) -> np.ndarray:
        return self.projection.to_wall(self.camera.normalise(px))

    def _pixels(self, wall: np.ndarray) -> np.ndarray:
        return self.camera.to_pixels(self.projection.to_image(wall))

    def _new_keyframe(self, img, t_s, owned: bool = False) -> bool:
        img = img if owned else img.copy()    # the frame buffer belongs to the camera or decoder
        pts, seen, pull = keyframe_features(img, t_s, self._kf or self._kf_last, self._motion_v, self.params,
                                            self._border)
        if len(pts) < self.params.min_tracks:
            self._kf = None
            self._prev_pts = None
            return False
        px = pts.astype(np.float64) + self._offset
        wall = self._wall(px)
        good = np.all(np.isfinite(wall), axis=1)
        pts, px, wall = pts[good], px[good], wall[good]
        predict = motion_model(px, wall, self._pixels, self.m_per_px)
        self._kf, self._kf_last = Keyframe(img, pts, wall, self.camera.row_time(px[:, 1]), t_s, self.distance,
                                           self.lateral, predict, seen, pull), None
        self.pose.keyframe(self._kf, px, t_s)
        self._prev_pts = self._kf.pts
        self._prev_origin = (self._kf, slice(None))
        self._jv = self._kf.rows_per_m
        self._last_step, self._last_lat, self._last_good_t = 0.0, 0.0, t_s
        self._good_roi, self._good_coarse = img, None
        self._good_at, self.reference_seq = (self.distance, self.lateral), self.reference_seq + 1
        return True

    def _start(self, img, t_s) -> Estimate:
        ok = self._new_keyframe(img, t_s)
        self._last_good_t = t_s
        if ok:
            self._speed.update(t_s, self.distance)
            self.lost_frames = 0
        else:
            self.lost_frames += 1
        n = 0 if self._kf is None else self._kf.n0
        est = self._estimate(t_s, ok, n, n if ok else 0, None, keyframe=ok)
        if ok:                  # after a blind stretch, this start does not know the motion before it
            est.continuous = not (self._blind_restart or self._unmeasured_since is not None or self._after_dense)
            self._blind_restart, self._unmeasured_since, self._after_dense = False, None, False
        return est

    def _view_of(self, n: int) -> tuple:
        if n not in self._views:
            self._views[n] = tuple(np.tile(a, (n, 1)) for a in self.view)
        return self._views[n]

    def _coarse_guess(self, img, t_s) -> list:
        """[(step, lateral)] from a phase correlation against the last tracked frame ([]: none).

        Only needed when the constant-velocity guess failed (start, a jerk, after a loss): it costs
        as much as the rest of the frame. The shift it finds wraps around the image: the wraps the
        speed measured last allows are tried (FrameGates.wraps).
        """
        if self._good_roi is None or self._good_roi.shape != img.shape:
            return []
        fp, flat = self.params.flow, self._kf is not None and self._kf.flat
        if self._good_coarse is None or self._good_coarse[0] != flat:
            self._good_coarse = (flat, flow.coarse_image(self._good_roi, fp, flat))
        (du, dv), response = flow.coarse_shift(self._good_coarse[1], flow.coarse_image(img, fp, flat),
                                               self._window, self._coarse_scale)
        if response < self.params.min_response:
            return []
        jyv, jyu, jsv, jsu = self._jac
        return [(self._last_step + jyv * d + jyu * du, self._last_lat + jsv * d + jsu * du)
                for d in self._gates.wraps(dv, img.shape[0], t_s - self._last_good_t, self._jv, t_s)]

    def _track(self, img, step_guess, lat_guess):
        """Track the keyframe's features that should be visible: (indices, positions, n visible)."""
        kf = self._kf
        return self.tracker(kf, img, step_guess, lat_guess, self._view_of(kf.n0), self.params.flow)

    def _track_guessed(self, img, t_s):
        """Constant velocity first; if most features are then lost, the global shift (its other wrap
        only where it tracks: else what the likelier one says is visible decides a renewal)."""
        p = self.params
        idx, pts1, n_visible = self._track(img, *self.guess(t_s))
        if len(idx) < max(p.min_tracks, p.retry_share * n_visible) or self.lost_frames:
            for k, coarse in enumerate(self._coarse_guess(img, t_s)):
                idx2, pts2, n2 = self._track(img, *coarse)
                if len(idx2) > len(idx) and (not k or len(idx2) >= p.min_tracks):
                    idx, pts1, n_visible = idx2, pts2, n2
        return idx, pts1, n_visible

    def _consensus(self, idx, pts1, t_s) -> Consensus | None:
        """The step the tracks agree on, or None (too few agree, or a corrupt frame)."""
        p, kf = self.params, self._kf
        n_tracked = len(idx)
        px = pts1 + self._offset
        moved = (kf.wall.take(idx, 0) - self._wall(px)).T * LATERAL_AXIAL     # rows: lateral, axial
        if self._rs:
            moved, idx, pts1 = rolling_shutter(moved, idx, pts1, t_s - kf.t_s, self.camera.row_time(px[:, 1]),
                                               kf.row_t, p.min_span_share)
        if len(idx) < p.min_tracks:
            return None
        (lat, step), both, (_, sigma) = robust_step(moved, p.inlier_floor_px * self.m_per_px, p.mad_k)
        c = Consensus(float(step), float(lat), int(np.count_nonzero(both)), float(sigma), 0.0,
                      pts1.compress(both, 0), idx.compress(both), (idx, pts1, moved, both))
        c.ratio = c.sigma / (abs(c.step) + self.m_per_px)
        enough = c.n_in >= p.min_tracks and c.n_in >= p.min_inlier_share * n_tracked
        return c if enough and self._spread.calm(c.step, c.sigma, c.ratio) else None

    def _plausible(self, c: Consensus, t_s: float) -> bool:
        """The speed since the last good frame (a fresh keyframe counts as one) against the one before
        (gates.py); on a faint frame, as under a pull, a stand must be seen coming (faint_texture_dn)."""
        dt, pulled = t_s - self._last_good_t, self._kf.flat or self._energy < self.params.faint_texture_dn
        return dt <= 0 or self._gates.plausible((c.step - self._last_step) / dt, t_s, pulled,
                                                 min(dt, t_s - (self._prev_t or 0.0)), self._dense.stands.take_set_off())

    def _measure(self, img, t_s, rescue: bool = True) -> Estimate:
        (idx, pts1, n_visible), p, kf = self._track_guessed(img, t_s), self.params, self._kf
        c = self._consensus(idx, pts1, t_s) if len(idx) >= p.min_tracks else None
        changed = c is None and self._gates.lit_as_before(img)   # the tracks gone: the picture changed
        clear = c is not None and (not self._resumed or reacquired(c, n_visible, p, self.m_per_px))
        morphed = c is not None and self._gates.morphed(kf, img, kf.distance + c.step, p.still_px * self.m_per_px)
        mute = self._copy or (c is not None and self._gates.tracks_say_nothing(
            kf, img, c, self._unmeasured_since, t_s - self._last_good_t))
        if c is not None and (morphed or mute or not (self._plausible(c, t_s) and clear)):
            c = None
        if c is None:      # a keyframe the encoder morphed away from is not worn out: no rescue from it
            if rescue and not morphed and self._good_roi is not None and kf.t_s < self._last_good_t:
                # the keyframe is worn out (features gone, light changed): start one at the last
                # tracked frame, whose distance is known, and measure this frame again from there
                if self._new_keyframe(self._good_roi, self._last_good_t, owned=True):
                    return self._measure(img, t_s, rescue=False)
                self._kf = kf
            return self._lost(img, t_s, len(idx), n_visible, changed)
        return self._accept(img, t_s, c, len(idx))

    def _accept(self, img, t_s, c: Consensus, n_tracked: int) -> Estimate:
        p, kf, raw = self.params, self._kf, (c.step, c.lat)   # the tracks' own step: what guesses the next
        fix = self.pose.measure(kf, c, t_s)        # corrects c and kf.distance for the pose (crawler/pose.py)
        self._speed.remeasured(fix.rescaled_m, fix.rescaled_over_m)   # a new tilt's scale
        dt_prev = t_s - self._last_good_t
        delta = raw[0] - self._last_step
        if dt_prev > 0:
            self._velocity = delta / dt_prev
            self._gates.measured(self._velocity, t_s, dt_prev)
        self._motion_v = delta * self._jv
        self._last_step, self._last_lat = raw
        self._good_roi, self._good_coarse = img.copy(), None   # the frame buffer goes back to the camera
        self._good_at, self.reference_seq = (kf.distance + c.step, kf.lateral + c.lat), self.reference_seq + 1
        self._spread.accepted(c.step, c.sigma, c.ratio)
        self._last_good_t = t_s
        self.distance = kf.distance + c.step
        self.lateral = kf.lateral + c.lat
        self._prev_pts = c.pts
        self._prev_origin = (kf, c.idx)
        self.lost_frames = 0
        self._speed.update(t_s, self.distance)
        # renew before the features run out: count those still inside after one more such step
        ahead = c.pts + kf.predict[0].take(c.idx, 0) * delta
        stay = int(np.count_nonzero(flow.within(ahead, *self._view_of(len(ahead)))))
        renew = (stay < max(p.min_tracks * p.renew_floor, p.renew_share * kf.n0)
                 or abs(c.step) / self.m_per_px > p.max_baseline_px)
        est = self._estimate(t_s, True, n_tracked, c.n_in, c.sigma, False, continuous=not self._blind_restart,
                             rescaled_m=fix.rescaled_m, rescaled_over_m=fix.rescaled_over_m, rescaled_since_s=fix.rescaled_since_s)
        self._blind_restart, self._unmeasured_since, self._after_dense, self._resumed = False, None, False, False
        if fix.remount is not None:           # the pose estimate moved the tilt: a keyframe at the new one;
            self.remount(fix.remount)         # the speed the gates hold was measured at the old one
            self._gates.v_ref = None
        if renew or fix.remount is not None:
            est.keyframe = self._new_keyframe(self._good_roi, t_s, owned=True)
        return est

    def _blind(self, t_s, changed: bool = False) -> Estimate:
        """A frame with nothing to measure (dark, featureless): lost, the keyframe kept for later."""
        self.lost_frames, self._prev_pts = self.lost_frames + 1, None
        self._unmeasured_since = t_s if self._unmeasured_since is None else self._unmeasured_since
        return self._estimate(t_s, False, 0, 0, None, keyframe=False, changed=changed)

    def _untextured(self, roi, t_s, energy: float) -> Estimate:
        """Too little texture for features: the dense shift, if the wall is lit and it finds one."""
        if self._gates.dark(roi) or energy < self.params.dense.min_energy_dn:
            self._dense.reset()               # an LED blackout, or a frame the encoder flattened
            self._dense.stands.unseen()
            return self._blind(t_s)
        found = self._dense.shift(roi, t_s)
        dt = t_s - self._prev_t if self._prev_t is not None else 0.0
        if found is None or dt <= 0:
            return self._blind(t_s, changed=self._gates.lit_as_before(roi))   # lit, the texture faded
        (du, dv), response, since_s = found
        jyv, jyu, jsv, jsu = self._dense_jac
        step, lat = jyv * dv + jyu * du, jsv * dv + jsu * du
        frames = (t_s - since_s) / dt if since_s is not None and since_s < t_s else 1.0   # a start: over its frames
        v = step / (frames * dt)
        if not self._gates.plausible(v, t_s, False, dt):
            return self._blind(t_s)
        continuous = self._unmeasured_since is None and not self._blind_restart
        self.distance, self.lateral = self.distance + step, self.lateral + lat
        # features start afresh when texture returns; the last keyframe still tests their pull (static_pull)
        self._kf_last, self._kf, self._prev_pts = self._kf or self._kf_last, None, None
        self._velocity, self._last_good_t, self._motion_v = v, t_s, dv / frames
        self._gates.measured(v, t_s)
        self._unmeasured_since, self._blind_restart, self._after_dense = None, False, True
        self.lost_frames = 0
        self._speed.update(t_s, self.distance)
        noise = math.hypot(self.params.dense.noise_px * self.m_per_px, self.params.dense.rel_error * step)
        est = self._estimate(t_s, True, 0, 0, noise, keyframe=True)
        est.quality, est.continuous = min(1.0, response) * 0.3, continuous
        if not continuous:                    # after a gap: the speed is known over the confirmed shifts
            est.since = (since_s, self.distance - step)
        return est

    def _lost(self, img, t_s, n_tracked, n_visible, changed: bool = False) -> Estimate:
        """No consensus: hold the distance, keep the keyframe a while, else start from this frame."""
        self.lost_frames, self._prev_pts = self.lost_frames + 1, None
        self._unmeasured_since = t_s if self._unmeasured_since is None else self._unmeasured_since
        renewed, p = False, self.params
        if self.lost_frames > p.max_lost_frames or t_s - self._last_good_t > p.max_lost_s or n_visible < p.min_tracks:
            renewed = self._new_keyframe(img, t_s)
            # the crawler goes on at about the speed it had: the next guess starts there
            self._velocity = self._gates.v_ref or 0.0
            self._speed.reset()
            self._blind_restart = True        # the motion from the last tracked frame to here is unknown
        return self._estimate(t_s, False, n_tracked, 0, None, keyframe=renewed, changed=changed)

    def _estimate(self, t_s, tracking, n_tracked, n_in, sigma, keyframe, **more) -> Estimate:
        share = n_in / n_tracked if n_tracked else 0.0
        full = self.params.full_quality_tracks * self.params.min_tracks
        quality = share * min(1.0, n_in / full) if tracking else 0.0
        r = self.projection.roll_radius_m
        return Estimate(
            frame=self.frame, t_s=t_s, distance_m=self.distance,
            speed_m_s=self._speed.value() if tracking else None,
            lateral_m=self.lateral, roll_deg=math.degrees(self.lateral / r) if r else None,
            tracking=tracking, quality=quality, tracks=n_tracked, inliers=n_in,
            spread_mm=None if sigma is None else sigma * 1000.0, keyframe=keyframe,
            scale_sigma_m=self.pose.scale_sigma_m, pitch_m=self.pose.pitch_shown_rad * self.m_per_px * self.camera.fy,
            stand=None if tracking else self._dense.stands.stand, **more)   # a stand the frames show (stands.py)
