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
    max_baseline_px: float = 120.0    # new keyframe when features moved this far (perspective change)
    max_lost_frames: int = 15         # keep hoping for the old keyframe this long, then start afresh
    min_response: float = 0.03        # weakest phase-correlation peak trusted as a first guess
    speed_window_s: float = 0.25      # least-squares speed over this much recent history
    spread_jump: float = 4.0          # tracks disagreeing this many times more than lately: corrupt frame
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

    def as_dict(self) -> dict:
        d = dict(self.__dict__)
        for k in ("distance_m", "lateral_m"):
            d[k] = round(d[k], 6)
        for k in ("speed_m_s", "roll_deg", "spread_mm"):
            d[k] = None if d[k] is None or not math.isfinite(d[k]) else round(d[k], 6)
        d["t_s"] = round(d["t_s"], 6)
        d["quality"] = round(d["quality"], 3)
        return d


class SpeedFilter:
    """Least-squares slope of distance over the last window of seconds.

    Works on timestamps, not frame counts, so dropped frames change nothing but the noise.
    """

    def __init__(self, window_s: float):
        self.window_s = window_s
        self._hist: deque[tuple[float, float]] = deque()

    def reset(self):
        self._hist.clear()

    def update(self, t: float, d: float) -> float | None:
        h = self._hist
        h.append((t, d))
        while h and h[0][0] < t - self.window_s:
            h.popleft()
        return self.value()

    def value(self) -> float | None:
        if len(self._hist) < 2:
            return None
        a = np.asarray(self._hist)
        tt = a[:, 0] - a[:, 0].mean()
        den = float(tt @ tt)
        if den <= 0:
            return None
        return float(tt @ (a[:, 1] - a[:, 1].mean()) / den)


def robust_step(values: np.ndarray, floor: float, k: float):
    """Median/MAD consensus: (mean of inliers, inlier mask, robust spread)."""
    med = np.median(values)
    dev = np.abs(values - med)
    sigma = 1.4826 * np.median(dev)
    inl = dev <= max(k * sigma, floor)
    if not inl.any():
        return float(med), inl, float(sigma)
    return float(values[inl].mean()), inl, float(sigma)


class _Keyframe:
    """Features of one keyframe: pixel positions in the ROI, wall positions, row times."""

    def __init__(self, img, pts, wall, row_t, t_s, distance, lateral):
        self.img = img
        self.pts = pts            # (N, 2) float32, ROI pixels
        self.wall = wall          # (N, 2) metres (s, y)
        self.row_t = row_t        # (N,) seconds after the frame's top row
        self.t_s = t_s
        self.distance = distance
        self.lateral = lateral
        self.n0 = len(pts)
        self.last = pts.astype(np.float32).copy()   # each feature's position in the latest frame


