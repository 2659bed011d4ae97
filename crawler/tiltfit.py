"""How well one step's features agree at a camera tilt, in wall metres (crawler/autotilt.py reads
the tilt from it, crawler/camturn.py a turn of the camera). Pure: no I/O."""

from __future__ import annotations

import math

import numpy as np

from .consensus import robust_step
from .odometry_params import OdometryParams


MAD_K = OdometryParams.mad_k              # the odometer's inlier gate, in robust sigmas


def far_apart(a, b, deg: float) -> bool:
    """Two projections' tilts more than deg apart."""
    return abs(a.mount.tilt_rad - b.mount.tilt_rad) > math.radians(deg)


def not_stray(projection, xy_k, xy_c, k: float = 6.0) -> np.ndarray:
    """Tracks that are not strays: within k robust sigmas of the median step (a wrong tilt only
    spreads the steps over the rows; a track that found the wrong texture lands anywhere)."""
    d = projection.to_wall(xy_k) - projection.to_wall(xy_c)
    dev = np.abs(d - np.median(d, axis=0))
    mad = np.median(dev, axis=0) * 1.4826 + 1e-9
    return np.all(dev <= k * mad, axis=1)


def robust_mean(values: np.ndarray, floor: float) -> float:
    """The odometer's consensus of one row of steps (crawler/consensus.py): the inliers' mean. A
    step measured again at a new tilt keeps the tracks chosen at the old one; one that agreed only
    there (a tilt far off spreads the rows) would pull a plain mean."""
    return float(robust_step(values[None, :], floor, MAD_K)[0][0])


def disagreement(projection, xy_k, xy_c, shutter=None, sway=None, robust: bool = False, *, at_keyframe=None) -> float:
    """How much the features disagree on one step at this projection, per square metre of step
    (each feature's step over one frame interval: `shutter`, its rolling-shutter factor).
    `sway`: the sway's field at the features ((N, 2): d(s, y)/d sway, less its mean), whose
    pattern is fitted and taken out. `at_keyframe`: the keyframe's projection, where the camera
    turned since (a sweep). Robust (for the search, whose tracks were chosen at a tilt
    maybe far off): the log of the median spread, so that a frame that agrees sharply somewhere
    outweighs one with a stray track."""
    d = (at_keyframe or projection).to_wall(xy_k) - projection.to_wall(xy_c)
    if shutter is not None:
        d = d * shutter[:, None]
    if sway is not None:
        scale = float(np.mean(d[:, 1])) ** 2
        bb, bz = float(np.sum(sway * sway)), float(np.sum(sway * d))
        left = float(np.var(d[:, 1]) + np.var(d[:, 0])) - (bz * bz / bb if bb > 0 else 0.0) / len(d)
        return left / scale if scale > 0 else math.inf
    if not robust:
        scale = float(np.mean(d[:, 1])) ** 2
        return float(np.var(d[:, 1]) + np.var(d[:, 0])) / scale if scale > 0 else math.inf
    dev = np.abs(d - np.median(d, axis=0))
    spread = float(np.sum(np.median(dev, axis=0) ** 2))
    scale = float(np.median(d[:, 1])) ** 2
    return math.log(spread / scale + 1e-12) if scale > 0 and math.isfinite(spread) else math.inf
