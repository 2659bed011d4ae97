"""A keyframe: the features every later frame is measured against, with their wall positions and a
per-feature model of how they move in the image. Pure: no I/O.

Each feature's image motion per metre of step comes from the exact projection, to second order
along the axis and first order across it, once per keyframe: the exact inverse projection is too
dear for every frame, and a guess need not be exact (LK finishes the job).
"""

from __future__ import annotations

import numpy as np

from . import flow

PROBE_STEP_PX = 40.0     # the model's finite-difference step, in pixels at the ROI centre: large
                         # enough to see the curvature of tilted rows, small against the ROI


class Keyframe:
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
        self.pose = None          # crawler/pose.py's terms for these features

    @property
    def rows_per_m(self) -> float:
        """Mean image rows the features move per metre of step (the sign says the entry side)."""
        return float(self.predict[0][:, 1].sum()) / self.n0


def motion_model(px: np.ndarray, wall: np.ndarray, to_pixels, m_per_px: float):
    """(per metre of step, per square metre, per metre lateral) pixel motion of each feature."""
    d = PROBE_STEP_PX * m_per_px
    n = len(wall)
    probes = to_pixels(np.concatenate([wall + [0.0, -d], wall + [0.0, d], wall + [d, 0.0]]))
    ahead, behind, aside = probes[:n], probes[n:2 * n], probes[2 * n:]
    predict = ((ahead - behind) / (2 * d), (ahead + behind - 2 * px) / (d * d), (aside - px) / d)
    return [a.astype(np.float32) for a in predict]


def find_features(img: np.ndarray, motion_rows: float, params, border_px: int) -> np.ndarray:
    """A new keyframe's features (ROI px). Moving (the wall went `motion_rows` rows in the last
    frame), only on the side the wall comes in from: they stay in view longest, and half the image
    costs half the detection. `params`: OdometryParams."""
    if abs(motion_rows) <= params.entry_side_px:
        return flow.detect(img, params.flow, border_px)
    band = int(params.entry_band * img.shape[0])
    top = 0 if motion_rows > 0 else img.shape[0] - band
    pts = flow.detect(img[top:top + band], params.flow, border_px)
    pts[:, 1] += top
    return pts


def track_visible(kf, img, step: float, lat: float, view: tuple, params) -> tuple:
    """The features of keyframe `kf` (its img, pts, model) that should be inside the view boxes
    after this axial and lateral step, tracked into img from where the model puts them:
    (indices, positions in img, how many should be visible). The Odometer's tracker port; a worker
    process (crawler/workers.py) runs the same function on the keyframe it was sent."""
    guess = kf.pts + kf.model.dot(np.float32([step, step * step, lat])).reshape(-1, 2)
    idx = flow.within(guess, *view).nonzero()[0]
    pts1, ok, _ = flow.track(kf.img, img, kf.pts.take(idx, 0), guess.take(idx, 0), params)
    return idx.compress(ok), pts1.compress(ok, 0), len(idx)     # ok: inside the image too