class Odometer:
    """Turns a stream of grey frames into distance, speed, lateral motion and a quality figure."""

    def __init__(self, camera: Camera, projection: Projection, roi, params: OdometryParams | None = None):
        self.camera = camera
        self.projection = projection
        self.roi = tuple(int(v) for v in roi)
        self.params = params or OdometryParams()
        x, y, w, h = self.roi
        self._offset = np.array([x, y], np.float64)
        self._roi_centre = np.array([[x + (w - 1) / 2.0, y + (h - 1) / 2.0]])
        self._border = self.params.flow.win_px // 2 + 1
        # metres per pixel along the axis at the ROI centre: the unit of the inlier floor
        c = self._roi_centre
        sy = self._wall(c + [[0, -0.5]]) - self._wall(c + [[0, 0.5]])
        self.m_per_px = float(abs(sy[0, 1]))
        lvl = self.params.flow.coarse_level
        self._coarse_scale = float(2 ** lvl)
        small = (math.ceil(h / 2 ** lvl), math.ceil(w / 2 ** lvl))
        self._window = cv2.createHanningWindow(small[::-1], cv2.CV_32F)
        self.reset()

    # -- public -------------------------------------------------------------------------------------

    def reset(self, distance: float = 0.0, lateral: float = 0.0):
        """Forget the keyframe and start counting from the given distance."""
        self.distance = distance
        self.lateral = lateral
        self.frame = -1
        self.lost_frames = 0
        self._kf: _Keyframe | None = None
        self._prev_coarse = None
        self._prev_t = None
        self._last_good_t = 0.0
        self._prev_pts = None      # last tracked positions of the keyframe's features (ROI px)
        self._prev_origin = None   # ...and where they were found
        self._last_step = 0.0      # distance gained since the keyframe at the previous frame
        self._last_lat = 0.0
        self._velocity = 0.0
        self._speed = SpeedFilter(self.params.speed_window_s)
        # recent track disagreement per unit of displacement: model errors grow with the step, a
        # corrupt frame jumps
        self._spreads: deque[float] = deque(maxlen=15)
        self._refusals = 0

    def update(self, frame: np.ndarray, t_s: float) -> Estimate:
        """Process one full grey frame (only its ROI is read) taken at t_s seconds."""
        self.frame += 1
        x, y, w, h = self.roi
        roi = frame[y:y + h, x:x + w]
        fp = self.params.flow
        coarse = flow.coarse_image(roi, fp)

        try:
            if self._kf is None:
                return self._start(roi, t_s)
            return self._measure(roi, coarse, t_s)
        finally:
            self._prev_coarse = coarse
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
        if self._prev_origin is None:
            return np.empty((0, 2))
        return self._prev_origin + self._offset

    # -- internals ----------------------------------------------------------------------------------

    def _wall(self, px: np.ndarray) -> np.ndarray:
        return self.projection.to_wall(self.camera.normalise(px))

    def _pixels(self, wall: np.ndarray) -> np.ndarray:
        return self.camera.to_pixels(self.projection.to_image(wall))

    def _new_keyframe(self, img, t_s) -> bool:
        img = img.copy()  # the frame buffer belongs to the camera or decoder
        pts = flow.detect(img, self.params.flow, self._border)
        if len(pts) < self.params.min_tracks:
            self._kf = None
            self._prev_pts = None
            return False
        px = pts.astype(np.float64) + self._offset
        wall = self._wall(px)
        good = np.all(np.isfinite(wall), axis=1)
        self._kf = _Keyframe(img, pts[good], wall[good], self.camera.row_time(px[good, 1]), t_s,
                             self.distance, self.lateral)
        self._prev_pts = self._kf.pts.copy()
        self._prev_origin = self._kf.pts.copy()
        self._last_step = 0.0
        self._last_lat = 0.0
        self._last_good_t = t_s
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
        return self._estimate(t_s, ok, n, n if ok else 0, None, keyframe=ok)

    def _guess_step(self, coarse, t_s):
        """Predicted (axial, lateral) motion since the keyframe for this frame."""
        step = self._last_step + self._velocity * (t_s - self._last_good_t)
        lat = self._last_lat
        if self._prev_coarse is not None and self._prev_coarse.shape == coarse.shape:
            shift, response = flow.coarse_shift(self._prev_coarse, coarse, self._window,
                                                 self._coarse_scale)
            if response >= self.params.min_response and self.lost_frames == 0:
                c = self._roi_centre
                before, after = self._wall(c - shift / 2), self._wall(c + shift / 2)
                d = before - after
                if np.all(np.isfinite(d)):
                    step = self._last_step + float(d[0, 1])
                    lat = self._last_lat - float(d[0, 0])
        return step, lat

    def _measure(self, img, coarse, t_s) -> Estimate:
        p = self.params
        kf = self._kf
        step_guess, lat_guess = self._guess_step(coarse, t_s)
        guess_wall = kf.wall + [lat_guess, -step_guess]
        guess = self._pixels(guess_wall) - self._offset
        x, y, w, h = self.roi
        b = self._border
        visible = ((guess[:, 0] >= b) & (guess[:, 0] < w - 1 - b) &
                   (guess[:, 1] >= b) & (guess[:, 1] < h - 1 - b) & np.all(np.isfinite(guess), axis=1))
        idx = np.flatnonzero(visible)
        n_visible = len(idx)
        pts1, ok, _ = flow.track(kf.img, img, kf.pts[idx], guess[idx], p.flow)
        inside = ((pts1[:, 0] >= 0) & (pts1[:, 0] <= w - 1) & (pts1[:, 1] >= 0) & (pts1[:, 1] <= h - 1))
        ok &= inside
        idx, pts1 = idx[ok], pts1[ok]
        n_tracked = len(idx)
        result = None
        if n_tracked >= p.min_tracks:
            px = pts1.astype(np.float64) + self._offset
            wall = self._wall(px)
            fin = np.all(np.isfinite(wall), axis=1)
            idx, pts1, px, wall = idx[fin], pts1[fin], px[fin], wall[fin]
            dt = t_s - kf.t_s
            # rolling shutter: a feature's displacement spans dt plus its change of row time
            span = dt + self.camera.row_time(px[:, 1]) - kf.row_t[idx]
            with np.errstate(divide="ignore", invalid="ignore"):
                scale = np.where(span > 0.2 * dt, dt / span, np.nan) if dt > 0 else np.ones(len(idx))
            axial = (kf.wall[idx, 1] - wall[:, 1]) * scale
            lateral = (wall[:, 0] - kf.wall[idx, 0]) * scale
            fin = np.isfinite(axial)
            axial, lateral, idx, pts1 = axial[fin], lateral[fin], idx[fin], pts1[fin]
            if len(axial) >= p.min_tracks:
                floor = p.inlier_floor_px * self.m_per_px
                step, inl, sigma = robust_step(axial, floor, p.mad_k)
                lat, inl_l, _ = robust_step(lateral, floor, p.mad_k)
                both = inl & inl_l
                n_in = int(both.sum())
                ratio = sigma / (abs(step) + self.m_per_px)
                usual = np.median(self._spreads) if self._spreads else np.inf
                calm = (ratio <= p.spread_jump * usual or sigma <= p.spread_floor_px * self.m_per_px
                        or self._refusals >= p.max_spread_refusals)
                self._refusals = 0 if calm else self._refusals + 1
                if n_in >= p.min_tracks and n_in >= p.min_inlier_share * n_tracked and calm:
                    step = float(axial[both].mean())
                    lat = float(lateral[both].mean())
                    result = (step, lat, n_in, sigma, pts1[both], idx[both])
        if result is None:
            return self._lost(img, t_s, n_tracked, n_visible)
        step, lat, n_in, sigma, pts_in, idx_in = result
        dt_prev = t_s - self._prev_t
        if dt_prev > 0:
            self._velocity = (step - self._last_step) / dt_prev
        self._last_step, self._last_lat = step, lat
        self._spreads.append(sigma / (abs(step) + self.m_per_px))
        self._last_good_t = t_s
        self.distance = kf.distance + step
        self.lateral = kf.lateral + lat
        self._prev_pts = pts_in
        self._prev_origin = kf.pts[idx_in]
        self.lost_frames = 0
        self._speed.update(t_s, self.distance)
        # renew before the features run out: count those still inside after one more such step
        motion = np.median(pts_in - kf.last[idx_in], axis=0)
        kf.last[idx_in] = pts_in
        ahead = pts_in + motion
        stay = int(np.count_nonzero((ahead[:, 0] >= b) & (ahead[:, 0] < w - 1 - b) &
                                    (ahead[:, 1] >= b) & (ahead[:, 1] < h - 1 - b)))
        moved = float(np.median(np.linalg.norm(pts_in - kf.pts[idx_in], axis=1)))
        renew = stay < max(p.min_tracks * 2, p.renew_share * kf.n0) or moved > p.max_baseline_px
        est = self._estimate(t_s, True, n_tracked, n_in, sigma, keyframe=False)
        if renew:
            est.keyframe = self._new_keyframe(img, t_s)
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
