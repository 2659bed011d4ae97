"""The pose filter's measurement model: how one frame's feature displacements depend on the pose.
Pure algebra: no I/O.

The state is this frame's pitch, height and sway and its keyframe's (crawler/pose.py). Each feature
gives an axial and a lateral row; each row of H and of z is a fixed combination of the feature's
fields where it is and where it was (crawler/posefield.py) and of its displacement, so the whole
model is one matrix product (MODEL), and the prior-free reading of this frame's pose one small
least-squares solve (least_squares).
"""

from __future__ import annotations

import math

import cv2
import numpy as np

PITCH, HEIGHT, SWAY, K_PITCH, K_HEIGHT, K_SWAY = range(6)   # the state: this frame's pose, the keyframe's
N_POSE = 3


def least_squares(hh, hz, k):
    """The states k read from the normal equations (hh, hz): (reading, the inverse's diagonal, the
    part of z'z explained), None if singular. Three in plain floats: on the Pi a numpy call costs more."""
    if len(k) == N_POSE:
        (a, b, c), (_, e, f), (_, _, i) = hh[:3, :3].tolist()
        g0, g1, g2 = hz[:3].tolist()
        ca, cb, cc = e * i - f * f, c * f - b * i, b * f - c * e       # cofactors (symmetric)
        ce, cf, ci = a * i - c * c, b * c - a * f, a * e - b * b
        det = a * ca + b * cb + c * cc
        if not det > 0 or not math.isfinite(det):
            return None
        read = [(ca * g0 + cb * g1 + cc * g2) / det, (cb * g0 + ce * g1 + cf * g2) / det,
                (cc * g0 + cf * g1 + ci * g2) / det]
        return read, [ca / det, ce / det, ci / det], read[0] * g0 + read[1] * g1 + read[2] * g2
    ok, inv = cv2.invert(hh[np.ix_(k, k)], flags=cv2.DECOMP_CHOLESKY)
    read = inv.dot(hz[k])
    explained = float(read.dot(hz[k]))
    if not ok or not math.isfinite(explained):
        return None
    return read.tolist(), inv.diagonal().tolist(), explained


def prior_free(hh, hz, zz, rows, k):
    """This frame's pose against its keyframe's, read from its tracks alone (no prior): (reading,
    covariance, both over all N_POSE states, zero where not in k), and the features' scatter about
    it; None where it cannot be had."""
    dof = rows - 2 - len(k)                        # less the axial and lateral means
    solved = least_squares(hh, hz, k) if k and dof > 0 else None
    if solved is None:
        return None
    read, diag, explained = solved
    sigma = math.sqrt(max(zz - explained, 0.0) / dof)
    var = max(sigma, 1e-9) ** 2
    d, cov = [0.0] * N_POSE, [0.0] * N_POSE
    for j, i in enumerate(k):
        d[i], cov[i] = read[j], diag[j] * var
    return d, cov, sigma


def height_change(hh, hz, zz, rows, k):
    """A frame's height change against its keyframe, prior-free, with the states k read too (m,
    variance), or None. With the keyframe's pitch and sway among them: a tilt that is off shows as
    the same pitch of both frames, which a reading without the keyframe's takes partly as a height
    change, each keyframe alike (2 deg: 0.7 mm per keyframe; crawler/ride.py sums them)."""
    dof = rows - 2 - len(k)
    solved = least_squares(hh, hz, k) if dof > 0 and HEIGHT in k else None
    if solved is None:
        return None
    read, diag, explained = solved
    j = k.index(HEIGHT)
    return read[j], diag[j] * max(zz - explained, 0.0) / dof


def _model_maps() -> np.ndarray:
    """(3, 14, 14): how each row of H and z (axial: columns 0-6, lateral: 7-13; H's six, then z)
    combines a feature's (jc 0-5, jk 6-11, moved lateral 12, axial 13), as base + tau * [1] +
    keyframe height * [2]. posefield.COLUMNS: 0 ds/dtilt, 1 dy/dtilt, 2 ds/dheight, 3 dy/dheight,
    4 ds/dsway, 5 dy/dsway."""
    n, f = 2 * N_POSE + 1, 2 * N_POSE          # a row group's width; the keyframe's fields start at f
    m = np.zeros((3, 2 * f + 2, 2 * n))
    for off, (tilt, height, sway, moved, sign) in ((0, (1, 3, 5, 13, 1.0)), (n, (0, 2, 4, 12, -1.0))):
        m[0, tilt, off + PITCH] = 1.0              # this frame's pitch and sway: their fields where it is
        m[0, height, off + HEIGHT] = 1.0
        m[0, sway, off + SWAY] = 1.0
        m[0, f + tilt, off + K_PITCH] = -1.0       # the keyframe's: where it was
        m[0, height, off + K_HEIGHT] = -1.0        # a height counts only as a change
        m[0, f + sway, off + K_SWAY] = -1.0
        m[0, moved, off + f] = sign                # z: the displacement less tilt and keyframe height
        m[1, tilt, off + f], m[1, f + tilt, off + f] = -1.0, 1.0
        m[2, height, off + f], m[2, f + height, off + f] = -1.0, 1.0
    return m


MODEL = _model_maps()
MODEL_FLAT = MODEL.reshape(3, -1)    # one dot with (1, tau, keyframe height) gives the product's matrix
