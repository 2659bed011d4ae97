"""A coarse, dense measurement for a wall with too little texture for features. Pure: no I/O.

A wet or smooth wall still has large-scale shading that moves with it; what does not move with it
is the LED's specular highlight, the lighting's fall-off, and whatever the video encoder copied
unchanged from the last frame. Those dominate a frame of such a wall, so a plain phase correlation
finds them and reads "no motion". Dividing each frame by a running mean of the recent frames (what
stays put in the image) leaves only what moves with the wall; a phase correlation of two such
frames at quarter resolution then finds the wall's shift. It is a lower-quality measurement than
tracked features (one shift for the whole region, converted at the region's centre), used only
where features cannot be had, and only once the running mean has seen enough frames.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from .flow import encoder_copy


@dataclass(frozen=True)
class DenseParams:
    level: int = 2                    # quarter resolution: the shading is coarse, and it is cheap
    memory: float = 0.1               # the running mean's weight of each new frame (~10 frames)
    warmup: int = 8                   # frames before the running mean has lost the moving texture
    blur: float = 1.0                 # Gaussian sigma (pixels at that level) before correlating
    min_response: float = 0.3         # weaker phase-correlation peaks are not a measurement
    noise_px: float = 0.4             # 1-sigma error of one shift, full-resolution pixels
    rel_error: float = 0.03           # ...and of its scale: one shift for a whole region, read 0.4-3 % short on smooth walls
    dark_share: float = 0.2           # a region darker than this share of the lit wall: nothing to see
    min_energy_dn: float = 0.4        # smoother than a sensor's noise (flow.texture_energy): the encoder
                                      # flattened it, and what still changes is the light, not the wall
    min_changed: float = 0.2          # fewer pixels changed at all since the last frame: the encoder froze it
    confirm: int = 3                  # shifts in a row that must agree before any is believed...
    agree: float = 0.2                # ...within this share of each other (or a pixel)


class DenseShift:
    """Frame-to-frame wall shift of an untextured region, in full-resolution pixels."""

    def __init__(self, shape: tuple[int, int], params: DenseParams | None = None):
        self.p = params or DenseParams()
        h, w = shape
        f = 2 ** self.p.level
        self._size = (-(-w // f), -(-h // f))
        self._scale = float(f)
        self._window = cv2.createHanningWindow(self._size, cv2.CV_32F)
        self.reset()

    def reset(self):
        self._mean = None             # the running mean of the recent frames: what stays put
        self._prev = None             # the last flat-fielded frame
        self._prev_small = None       # ...and the last frame as it came, at that level
        self._frames = 0
        self._pending: list = []      # (shift, response, start time) found, not yet confirmed by the next
        self._last_dv = None          # the last shift handed out, once confirmed
        self._prev_t = None           # the last frame's time

    def shift(self, roi: np.ndarray, t_s: float):
        """((du, dv), response, since_s): the shift since the last one returned (the sum of the
        confirmed frame-to-frame shifts, from the frame taken at since_s), or None while warming
        up, unsure or waiting for confirmation."""
        found, since = self._frame_shift(roi), self._prev_t
        self._prev_t = t_s
        if found is None:
            self._pending, self._last_dv = [], None
            return None
        if self._last_dv is not None and self._agree([self._last_dv, found[0][1]]):
            self._last_dv = found[0][1]               # confirmed before, and it goes on
            return (*found, since)
        self._last_dv = None
        self._pending.append((*found, since))
        recent = [dv for (_, dv), _, _ in self._pending[-self.p.confirm:]]
        if len(recent) < self.p.confirm or not self._agree(recent):
            self._pending = self._pending[-(self.p.confirm - 1):]
            return None
        du = sum(s[0] for s, _, _ in self._pending)
        dv = sum(s[1] for s, _, _ in self._pending)
        response = min(r for _, r, _ in self._pending)
        since = self._pending[0][2]
        self._pending, self._last_dv = [], recent[-1]
        return (du, dv), response, since

    def _agree(self, dvs) -> bool:
        lo, hi = min(dvs), max(dvs)
        return hi - lo <= max(1.0, self.p.agree * max(abs(lo), abs(hi)))

    def _frame_shift(self, roi: np.ndarray):
        small8 = cv2.resize(roi, self._size, interpolation=cv2.INTER_AREA)
        # a low-contrast wall is copied unchanged from frame to frame by the video encoder: such a
        # frame says nothing about the motion (not even that there was none). A faint wall that
        # moves still changes most pixels a little (a copied block changes none)
        frozen = self._prev_small is not None and encoder_copy(small8, self._prev_small, self.p.min_changed)
        self._prev_small = small8
        small = small8.astype(np.float32)
        if self._mean is None:
            self._mean = small.copy()
        else:                         # a plain average at first: the first frame must not linger in it
            a = max(self.p.memory, 1.0 / (self._frames + 1))
            cv2.addWeighted(self._mean, 1.0 - a, small, a, 0.0, dst=self._mean)
        flat = cv2.GaussianBlur(small / (self._mean + 1.0), (0, 0), self.p.blur)
        flat -= float(flat.mean())
        prev, self._prev = self._prev, flat
        self._frames += 1
        if prev is None or self._frames <= self.p.warmup or frozen:
            return None
        (du, dv), response = cv2.phaseCorrelate(prev, flat, self._window)
        if response < self.p.min_response:
            return None
        return (du * self._scale, dv * self._scale), float(response)


def centre_jacobian(wall, roi) -> tuple:
    """((axial m per row, axial m per column, lateral m per row, lateral m per column), wall metres
    per image pixel) at the ROI centre: the unit of the odometer's gates, and the Jacobian that
    turns the global phase-correlation shift into a first guess of the step."""
    x, y, w, h = roi
    c = np.array([[x + (w - 1) / 2.0, y + (h - 1) / 2.0]])
    dv = wall(c + [[0, 0.5]]) - wall(c + [[0, -0.5]])
    du = wall(c + [[0.5, 0]]) - wall(c + [[-0.5, 0]])
    return (-float(dv[0, 1]), -float(du[0, 1]), float(dv[0, 0]), float(du[0, 0])), abs(float(dv[0, 1]))


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
