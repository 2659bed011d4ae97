"""From grey frames and their times to distance along the pipe. Pure: no I/O, no logging.

Each feature is measured against the keyframe it was found in, not the previous frame: LK on
compressed video is biased toward zero motion on every image pair, and one long baseline carries
that bias once instead of once per frame. The previous frame only supplies the starting guess (a
phase-correlation shift turned into a wall displacement, so the guess follows the geometry of every
row). Per-feature displacements along the axis are corrected for rolling shutter and reduced to one
step by a median/MAD consensus; a frame without consensus is reported as lost and never integrated.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field

import cv2
import numpy as np

from . import flow
from .flow import FlowParams
from .geometry import Camera, Projection


@dataclass(frozen=True)
class OdometryParams:
    flow: FlowParams = field(default_factory=FlowParams)
    min_tracks: int = 8               # fewer agreeing tracks than this: tracking lost
    min_inlier_share: float = 0.5     # fewer agreeing than this share of tracked: lost
    mad_k: float = 3.5                # inlier gate in robust standard deviations
    inlier_floor_px: float = 0.35     # ...but never tighter than this (in pixels at the ROI centre)
    renew_share: float = 0.5          # new keyframe when fewer than this share of its features remain
    entry_band: float = 0.6           # moving: new features only in this share of the ROI (entry side)
    max_baseline_px: float = 120.0    # new keyframe when features moved this far (perspective change)
    max_lost_frames: int = 15         # keep hoping for the old keyframe this long, then start afresh
    min_response: float = 0.03        # weakest phase-correlation peak trusted as a first guess
    speed_window_s: float = 0.25      # least-squares speed over this much recent history
    spread_jump: float = 3.0          # tracks disagreeing this many times more than lately: corrupt frame
    spread_floor_px: float = 0.1      # ...unless they still agree within this
    max_spread_refusals: int = 2      # then believe the new level (the scene changed, not the frame)


@dataclass
class Estimate:
    """One frame's result. Distances are metres since the run start; quality in [0, 1]."""

    frame: int
    t_s: float
    distance_m: float
    speed_m_s: float | None
    lateral_m: float
    roll_deg: float | None
    tracking: bool
    quality: float
    tracks: int
    inliers: int
    spread_mm: float | None
    keyframe: bool
    continuous: bool = True           # False: a fresh start, the motion since the last tracked frame unknown
    # filled in after the odometer (crawler/distance.py): the published distance's uncertainty and origin
    sigma_m: float | None = None
    bridged: bool = False
    source: str = "vision"
    slip: bool = False
    wheel_distance_m: float | None = None
    wheel_scale: float | None = None
    gap_s: float = 0.0

    def as_dict(self) -> dict:
        d = dict(self.__dict__)
        for k in ("distance_m", "lateral_m"):
            d[k] = round(d[k], 6)
        for k in ("speed_m_s", "roll_deg", "spread_mm", "sigma_m", "wheel_distance_m", "wheel_scale"):
            d[k] = None if d[k] is None or not math.isfinite(d[k]) else round(d[k], 6)
        d["gap_s"] = round(d["gap_s"], 4)
        d["t_s"] = round(d["t_s"], 6)
        d["quality"] = round(d["quality"], 3)
        return d


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

    def value(self) -> float | None:
        n = self._n
        den = n * self._stt - self._st * self._st
        if n < 2 or den <= 1e-12 * max(1.0, n * self._stt):
            return None
        return (n * self._std - self._st * self._sd) / den


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
    sigma = part[:, mid] * 1.4826
    gate = np.maximum(sigma * k, floor)
    inl = np.logical_and.reduce(dev <= gate[:, None], axis=0)
    n_in = np.count_nonzero(inl)
    if not n_in:
        return med.ravel(), inl, sigma
    return values.dot(inl.astype(values.dtype)) / n_in, inl, sigma


_LATERAL_AXIAL = np.array([[-1.0], [1.0]])   # moved = keyframe wall - wall, signs per row


