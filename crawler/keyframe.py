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

    def __init__(self, img, pts, wall, row_t, t_s, distance, lateral, predict, seen=None, pull=None):
        self.img = img            # the picture, as it came
        self.seen = img if seen is None else seen   # ...and as LK sees it: flow.flatten'd if `flat`
        self.flat = seen is not None
        self.pull = pull          # its pull (keyframe_features; None: not tested)
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


def find_features(img: np.ndarray, motion_rows: float, params, border_px: int, raw=None) -> np.ndarray:
    """A new keyframe's features (ROI px). Moving (the wall went `motion_rows` rows in the last
    frame), only on the side the wall comes in from: they stay in view longest, and half the image
    costs half the detection. `params`: OdometryParams; `raw`: the frame as it came, if img is
    flattened (a highlight is found there)."""
    if abs(motion_rows) <= params.entry_side_px:
        return flow.detect(img, params.flow, border_px, raw)
    band = int(params.entry_band * img.shape[0])
    top = 0 if motion_rows > 0 else img.shape[0] - band
    pts = flow.detect(img[top:top + band], params.flow, border_px, None if raw is None else raw[top:top + band])
    pts[:, 1] += top
    return pts


PULL_RETEST_S = 0.1     # a keyframe this soon after one whose pull is far below the threshold is not tested


def keyframe_features(img: np.ndarray, t_s: float, before, motion_rows: float, params, border_px: int):
    """A new keyframe's features, what LK is to see of it and its pull: (pts, seen, pull), seen None
    for the frame as it came. Where shading that stays put in the image would pull the features'
    LK toward no motion (flow.static_pull against `before`, the last Keyframe's picture, kept as a
    running mean with its pull), the keyframe is tracked flattened (flow.flatten), with features
    found where texture is left once the shading is gone. Within PULL_RETEST_S of a keyframe whose
    pull is far below the threshold no keyframe is tested (the test costs 0.8 M ARM instructions:
    at 0.6 m/s, a keyframe every third frame, 6 % of a frame's cost)."""
    pts = find_features(img, motion_rows, params, border_px)
    fp, pull = params.flow, None
    if before is not None and len(pts) and (before.pull is None or before.pull > fp.flat_pull / 2
                                            or t_s - before.t_s >= PULL_RETEST_S):
        # one reading scatters by about the threshold itself (0.003-0.12 on keyframes a few mm apart
        # under one highlight, and below zero): the pull is a running mean, half this reading and
        # half the last keyframe's pull (never below none), and it or the reading flattens
        read = flow.static_pull(img, before.img, pts, fp)
        pull = max(0.0, read if before.pull is None else 0.5 * (read + before.pull))
        if max(read, pull) > fp.flat_pull:
            seen = flow.flatten(img, fp)
            return find_features(seen, motion_rows, params, border_px, raw=img), seen, pull
    return pts, None, pull


def track_visible(kf, img, step: float, lat: float, view: tuple, params) -> tuple:
    """The features of keyframe `kf` (its img, pts, model) that should be inside the view boxes
    after this axial and lateral step, tracked into img from where the model puts them:
    (indices, positions in img, how many should be visible). The Odometer's tracker port; a worker
    process (crawler/workers.py) runs the same function on the keyframe it was sent. A flat
    keyframe's frames are tracked flattened, as it was (flow.flatten)."""
    guess = kf.pts + kf.model.dot(np.float32([step, step * step, lat])).reshape(-1, 2)
    idx = flow.within(guess, *view).nonzero()[0]
    if kf.flat and len(idx):
        img = flow.flatten(img, params)
    pts1, ok, _ = flow.track(kf.seen, img, kf.pts.take(idx, 0), guess.take(idx, 0), params)
    return idx.compress(ok), pts1.compress(ok, 0), len(idx)     # ok: inside the image too
