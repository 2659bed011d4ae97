"""Intrinsics from board views: which views to use, cv2.calibrateCamera, and how good the result is.

Pure: no I/O. A recording holds hundreds of near-identical views; calibrating on all of them weighs
wherever the operator lingered. So each view is described by where the board is in the frame, how
much of it the board fills and how far it is turned from the camera (the four numbers ROS's
camera_calibration tracks), and the views are chosen greedily, each the one least like those already
chosen: the board all over the image (the distortion lives at the edges) and turned both ways (which
separates the focal length from the distance). One pass then drops views that fit far worse than the
rest (a blurred frame, a corner found on the wrong square) and calibrates again.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import cv2
import numpy as np

MAX_VIEWS = 40          # calibrateCamera's cost grows with views; past ~40 diverse ones nothing improves
MIN_VIEWS = 8           # below this the focal length and the distortion are not separated
OUTLIER_FACTOR = 3.0    # a view fitting this many times worse than the median is dropped...
OUTLIER_FLOOR_PX = 0.3  # ...if its error is above this too
COVERAGE_GRID = (8, 6)  # cells across, down for the coverage figure


@dataclass(frozen=True)
class View:
    """One frame's board: object points (N, 3) on the board plane and image points (N, 2), float32."""

    frame: int
    obj: np.ndarray
    img: np.ndarray


@dataclass
class Intrinsics:
    """calibrateCamera's answer over the chosen views."""

    matrix: np.ndarray
    dist: np.ndarray
    rms_px: float
    frames: list[int]
    view_errors_px: list[float]
    std: dict[str, float]               # one-sigma of fx, fy, cx, cy (px) from the fit
    dropped: list[int] = field(default_factory=list)    # frames left out as outliers

    @property
    def fx(self) -> float:
        return float(self.matrix[0, 0])

    @property
    def fy(self) -> float:
        return float(self.matrix[1, 1])

    @property
    def cx(self) -> float:
        return float(self.matrix[0, 2])

    @property
    def cy(self) -> float:
        return float(self.matrix[1, 2])


def view_features(view: View, size: tuple[int, int]) -> np.ndarray:
    """(x, y, size, turn) of a view, each about 0..1: the board's centre in the frame, the square root
    of the share of the frame it covers, and its turn away from the camera (from the affine fit of board
    to image: the ratio of its singular values is cos(turn))."""
    w, h = size
    img = view.img.astype(np.float64)
    cx, cy = img.mean(axis=0) / (w, h)
    area = cv2.contourArea(cv2.convexHull(view.img.reshape(-1, 1, 2)))
    design = np.column_stack([view.obj[:, :2].astype(np.float64), np.ones(len(img))])
    affine = np.linalg.lstsq(design, img, rcond=None)[0][:2]
    s = np.linalg.svd(affine, compute_uv=False)
    turn = math.acos(min(1.0, s[1] / s[0])) / (math.pi / 2) if s[0] > 0 else 0.0
    return np.array([cx, cy, math.sqrt(area / (w * h)), turn])


def select_views(views: list[View], size: tuple[int, int], max_views: int = MAX_VIEWS) -> list[int]:
    """Indices of up to max_views views, farthest-point first in (x, y, size, turn); the first is the
    largest board (a near, central view anchors the fit)."""
    if len(views) <= max_views:
        return list(range(len(views)))
    f = np.array([view_features(v, size) for v in views])
    chosen = [int(np.argmax(f[:, 2]))]
    gap = np.linalg.norm(f - f[chosen[0]], axis=1)
    while len(chosen) < max_views:
        k = int(np.argmax(gap))
        chosen.append(k)
        gap = np.minimum(gap, np.linalg.norm(f - f[k], axis=1))
    return sorted(chosen)


def coverage(views: list[View], size: tuple[int, int], grid: tuple[int, int] = COVERAGE_GRID) -> float:
    """Share of the frame's grid cells in which some view has a corner: the edges must be in it."""
    w, h = size
    gx, gy = grid
    pts = np.concatenate([v.img for v in views])
    cells = (np.clip(pts[:, 0] * gx / w, 0, gx - 1).astype(int) * gy
             + np.clip(pts[:, 1] * gy / h, 0, gy - 1).astype(int))
    return len(np.unique(cells)) / (gx * gy)


def _fit(views: list[View], size: tuple[int, int], flags: int) -> Intrinsics:
    obj = [v.obj.reshape(-1, 1, 3) for v in views]
    img = [v.img.reshape(-1, 1, 2) for v in views]
    rms, k, dist, _, _, std, _, per_view = cv2.calibrateCameraExtended(obj, img, tuple(size), None, None,
                                                                       flags=flags)
    std = np.asarray(std, np.float64).ravel()
    return Intrinsics(k, np.asarray(dist, np.float64).ravel(), float(rms), [v.frame for v in views],
                      [float(e) for e in np.asarray(per_view).ravel()],
                      {name: float(std[i]) for i, name in enumerate(("fx", "fy", "cx", "cy"))})


def calibrate(views: list[View], size: tuple[int, int], k3: bool = False) -> Intrinsics:
    """Intrinsics over `views`, refitted once without views that fit OUTLIER_FACTOR times worse than
    the median. k3 = False fixes the sixth-order radial term at 0: for the Pi's narrow lenses it only
    fits noise at the corners (free it for wide-angle lenses)."""
    flags = 0 if k3 else cv2.CALIB_FIX_K3
    first = _fit(views, size, flags)
    errors = np.array(first.view_errors_px)
    bad = errors > max(OUTLIER_FACTOR * float(np.median(errors)), OUTLIER_FLOOR_PX)
    if not bad.any() or len(views) - bad.sum() < MIN_VIEWS:
        return first
    result = _fit([v for v, b in zip(views, bad) if not b], size, flags)
    result.dropped = [v.frame for v, b in zip(views, bad) if b]
    return result


def implausible(result: Intrinsics, size: tuple[int, int]) -> str | None:
    """Why these intrinsics cannot be a real camera's, or None: a principal point off the frame, a
    focal length that is not finite and positive, pixels that are far from square."""
    w, h = size
    values = [result.fx, result.fy, result.cx, result.cy, *result.dist]
    if not np.isfinite(values).all() or result.fx <= 0 or result.fy <= 0:
        return f"the fit diverged (fx={result.fx:.6g}, fy={result.fy:.6g})"
    if not (0 <= result.cx < w and 0 <= result.cy < h):
        return f"the principal point ({result.cx:.1f}, {result.cy:.1f}) lies outside the {w}x{h} frame"
    if not 0.8 < result.fx / result.fy < 1.25:
        return f"fx/fy = {result.fx / result.fy:.3f}: pixels this far from square are not a Pi camera's"
    return None