def _median(values) -> float:
    v = sorted(values)
    return v[len(v) // 2]


class _Keyframe:
    """Features of one keyframe: pixel positions in the ROI, wall positions, row times."""

    def __init__(self, img, pts, wall, row_t, t_s, distance, lateral, predict):
        self.img = img
        self.pts = pts            # (N, 2) float32, ROI pixels
        self.wall = wall          # (N, 2) metres (s, y)
        self.row_t = row_t        # (N,) seconds after the frame's top row
        self.predict = predict    # (jy, ky, js): pixel motion per metre of axial/lateral step
        # the same as one (N, 2, 3) matrix: motion = model . (step, step^2, lateral)
        self.model = np.stack([predict[0], 0.5 * predict[1], predict[2]], axis=-1).reshape(-1, 3)
        self.t_s = t_s
        self.distance = distance
        self.lateral = lateral
        self.n0 = len(pts)


class Odometer:
    """Turns a stream of grey frames into distance, speed, lateral motion and a quality figure."""

    def __init__(self, camera: Camera, projection: Projection, roi, params: OdometryParams | None = None):
        self.camera = camera
        self.projection = projection
        self.roi = tuple(int(v) for v in roi)
        self.params = params or OdometryParams()
        x, y, w, h = self.roi
        self._offset = np.array([x, y], np.float64)
        self._border = self.params.flow.win_px // 2 + 1
        b = self._border
        # where a guess must fall for the feature to be tracked, as a box's centre and half-size
        mid = np.float32([(w - 1) / 2.0, (h - 1) / 2.0])
        self._view, self._views = (mid, mid - b), {}   # ...and tiled for n points (cheaper numpy)
        # wall metres per image pixel at the ROI centre: the unit of the gates, and the Jacobian that
        # turns the global phase-correlation shift into a first guess of the step
        c = np.array([[x + (w - 1) / 2.0, y + (h - 1) / 2.0]])
        dv = self._wall(c + [[0, 0.5]]) - self._wall(c + [[0, -0.5]])
        du = self._wall(c + [[0.5, 0]]) - self._wall(c + [[-0.5, 0]])
        self._jac = (-float(dv[0, 1]), -float(du[0, 1]), float(dv[0, 0]), float(du[0, 0]))
        self.m_per_px = abs(float(dv[0, 1]))
        lvl = self.params.flow.coarse_level
        self._coarse_scale = float(2 ** lvl)
        small = (math.ceil(h / 2 ** lvl), math.ceil(w / 2 ** lvl))
        self._window = cv2.createHanningWindow(small[::-1], cv2.CV_32F)
        self._rs = camera.readout_s > 0
        self.reset()

    # -- public -------------------------------------------------------------------------------------

    def reset(self, distance: float = 0.0, lateral: float = 0.0):
        """Forget the keyframe and start counting from the given distance."""
        self.distance = distance
        self.lateral = lateral
        self.frame = -1
        self.lost_frames = 0
        self._kf: _Keyframe | None = None
        self._good_coarse = None   # quarter-size ROI of the last tracked frame, for the guess
        self._good_roi = None
        self._prev_t = None
        self._last_good_t = 0.0
        self._prev_pts = None      # last tracked positions of the keyframe's features (ROI px)
        self._prev_origin = None   # ...and where they were found: (keyframe, indices)
        self._last_step = 0.0      # distance gained since the keyframe at the previous frame
        self._last_lat = 0.0
        self._velocity = 0.0
        self._motion_v = 0.0       # image rows the wall moved in the last tracked frame
        self._jv = 0.0
        self._speed = SpeedFilter(self.params.speed_window_s)
        # recent track disagreement per unit of displacement: model errors grow with the step, a
        # corrupt frame jumps
        self._spreads: deque[float] = deque(maxlen=15)
        self._sigmas: deque[float] = deque(maxlen=15)
        self._refusals = 0
        self._blind_restart = False

    def set_distance(self, distance: float = 0.0):
        """Count from `distance` now, without losing track (an operator's reset mid-run)."""
        delta = distance - self.distance
        self.distance = distance
        if self._kf is not None:
            self._kf.distance += delta
        self._speed.reset()

    def update(self, frame: np.ndarray, t_s: float) -> Estimate:
        """Process one full grey frame (only its ROI is read) taken at t_s seconds."""
        self.frame += 1
        x, y, w, h = self.roi
        roi = frame[y:y + h, x:x + w]
        try:
            if self._kf is None:
                return self._start(roi, t_s)
            return self._measure(roi, t_s)
        finally:
            self._prev_t = t_s

    @property
    def tracked_points(self) -> np.ndarray:
        """Current positions (frame pixels) of the features in use, for drawing."""
        if self._prev_pts is None:
            return np.empty((0, 2))
        return self._prev_pts + self._offset

    @property
    def track_origins(self) -> np.ndarray:
        """Where the features in tracked_points were found in their keyframe (frame pixels)."""
        if self._prev_origin is None or self._prev_pts is None:
            return np.empty((0, 2))
        kf, idx = self._prev_origin
        return kf.pts[idx] + self._offset

    # -- internals ----------------------------------------------------------------------------------

    def _wall(self, px: np.ndarray) -> np.ndarray:
        return self.projection.to_wall(self.camera.normalise(px))

    def _pixels(self, wall: np.ndarray) -> np.ndarray:
        return self.camera.to_pixels(self.projection.to_image(wall))

    def _new_keyframe(self, img, t_s, owned: bool = False) -> bool:
        if not owned:
            img = img.copy()  # the frame buffer belongs to the camera or decoder
        h = img.shape[0]
        if abs(self._motion_v) > 2.0:
            # moving: look for features only on the side the wall comes in from; they stay in view
            # longest, and half the image costs half the detection
            band = int(self.params.entry_band * h)
            top = 0 if self._motion_v > 0 else h - band
            pts = flow.detect(img[top:top + band], self.params.flow, self._border)
            pts[:, 1] += top
        else:
            pts = flow.detect(img, self.params.flow, self._border)
        if len(pts) < self.params.min_tracks:
            self._kf = None
            self._prev_pts = None
            return False
        px = pts.astype(np.float64) + self._offset
        wall = self._wall(px)
        good = np.all(np.isfinite(wall), axis=1)
        pts, px, wall = pts[good], px[good], wall[good]
        # each feature's image motion per metre of step, to second order (once per keyframe: the
        # exact inverse projection is too dear for every frame, and the guess need not be exact)
        d = 40 * self.m_per_px
        n = len(wall)
        probes = self._pixels(np.concatenate([wall + [0.0, -d], wall + [0.0, d], wall + [d, 0.0]]))
        ahead, behind, aside = probes[:n], probes[n:2 * n], probes[2 * n:]
        predict = ((ahead - behind) / (2 * d), (ahead + behind - 2 * px) / (d * d), (aside - px) / d)
        self._kf = _Keyframe(img, pts, wall, self.camera.row_time(px[:, 1]), t_s,
                             self.distance, self.lateral, [a.astype(np.float32) for a in predict])
        self._prev_pts = self._kf.pts
        self._prev_origin = (self._kf, slice(None))
        self._jv = float(self._kf.predict[0][:, 1].sum()) / self._kf.n0   # image rows per metre of step
        self._last_step = 0.0
        self._last_lat = 0.0
        self._last_good_t = t_s
        self._good_roi, self._good_coarse = img, None
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
            est.continuous, self._blind_restart = not self._blind_restart, False
        return est

    def _view_of(self, n: int) -> tuple:
        if n not in self._views:
            self._views[n] = tuple(np.tile(a, (n, 1)) for a in self._view)
        return self._views[n]

    def _predict(self, step: float, lat: float) -> np.ndarray:
        """Where the keyframe's features should be after this axial and lateral step (ROI px)."""
        return self._kf.pts + self._kf.model.dot(np.float32([step, step * step, lat])).reshape(-1, 2)

    def _coarse_guess(self, img):
        """(step, lateral) from a phase correlation against the last tracked frame, or None.

        Only needed when the constant-velocity guess failed (start, a jerk, after a loss): it costs
        as much as the rest of the frame.
        """
        if self._good_roi is None or self._good_roi.shape != img.shape:
            return None
        fp = self.params.flow
        if self._good_coarse is None:
            self._good_coarse = flow.coarse_image(self._good_roi, fp)
        (du, dv), response = flow.coarse_shift(self._good_coarse, flow.coarse_image(img, fp),
                                               self._window, self._coarse_scale)
        if response < self.params.min_response:
            return None
        jyv, jyu, jsv, jsu = self._jac
        return self._last_step + jyv * dv + jyu * du, self._last_lat + jsv * dv + jsu * du

    def _track(self, img, step_guess, lat_guess):
        """Track the keyframe's features that should be visible: (indices, positions, n visible)."""
        kf = self._kf
        guess = self._predict(step_guess, lat_guess)
        idx = flow.within(guess, *self._view_of(len(guess))).nonzero()[0]
        pts1, ok, _ = flow.track(kf.img, img, kf.pts.take(idx, 0), guess.take(idx, 0), self.params.flow)
        return idx.compress(ok), pts1.compress(ok, 0), len(idx)     # ok: inside the image too

    def _measure(self, img, t_s, rescue: bool = True) -> Estimate:
        p = self.params
        kf = self._kf
        # first guess: constant velocity; if most features are then lost, the global shift
        guess = (self._last_step + self._velocity * (t_s - self._last_good_t), self._last_lat)
        idx, pts1, n_visible = self._track(img, *guess)
        if len(idx) < max(p.min_tracks, 0.6 * n_visible) or self.lost_frames:
            coarse = self._coarse_guess(img)
            if coarse is not None:
                idx2, pts2, n2 = self._track(img, *coarse)
                if len(idx2) > len(idx):
                    idx, pts1, n_visible = idx2, pts2, n2
        n_tracked = len(idx)
        result = None
        if n_tracked >= p.min_tracks:
            px = pts1 + self._offset
            wall = self._wall(px)
            moved = (kf.wall.take(idx, 0) - wall).T * _LATERAL_AXIAL     # rows: lateral, axial
            if self._rs:
                # rolling shutter: a feature's displacement spans dt plus its change of row time
                dt = t_s - kf.t_s
                span = dt + self.camera.row_time(px[:, 1]) - kf.row_t[idx]
                keep = span > 0.2 * dt
                moved, idx, pts1 = moved[:, keep] * (dt / span[keep]), idx[keep], pts1[keep]
            if len(idx) >= p.min_tracks:
                floor = p.inlier_floor_px * self.m_per_px
                (lat, step), both, (_, sigma) = robust_step(moved, floor, p.mad_k)
                lat, step, sigma = float(lat), float(step), float(sigma)
                n_in = int(np.count_nonzero(both))
                ratio = sigma / (abs(step) + self.m_per_px)
                # a corrupt frame: the tracks disagree far more than lately, both in metres and per
                # metre of step (model errors grow with the step; noise does not)
                moving = abs(step) > 3 * self.m_per_px      # the ratio means nothing at a standstill
                jump = (moving and len(self._spreads) >= 5 and len(self._sigmas) >= 5
                        and ratio > p.spread_jump * _median(self._spreads)
                        and sigma > p.spread_jump * _median(self._sigmas))
                calm = (not jump or sigma <= p.spread_floor_px * self.m_per_px
                        or self._refusals >= p.max_spread_refusals)
                self._refusals = 0 if calm else self._refusals + 1
                if n_in >= p.min_tracks and n_in >= p.min_inlier_share * n_tracked and calm:
                    result = (step, lat, n_in, sigma, ratio, pts1.compress(both, 0), idx.compress(both))
        if result is None:
            if rescue and self._good_roi is not None and kf.t_s < self._last_good_t:
                # the keyframe is worn out (features gone, light changed): start one at the last
                # tracked frame, whose distance is known, and measure this frame again from there
                if self._new_keyframe(self._good_roi, self._last_good_t, owned=True):
                    return self._measure(img, t_s, rescue=False)
                self._kf = kf
            return self._lost(img, t_s, n_tracked, n_visible)
        step, lat, n_in, sigma, ratio, pts_in, idx_in = result
        dt_prev = t_s - self._prev_t
        if dt_prev > 0:
            self._velocity = (step - self._last_step) / dt_prev
        delta = step - self._last_step
        self._motion_v = delta * self._jv
        self._last_step, self._last_lat = step, lat
        self._good_roi, self._good_coarse = img.copy(), None   # the frame buffer goes back to the camera
        self._sigmas.append(sigma)
        if abs(step) > 3 * self.m_per_px:
            self._spreads.append(ratio)
        self._last_good_t = t_s
        self.distance = kf.distance + step
        self.lateral = kf.lateral + lat
        self._prev_pts = pts_in
        self._prev_origin = (kf, idx_in)
        self.lost_frames = 0
        self._speed.update(t_s, self.distance)
        # renew before the features run out: count those still inside after one more such step
        ahead = pts_in + kf.predict[0].take(idx_in, 0) * delta
        stay = int(np.count_nonzero(flow.within(ahead, *self._view_of(len(ahead)))))
        renew = (stay < max(p.min_tracks * 2, p.renew_share * kf.n0)
                 or abs(step) / self.m_per_px > p.max_baseline_px)
        est = self._estimate(t_s, True, n_tracked, n_in, sigma, keyframe=False)
        est.continuous, self._blind_restart = not self._blind_restart, False
        if renew:
            est.keyframe = self._new_keyframe(self._good_roi, t_s, owned=True)
        return est

    def _lost(self, img, t_s, n_tracked, n_visible) -> Estimate:
        """No consensus: hold the distance, keep the keyframe a while, else start from this frame."""
        self.lost_frames += 1
        self._prev_pts = None
        renewed = False
        if self.lost_frames > self.params.max_lost_frames or n_visible < self.params.min_tracks:
            renewed = self._new_keyframe(img, t_s)
            self._velocity = 0.0
            self._speed.reset()
            self._blind_restart = True        # the motion from the last tracked frame to here is unknown
        return self._estimate(t_s, False, n_tracked, 0, None, keyframe=renewed)

    def _estimate(self, t_s, tracking, n_tracked, n_in, sigma, keyframe) -> Estimate:
        share = n_in / n_tracked if n_tracked else 0.0
        quality = share * min(1.0, n_in / (3.0 * self.params.min_tracks)) if tracking else 0.0
        r = self.projection.roll_radius_m
        return Estimate(
            frame=self.frame, t_s=t_s, distance_m=self.distance,
            speed_m_s=self._speed.value() if tracking else None,
            lateral_m=self.lateral, roll_deg=math.degrees(self.lateral / r) if r else None,
            tracking=tracking, quality=quality, tracks=n_tracked, inliers=n_in,
            spread_mm=None if sigma is None else sigma * 1000.0, keyframe=keyframe)
