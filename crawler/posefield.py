"""How the wall coordinates of an image point move when the camera tilts, rises or sways. Pure: no I/O.

The pose estimator (crawler/pose.py) needs, for every tracked feature and every frame, the derivative
of its wall position (s, y) with respect to the camera's tilt, its height below the crown and its
sideways offset (in a cylinder a sway is no plain shift: rays across the image meet the curved
wall at other depths, an axial pattern that would read as pitch). The
exact projection differentiated per frame is too dear on the Pi, and these fields are smooth over an
ROI: a cubic polynomial of the normalised image point, fitted once per mount to central differences
of the exact projection, is within 1 % of them up to 40 degrees of tilt (docs/odometry.md, "Pose").
Per frame the pose filter reads them from a table of the exact fields on a pixel grid instead
(`at_roi`, bilinear, one cv2.remap): no normalisation and no polynomial, a fifth of the cost on the Pi.
"""

from __future__ import annotations

from dataclasses import replace

import cv2
import numpy as np

from .geometry import Camera, Projection

TILT_PROBE_RAD = 1e-4     # central differences: far above rounding, far below the fields' curvature
HEIGHT_PROBE_M = 1e-4
SWAY_PROBE_M = 1e-4
GRID = 12                 # fit points per side of the ROI
TABLE_STEP_PX = 8         # the per-frame table's grid: bilinear, within 0.1 % of the fields (tests/test_pose.py)
_TABLE_SCALE = np.float32(1.0 / TABLE_STEP_PX)
COLUMNS = ("ds_dtilt", "dy_dtilt", "ds_dheight", "dy_dheight", "ds_dsway", "dy_dsway")   # in this order


def _monomials(xy: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """1, x, y, x^2, xy, y^2, x^3, x^2 y, x y^2, y^3 of each point: (N, 10)."""
    x, y = xy[:, 0], xy[:, 1]
    m = np.empty((len(xy), 10)) if out is None else out
    m[:, 0] = 1.0
    m[:, 1] = x
    m[:, 2] = y
    np.multiply(x, x, out=m[:, 3])
    np.multiply(x, y, out=m[:, 4])
    np.multiply(y, y, out=m[:, 5])
    np.multiply(m[:, 3], x, out=m[:, 6])
    np.multiply(m[:, 3], y, out=m[:, 7])
    np.multiply(m[:, 5], x, out=m[:, 8])
    np.multiply(m[:, 5], y, out=m[:, 9])
    return m


def exact_derivatives(projection: Projection, xy: np.ndarray) -> np.ndarray:
    """(N, 6) d(s, y)/d tilt, height and sway of canonical normalised points, by central differences."""
    m, kind = projection.mount, type(projection)

    def wall(**change):
        return kind(replace(m, **change)).to_wall(xy)

    dt = (wall(tilt_rad=m.tilt_rad + TILT_PROBE_RAD) - wall(tilt_rad=m.tilt_rad - TILT_PROBE_RAD)) / (2 * TILT_PROBE_RAD)
    dh = (wall(height_m=m.height_m + HEIGHT_PROBE_M) - wall(height_m=m.height_m - HEIGHT_PROBE_M)) / (2 * HEIGHT_PROBE_M)
    dx = (wall(sway_m=m.sway_m + SWAY_PROBE_M) - wall(sway_m=m.sway_m - SWAY_PROBE_M)) / (2 * SWAY_PROBE_M)
    return np.column_stack([dt, dh, dx])


class JacobianField:
    """d(wall)/d(tilt, height, sway) over one ROI at one mount: `at(xy)` -> (N, 6), COLUMNS."""

    def __init__(self, camera: Camera, projection: Projection, roi):
        x, y, w, h = roi
        g = np.linspace(0.0, 1.0, GRID)
        u, v = np.meshgrid(x + g * (w - 1), y + g * (h - 1))
        xy = camera.normalise(np.column_stack([u.ravel(), v.ravel()]))
        d = exact_derivatives(projection, xy)
        ok = np.all(np.isfinite(d), axis=1)
        self.projection = projection
        self.coef = np.linalg.lstsq(_monomials(xy[ok]), d[ok], rcond=None)[0]    # (10, 6)
        u, v = np.meshgrid(x + TABLE_STEP_PX * np.arange(w // TABLE_STEP_PX + 2),
                           y + TABLE_STEP_PX * np.arange(h // TABLE_STEP_PX + 2))
        xy = camera.normalise(np.column_stack([u.ravel(), v.ravel()]))
        d = exact_derivatives(projection, xy)
        bad = ~np.all(np.isfinite(d), axis=1)      # a ray past the wall: the fit's value there
        d[bad] = self.at(xy[bad])
        self._table = d.reshape(u.shape + (6,)).astype(np.float32)

    def at(self, xy: np.ndarray) -> np.ndarray:
        """The fields at canonical normalised points: the polynomial."""
        return _monomials(xy).dot(self.coef)

    def at_roi(self, pts: np.ndarray) -> np.ndarray:
        """The fields at ROI pixels (N, 2): the table, interpolated bilinearly. (N, 6) float32."""
        grid = np.multiply(pts, _TABLE_SCALE, dtype=np.float32).reshape(-1, 1, 2)
        return cv2.remap(self._table, grid, None, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE).reshape(-1, 6)
