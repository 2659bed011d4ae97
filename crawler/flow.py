"""Feature detection and checked Lucas–Kanade tracking on grey ROIs. Pure: no I/O, no state.

All tuning sits in one frozen FlowParams. (OpenCV's Python binding cannot take a prebuilt pyramid in
calcOpticalFlowPyrLK — a list is not accepted as InputArray there — so each LK call builds its own
image derivatives. On the Pi, without NEON, those derivatives cost more than the tracking itself, so
LK runs on a mosaic of small patches around the features instead of on the whole images.)
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.lib.stride_tricks import as_strided


@dataclass(frozen=True)
class FlowParams:
    max_features: int = 30          # Shi–Tomasi corners per keyframe (docs/performance.md)
    quality_level: float = 0.01     # corner strength relative to the strongest one
    min_distance_px: int = 8        # spread features over the ROI
    block_size: int = 7             # corner measure window at full resolution
    detect_scale: int = 2           # corners are looked for on the ROI shrunk this many times
    detect_block: int = 5           # ...with this window there (0: block_size scaled, odd)
    win_px: int = 9                 # LK window (odd)
    search_px: int = 3              # how far LK may move from the guess on its patch (the guess is good)
    levels: int = 1                 # pyramid levels of the whole-image LK for a feature that leaves
                                    # its patch (the guess was off by more than search_px)
    iterations: int = 10
    epsilon_px: float = 0.01
    max_roundtrip_px: float = 0.5   # forward–backward check
    check_backward: bool = True     # the backward LK call of that check (half the tracking cost)
    coarse_level: int = 2           # pyramid level of the phase-correlation first guess
    saturated_dn: int = 250         # grey level of a highlight: no features on or around it (0: off)
    flat_pull: float = 0.03         # a keyframe whose features' row gradient has this share of shading
                                    # that stays put in the image is tracked flat-fielded (`static_pull`)
    flat_px: int = 9                # ...with the local mean over this square taken out (`flatten`)
    flat_gain: float = 4.0          # ...and the rest amplified this much (a wet wall's grain is a few DN)

    @property
    def lk_kwargs(self) -> dict:
        return dict(winSize=(self.win_px, self.win_px), maxLevel=self.levels,
                    criteria=(cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT,
                              self.iterations, self.epsilon_px),
                    flags=cv2.OPTFLOW_USE_INITIAL_FLOW)

    @property
    def detect_block_px(self) -> int:
        return self.detect_block or max(3, (self.block_size // self.detect_scale) | 1)

    @functools.cached_property
    def lk_patch_kwargs(self) -> dict:
        return dict(self.lk_kwargs, maxLevel=0)

    @property
    def patch_px(self) -> int:
        """Side of a feature's patch: its window, one pixel each for the bilinear sample and the
        Scharr derivative (so the patch's own border never reaches the window), and the search."""
        return 2 * (self.win_px // 2 + 2 + self.search_px) + 1


def coarse_image(img: np.ndarray, params: FlowParams, flat: bool = False) -> np.ndarray:
    """The low-resolution copy used for the global phase-correlation guess, as float32; `flat`:
    less its local mean, as `flatten` (shading that stays put would read as a standstill)."""
    f = 2 ** params.coarse_level
    h, w = img.shape
    small = cv2.resize(img, (-(-w // f), -(-h // f)), interpolation=cv2.INTER_AREA).astype(np.float32)
    if flat:
        k = max(3, (params.flat_px // f) | 1)
        small -= cv2.blur(small, (k, k))
    return small


def flatten(img: np.ndarray, params: FlowParams) -> np.ndarray:
    """What LK sees of a wall under shading that stays put in the image (the LED's highlight on a
    wet wall, its fall-off): the image less its local mean over flat_px, times flat_gain, about 128.

    Such shading adds its gradient to the wall's, and LK, which matches gradients, is pulled toward
    no motion by the share of it (`static_pull`). A local mean is a filter that does not depend on
    where it is applied, so the wall's texture moves in the flattened frames exactly as in the
    frames; the shading, smooth over flat_px, is gone. It costs 2.6 M ARM instructions a frame, so
    only keyframes that need it are tracked so (docs/odometry.md, "Weak texture under a fixed
    highlight").
    """
    k = params.flat_px
    return cv2.addWeighted(img, params.flat_gain, cv2.blur(img, (k, k)), -params.flat_gain, 128.0)


def static_pull(img: np.ndarray, before: np.ndarray, pts: np.ndarray, params: FlowParams) -> float:
    """The share of the features' row gradient that stays put in the image: how far LK on img is
    pulled toward no motion (0: not at all, 1: it reads a standstill).

    A patch's shading slope along the rows (its least-squares plane's) is the shading's; texture
    averages out of it. The wall's own coarse shading moves, the LED's stays: `before` is a frame
    taken where the wall was elsewhere, and the product of the two slopes at the same pixels keeps
    only the slope they share, over the patches' mean squared row gradient (LK's weight). Where the
    fine texture stayed too (a stand, blocks the video encoder copied) nothing is pulled: each
    patch counts by how little its row gradients, less their mean, match those before."""
    if len(pts) == 0 or before is None or before.shape != img.shape:
        return 0.0
    t = params.patch_px
    h, w = img.shape
    # every other feature and every other column of its patch, both frames in one array: a
    # statistic, not a measurement (numpy's calls, not its arithmetic, are the cost on the Pi)
    corner = np.minimum(np.maximum(pts[::2].astype(np.intp) - t // 2, 0), (w - t, h - t))
    n = len(corner)
    both = np.concatenate([patches(img, corner, t), patches(before, corner, t)])[:, ::2]
    both = both.astype(np.float32).reshape(2, n, t, -1)
    slope = both.reshape(2, n, -1) @ _row_ramp(t, both.shape[3])        # (2, n)
    rows = np.diff(both, axis=2)
    size = rows[0, 0].size
    mean = rows.sum(axis=(2, 3)) / size                                 # the slope again, per pixel
    sq = np.einsum("knij,knij->kn", rows, rows) / size - mean * mean     # the fine texture's power
    cross = np.einsum("nij,nij->n", rows[0], rows[1]) / size - mean[0] * mean[1]
    same = cross / np.sqrt(sq[0] * sq[1] + 1e-6)      # how alike the fine texture is in both
    moved = np.clip(1.0 - 2.0 * same, 0.0, 1.0)        # half of it the same: a copy, a stand
    gain = slope[0] * slope[1] / np.maximum(sq[0] + mean[0] * mean[0], 1e-6)
    return float(np.mean(moved * gain))


@functools.lru_cache(maxsize=4)
def _row_ramp(t: int, width: int) -> np.ndarray:
    """The weights of a t x width patch's pixels, row by row, that give its least-squares slope
    along the rows (grey levels/px)."""
    y = np.arange(t, dtype=np.float32) - (t - 1) / 2.0
    return np.repeat(y / np.sum(y * y) / width, width)


def detect(img: np.ndarray, params: FlowParams, border_px: int = 0, raw: np.ndarray | None = None) -> np.ndarray:
    """Shi–Tomasi corners (N, 2) float32 in img's pixels, kept border_px away from its edge; a
    specular highlight is looked for in `raw`, the frame as it came, if img is flattened.

    Found on a copy shrunk by detect_scale (averages of s x s pixels): the corner measure is the
    dearest part of a keyframe on the Pi, and LK needs texture under its window, not a corner's
    exact spot.
    """
    s = params.detect_scale
    h, w = img.shape
    small = img if s == 1 else cv2.resize(img, (w // s, h // s), interpolation=cv2.INTER_AREA)
    lit = small if raw is None else raw if s == 1 else cv2.resize(raw, (w // s, h // s), interpolation=cv2.INTER_AREA)
    b = -(-border_px // s)
    mask = None
    if b:
        mask = np.zeros(small.shape, np.uint8)
        mask[b:-b, b:-b] = 255
    if params.saturated_dn and cv2.minMaxLoc(lit)[1] >= params.saturated_dn:
        # a specular highlight stays put in the image while the wall moves under it: its rim is
        # texture that does not move, so no feature is taken on or next to it. Only blobs count
        # (what survives an erosion): bright grains of a well-lit wall clip too, and move with it
        core = cv2.erode((lit >= params.saturated_dn).astype(np.uint8), None, iterations=2)
        if cv2.countNonZero(core):
            glare = cv2.dilate(core, None, iterations=2 + max(1, params.detect_block_px))
            mask = np.full(small.shape, 255, np.uint8) if mask is None else mask
            mask[glare > 0] = 0
    pts = cv2.goodFeaturesToTrack(small, params.max_features, params.quality_level,
                                  max(1, params.min_distance_px // s), mask=mask,
                                  blockSize=params.detect_block_px)
    if pts is None:
        return np.empty((0, 2), np.float32)
    pts = pts.reshape(-1, 2)
    return pts if s == 1 else pts * s + (s - 1) / 2.0


def texture_energy(img: np.ndarray) -> float:
    """How much fine texture a grey image has: the mean absolute difference of horizontal pixel
    neighbours on every 8th row (a few thousand pixels: cheap). Sensor noise alone gives about
    1.1 sigma; lit concrete tens of grey levels; a dark, wet or smooth wall little more than noise."""
    rows = img[::8]
    return float(cv2.mean(cv2.absdiff(rows[:, 1:], rows[:, :-1]))[0])


def encoder_copy(img: np.ndarray, prev: np.ndarray, min_changed: float) -> bool:
    """Fewer than min_changed of the pixels changed at all since prev: a frame the video encoder
    copied. A camera's own frames always differ by their noise."""
    return cv2.countNonZero(cv2.absdiff(img, prev)) < min_changed * img.size


def coarse_shift(prev: np.ndarray, cur: np.ndarray, window: np.ndarray, scale: float):
    """Global image shift prev -> cur by phase correlation: ((dx, dy) in full-res px, response).
    OpenCV multiplies its inputs by the window in place (when their size suits its DFT, as 60 x 60
    does): a reference kept for every frame of a gap would be windowed again at each one."""
    (dx, dy), response = cv2.phaseCorrelate(prev.copy(), cur.copy(), window)
    return np.array([dx * scale, dy * scale]), float(response)


def track(img0: np.ndarray, img1: np.ndarray, pts0: np.ndarray, guess: np.ndarray, params: FlowParams):
    """Track pts0 from image 0 into image 1 starting at guess; check by tracking back.

    Returns (pts1, ok, roundtrip_px). A point is ok when both directions converge, the backward
    track lands within max_roundtrip_px of where it started and its window is inside image 1.
    LK runs on patches around each feature and its guess, which gives what LK on the whole images
    at level 0 gives as long as the feature stays on its patch; one that leaves it is tracked again
    on the whole images, with the pyramid.
    """
    if len(pts0) == 0:
        return pts0.copy(), np.zeros(0, bool), np.zeros(0, np.float32)
    p0 = np.ascontiguousarray(pts0, np.float32).reshape(-1, 2)
    g = np.ascontiguousarray(guess, np.float32).reshape(-1, 2)
    t = params.patch_px
    if min(img0.shape) < t or img0.shape != img1.shape:
        return _track_whole(img0, img1, p0, g, params)
    pts1, ok, roundtrip, settled = _track_patches(img0, img1, p0, g, t, params)
    if np.count_nonzero(settled) < len(p0):
        left = (~settled).nonzero()[0]
        pts1[left], ok[left], roundtrip[left] = _track_whole(img0, img1, p0.take(left, 0),
                                                             g.take(left, 0), params)
    return pts1, ok, roundtrip


class _Layout:
    """Constant arrays of a mosaic of n patches of side t, stacked in one column, from images of a
    given shape. Rows 0..n-1 of the (2n, 2) arrays are image 0's patches, rows n..2n-1 image 1's.

    Where a result must stay on its patch: the window plus a pixel for the bilinear sample and one
    for the derivative, whose values at the patch's edge are not the whole image's; as centre and
    half-width per axis. A patch kept inside the image ends at the image's own zone there, so a
    result off its patch but in the image left through an inner side.
    """

    def __init__(self, n: int, t: int, shape, win_px: int):
        self.n, self.t = n, t
        h, w = shape
        self.tile = np.zeros((2 * n, 2), np.float32)
        self.tile[:, 1] = (np.arange(2 * n) % n) * t          # each patch's corner in the mosaic
        self.centre = np.full((2 * n, 2), t // 2, np.float32)
        self.zero = np.zeros((2 * n, 2), np.float32)
        self.last = np.tile(np.float32([w - t, h - t]), (2 * n, 1))
        hw = win_px // 2
        half = (t - 2 * hw - 4) / 2.0
        self.patch_mid = self.tile[n:] + (hw + 1 + half)
        self.half = np.full((n, 2), half, np.float32)
        self.image_mid = np.tile(np.float32([(w - 2) / 2.0, (h - 2) / 2.0]), (n, 1))
        self.image_half = self.image_mid - (hw + 1)          # the zone is hw + 1 .. size - hw - 3


@functools.lru_cache(maxsize=512)
def _layout(n: int, t: int, shape, win_px: int) -> _Layout:
    return _Layout(n, t, shape, win_px)


def patches(img: np.ndarray, corners: np.ndarray, t: int) -> np.ndarray:
    """The t x t patches of img at integer corners (n, 2), stacked into one (n * t, t) image.

    One fancy index on a strided view, patches[y, x] = img[y:y + t, x:x + t]: no Python loop.
    """
    h, w = img.shape
    s0, s1 = img.strides
    shape, strides = (h - t + 1, w - t + 1, t, t), (s0, s1, s0, s1)
    if img.flags.c_contiguous:         # np.ndarray on the buffer costs a fifth of as_strided
        view = np.ndarray(shape, img.dtype, img, 0, strides)
    else:
        view = as_strided(img, shape, strides)
    return view[corners[:, 1], corners[:, 0]].reshape(-1, t)


def _track_patches(img0, img1, p0, g, t, params):
    """LK on two mosaics of t x t patches: image 0 around p0, image 1 around the guesses.

    Returns (pts1, ok, roundtrip, settled): a result is ok only on its patch and with its window
    inside image 1; not `settled` are those that left their patch through an inner side.
    """
    n = len(p0)
    lay = _layout(n, t, img0.shape, params.win_px)
    pos = np.concatenate([p0, g])
    corner = np.floor(pos)
    corner -= lay.centre
    np.maximum(corner, lay.zero, out=corner)
    np.minimum(corner, lay.last, out=corner)
    shift = corner - lay.tile                         # image position - mosaic position
    q = pos - shift
    ci = corner.astype(np.intp)
    m0, m1 = patches(img0, ci[:n], t), patches(img1, ci[n:], t)
    q0 = q[:n].reshape(-1, 1, 2)
    lk = params.lk_patch_kwargs
    q1, st1, _ = cv2.calcOpticalFlowPyrLK(m0, m1, q0, q[n:].reshape(-1, 1, 2), **lk)
    r = q1.reshape(-1, 2)
    pts1 = r + shift[n:]
    # a patch lies inside the image, so a result on its patch has its window inside the image
    on_patch = within(r, lay.patch_mid, lay.half)
    settled = on_patch
    if np.count_nonzero(on_patch) < n:
        settled = on_patch | ~within(pts1, lay.image_mid, lay.image_half)
    if not params.check_backward:
        return pts1, st1.ravel().view(bool) & on_patch, np.zeros(n, np.float32), settled
    back, st2, _ = cv2.calcOpticalFlowPyrLK(m1, m0, q1, q0.copy(), **lk)
    d = (back - q0).reshape(-1, 2)
    roundtrip = np.hypot(d[:, 0], d[:, 1])
    ok = (st1 & st2).ravel().view(bool) & (roundtrip < params.max_roundtrip_px) & on_patch
    return pts1, ok, roundtrip, settled


def within(p: np.ndarray, mid: np.ndarray, half: np.ndarray) -> np.ndarray:
    """Points (n, 2) inside the boxes mid +- half on both axes (five cheap numpy calls)."""
    off = np.abs(p - mid)
    off -= half
    return np.maximum(off[:, 0], off[:, 1]) <= 0


def _track_whole(img0, img1, p0, g, params):
    """LK on the whole images with the pyramid of params.levels."""
    p0 = p0.reshape(-1, 1, 2)
    lk = params.lk_kwargs
    p1, st1, _ = cv2.calcOpticalFlowPyrLK(img0, img1, p0, g.reshape(-1, 1, 2).copy(), **lk)
    p1 = p1.reshape(-1, 2)
    h, w = img1.shape
    b = params.win_px // 2 + 1                                 # the patches' zone (_Layout)
    inside = ((p1 >= b) & (p1 <= (w - 2 - b, h - 2 - b))).all(axis=1)
    if not params.check_backward:
        return p1, (st1.ravel() == 1) & inside, np.zeros(len(p0), np.float32)
    back, st2, _ = cv2.calcOpticalFlowPyrLK(img1, img0, p1.reshape(-1, 1, 2), p0.copy(), **lk)
    roundtrip = np.linalg.norm((back - p0).reshape(-1, 2), axis=1)
    ok = (st1.ravel() == 1) & (st2.ravel() == 1) & (roundtrip < params.max_roundtrip_px) & inside
    return p1, ok, roundtrip
