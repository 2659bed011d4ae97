"""Where the dense shift's pixels lie on the wall: the grid even in wall metres it correlates on, and
the Jacobians that turn its shift into wall metres. Pure geometry: no I/O."""

from __future__ import annotations

import numpy as np


def centre_jacobian(wall, roi) -> tuple:
    """((axial m per row, axial m per column, lateral m per row, lateral m per column), wall metres
    per image pixel) at the ROI centre: the unit of the odometer's gates, and the Jacobian that
    turns the global phase-correlation shift into a first guess of the step."""
    x, y, w, h = roi
    c = np.array([[x + (w - 1) / 2.0, y + (h - 1) / 2.0]])
    dv = wall(c + [[0, 0.5]]) - wall(c + [[0, -0.5]])
    du = wall(c + [[0.5, 0]]) - wall(c + [[-0.5, 0]])
    return (-float(dv[0, 1]), -float(du[0, 1]), float(dv[0, 0]), float(du[0, 0])), abs(float(dv[0, 1]))


def wall_grid(wall, pixels, roi, level: int, jac) -> tuple | None:
    """(map_x, map_y, k): where each pixel of a grid even in wall metres lies in the ROI shrunk to
    `level`, for cv2.remap, and the grid's spacing as a share k of the ROI centre's pixel (the
    axial and lateral metres per pixel of `jac`, centre_jacobian's). On that grid the wall's motion
    is one shift everywhere, where in the image it is not (at a tilt the near rows move farther
    than the far ones, and one phase correlation of the image reads 1-3 % off their mean). The grid
    has the shrunk ROI's size and is centred on the ROI's centre; k < 1 where a grid at the
    centre's pixel would reach past the ROI's edge. None if the ROI is not on the wall."""
    x, y, w, h = roi
    f = 2 ** level
    wq, hq = -(-w // f), -(-h // f)
    c = np.array([[x + (w - 1) / 2.0, y + (h - 1) / 2.0]])
    centre = wall(c)[0]
    jyv, jsu = jac[0], jac[3]
    if not (np.all(np.isfinite(centre)) and jyv > 0 and jsu != 0):
        return None
    jj, ii = np.meshgrid(np.arange(wq) - (wq - 1) / 2.0, np.arange(hq) - (hq - 1) / 2.0)
    for k in (1.0, 0.9, 0.8, 0.7, 0.6, 0.5):
        pts = np.column_stack([centre[0] + jsu * f * k * jj.ravel(), centre[1] - jyv * f * k * ii.ravel()])
        px = pixels(pts)
        qx = (px[:, 0] - x - (f - 1) / 2.0) / f
        qy = (px[:, 1] - y - (f - 1) / 2.0) / f
        ok = np.isfinite(qx) & np.isfinite(qy)
        if ok.all() and qx.min() >= -0.5 and qy.min() >= -0.5 and qx.max() <= wq - 0.5 and qy.max() <= hq - 0.5:
            return qx.reshape(hq, wq).astype(np.float32), qy.reshape(hq, wq).astype(np.float32), k
    return None


def dense_conversion(wall, pixels, roi, level: int, jac) -> tuple:
    """(Jacobian, maps): how the dense shift becomes wall metres ((axial m per row, per column,
    lateral m per row, per column), as window_jacobian's), and the wall grid's maps to resample the
    frames with (or None: then the shift is of the image itself, and its Jacobian the window's)."""
    grid = wall_grid(wall, pixels, roi, level, jac)
    if grid is None:
        return window_jacobian(wall, roi), None
    map_x, map_y, k = grid
    return (k * jac[0], 0.0, 0.0, k * jac[3]), (map_x, map_y)


def window_jacobian(wall, roi) -> tuple:
    """(axial m per row, axial m per column, lateral m per row, lateral m per column) for a global
    shift of the ROI; `wall` maps frame pixels to wall metres (the odometer's projection).

    A phase correlation of two windowed frames reports the window-weighted (squared: both frames
    carry it) mean of the local pixel shifts, and the wall metres per pixel change over the ROI
    (curvature, tilt): so the pixels per metre are averaged with those weights, and inverted."""
    x, y, w, h = roi
    s = np.linspace(0.0, 1.0, 11)[1:-1]
    u, v = np.meshgrid(x + s * (w - 1), y + s * (h - 1))
    weight = (np.outer(np.sin(np.pi * s) ** 2, np.sin(np.pi * s) ** 2) ** 2).ravel()  # Hanning^2
    c = np.column_stack([u.ravel(), v.ravel()])
    dv = wall(c + [0, 0.5]) - wall(c + [0, -0.5])
    du = wall(c + [0.5, 0]) - wall(c + [-0.5, 0])
    ok = np.all(np.isfinite(dv) & np.isfinite(du), axis=1) & (np.abs(dv[:, 1]) > 0) & (np.abs(du[:, 0]) > 0)
    wt = weight[ok] / weight[ok].sum()
    dv, du = dv[ok], du[ok]
    jyv = 1.0 / float(wt @ (1.0 / -dv[:, 1]))      # axial metres per image row
    jsu = 1.0 / float(wt @ (1.0 / du[:, 0]))       # lateral metres per image column
    return jyv, -float(wt @ du[:, 1]), float(wt @ dv[:, 0]), jsu
