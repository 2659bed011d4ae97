"""A coarse, dense measurement for a wall with too little texture for features. Pure: no I/O.

A wet or smooth wall still has large-scale shading that moves with it; what does not move with it
is the LED's specular highlight, the lighting's fall-off, and whatever the video encoder copied
unchanged from the last frame. Those dominate a frame of such a wall, so a plain phase correlation
finds them and reads "no motion". Dividing each frame by a running mean of the recent frames (what
stays put in the image) leaves only what moves with the wall; a phase correlation of two such
frames at quarter resolution then finds the wall's shift. The frames are first resampled onto a grid
even in wall metres (`densegrid.wall_grid`), on which the wall's motion is one shift everywhere, and the shift
is read to a hundredth of a pixel (`refine`). It is a lower-quality measurement than tracked features
(one shift for the whole region), used only where features cannot be had, and only once the running
mean has seen enough frames.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import cv2
import numpy as np

from .flow import coarse_shift, encoder_copy
from .stands import StandParams, StandWatch


@dataclass(frozen=True)
class DenseParams:
    level: int = 2                    # quarter resolution: the shading is coarse, and it is cheap
    memory: float = 0.1               # the running mean's weight of each new frame (~10 frames)
    warmup: int = 8                   # frames before the running mean has lost the moving texture
    blur: float = 1.0                 # Gaussian sigma (pixels at that level) before correlating
    min_response: float = 0.3         # weaker phase-correlation peaks are not a measurement
    noise_px: float = 0.4             # 1-sigma error of one shift, full-resolution pixels
    rel_error: float = 0.015          # ...and of its scale (the wet stress runs read 0.1-0.6 % short)
    dark_share: float = 0.2           # a region darker than this share of the lit wall: nothing to see
    min_energy_dn: float = 0.4        # smoother than a sensor's noise (flow.texture_energy): the encoder
                                      # flattened it, and what still changes is the light, not the wall
    min_changed: float = 0.2          # fewer pixels changed at all since the last frame: the encoder froze it
    confirm: int = 3                  # shifts in a row that must go on steadily before any is believed...
    agree: float = 0.2                # ...each its neighbours' mean within this share (or a pixel)
    refine: int = 1                   # passes of `refine` on OpenCV's shift (0: OpenCV's as it is)
    stop_px: float = 2.0              # a frozen frame after a believed shift this small (px a frame): a stand
    slow_px: float = 6.0              # a first believed motion this slow (px a frame) must add up: across
                                      # its frames at once the shift must be their sum (stop_px or agree)
    slow_confirm_s: float = 0.2       # ...and go on steadily this long (what the car's pitch moves swings back)
    clipped_dn: float = 250.0         # a pixel this bright (at that level) is clipped: it shows no wall
    clipped_margin: int = 1           # ...nor its neighbours (pixels at that level), half-clipped
    clipped_fade: float = 2.0         # the wall around is faded in over this many pixels (Gaussian sigma)
    max_clipped: float = 0.6          # a region clipped more than this share: too little wall to correlate
    clip_forgotten: float = 0.01      # a clip the running mean holds less than this of: gone (~22 frames)
    stand: StandParams = StandParams()   # where no shift is found: a stand the frames show (stands.py)


class DenseShift:
    """Frame-to-frame wall shift of an untextured region, in full-resolution pixels."""

    def __init__(self, shape: tuple[int, int], params: DenseParams | None = None):
        self.p = params or DenseParams()
        h, w = shape
        f = 2 ** self.p.level
        self._size = (-(-w // f), -(-h // f))
        self._scale = float(f)
        self._window = cv2.createHanningWindow(self._size, cv2.CV_32F)
        self.maps = None              # (map_x, map_y) of wall_grid: correlate on the wall, not the image
        self.stands = StandWatch(self.p.stand)   # fed every frame here; reset by the odometer, not with the rest
        self.reset()

    def reset(self):
        self._mean = None             # the running mean of the recent frames: what stays put
        self._clip = None             # ...and of where they were clipped (None: nowhere lately)
        self._prev = None             # the last frame flat-fielded, and where it is clipped (None: nowhere)
        self._prev_small = None       # ...and the last frame as it came, at that level
        self._frames = 0
        self._pending: list = []      # (shift, response, start time, start frame, frame periods) found,
                                      # not yet confirmed
        self._last_dv = None          # the last two shifts handed out, once confirmed
        self._prev_t = None           # the last frame's time
        self._intervals = None        # the last intervals between frames (a list, made when first needed)
        self._frozen = False          # the last frame was the encoder's copy of the one before

    def watch(self, roi: np.ndarray, t_s: float) -> tuple | None:
        """Show the stand watch a frame the odometer could not measure but did not give the dense shift
        (texture enough to try features on, as a faint wall's frames the encoder copies may have):
        the stand it shows, if any."""
        return self.stands.update(t_s, cv2.resize(roi, self._size, interpolation=cv2.INTER_AREA))

    def resample(self, maps):
        """Resample the frames with these maps (dense_conversion's) from now on; what was seen on the
        old grid is forgotten."""
        self.maps = maps
        self.reset()

    def shift(self, roi: np.ndarray, t_s: float):
        """((du, dv), response, since_s): the shift since the last one returned (the sum of the
        confirmed frame-to-frame shifts, from the frame taken at since_s), or None while warming
        up, unsure or waiting for confirmation."""
        before, since = self._prev, self._prev_t
        found = self._frame_shift(roi)
        self.stands.update(t_s, self._prev_small)
        self._prev_t = t_s
        periods = self._periods(t_s, since)
        if found is None and self._frozen and self._last_dv is not None and abs(self._last_dv[-1]) <= self.p.stop_px:
            # seen slowing to a crawl, then frames the encoder left as they were: a faint wall that
            # moved would have changed them as it did a moment ago, so the crawler stands
            self._pending, self._last_dv = [], [0.0, 0.0]
            return (0.0, 0.0), 1.0, since
        if found is None:
            self._pending, self._last_dv = [], None
            return None
        per_frame = found[0][1] / periods     # frames that never came: the shift spans them all
        if self._last_dv is not None and self._steady([*self._last_dv, per_frame]):
            self._last_dv = [self._last_dv[-1], per_frame]      # confirmed before, and it goes on
            return (*found, since)
        self._last_dv = None
        self._pending.append((*found, since, before, periods))
        # a slow first motion must go on for slow_confirm_s: over three frames a sine is a steady
        # shift, and the LED's mirror point on a wet wall moves in the image as the car pitches (0.3
        # degrees at 3 Hz: ~5 px, read as a 0.02 m/s crawl for 0.13 s where the crawler drove at 0.3,
        # and the gap after it carried at that, an independent stress run: -9.1 %); a drive's crawl goes on
        need = self.p.confirm
        recent = [shift[1] / k for shift, _, _, _, k in self._pending]   # (all pending are steady or none)
        if abs(sum(recent[-need:])) < self.p.slow_px * len(recent[-need:]):
            need = max(need, self._slow_frames())
        # next to no motion with no brake seen before it is not believed either: a wall that stands
        # becomes the running mean, and a camera's frames of it flat-field to noise that does not
        # correlate. Only what stays put in the image does (the encoder's copied blocks, what is
        # left of a highlight), while the crawler may drive on under it. Net: shifts of noise that
        # swing each way (+4.9, +0.7, -2.0 px on a wet brick wall, driven over at 30 px a frame after
        # 2 s blind) are no motion either; read as a crawl, they settled the gap as a stand: -26 %
        still = abs(sum(recent)) < self.p.stop_px * len(recent)
        du = sum(shift[0] for shift, *_ in self._pending)
        dv = sum(shift[1] for shift, *_ in self._pending)
        if len(recent) < need or not self._steady(recent) or still or not self._adds_up(dv):
            self._pending = self._pending[-(need - 1):]
            return None
        response = min(r for _, r, *_ in self._pending)
        start = self._pending[0][2]
        self._pending, self._last_dv = [], recent[-2:]
        return (du, dv), response, start

    def _adds_up(self, dv: float) -> bool:
        """Does the wall's shift from the pending shifts' first frame to this one, read at once, make
        their sum dv? What stays put in the image (what is left of a clipped highlight, its glare
        breathing with the car's pose) reads next to no shift frame by frame, its noise a pixel or
        two each way; three of those in a row, just over stop_px, were taken for a crawler setting
        off at 0.2 m/s where the wall moved 30 px a frame (a lobe run: -36 %). Across three frames
        it still reads next to nothing, where a wall that moves reads three times the shift. Only
        checked on a start under slow_px a frame: faster, what stays put does not look like it; but
        always where slow shifts pending are summed with a start's fast ones (glare that lined up
        with a start was summed into it: 36 px where it moved 27, a review's case)."""
        if len(self._pending) <= self.p.confirm and abs(dv) >= self.p.slow_px * sum(k for *_, k in self._pending):
            return True
        # (its peak however weak: one below min_response that agrees is no chance, on a faint wall
        # across three frames it can be the wall's; requiring min_response read a stop run +7 -> +13 %)
        (_, dv_at_once), _ = self._correlate(self._pending[0][3], self._prev)
        return abs(dv_at_once * self._scale - dv) <= max(self.p.stop_px, self.p.agree * abs(dv))

    def _slow_frames(self) -> int:
        """Frames a slow first motion must go on steadily for: slow_confirm_s of them."""
        return math.ceil(self.p.slow_confirm_s / (self._period() or 1 / 30) - 1e-6)

    def _period(self) -> float | None:
        """The frame period: the second shortest of the last nine intervals (one odd timestamp is
        no period; drops only lengthen intervals). None before any."""
        return sorted(self._intervals)[min(1, len(self._intervals) - 1)] if self._intervals else None

    def _periods(self, t_s: float, since) -> int:
        """How many frame periods the interval since the last frame spans (1 but across frames that
        never came: a camera's drops when the loop is late, a recording's gaps). The shifts are
        judged a frame period at a time: counted per frame received, one drop in three left a faint
        wall unmeasured, as each shift across a drop broke the steadiness its neighbours showed.
        Drops only lengthen intervals, so the period is a short one of the recent ones."""
        if since is None or t_s <= since:
            return 1
        dt = t_s - since
        if self._intervals is None:
            self._intervals = []
        self._intervals = (self._intervals + [dt])[-9:]
        return max(1, round(dt / self._period()))

    def _steady(self, dvs) -> bool:
        """Do these frame-to-frame shifts go on as a crawler's drive does: each the mean of its
        neighbours (a steady speed, or a steady brake or start) within 20 % or a pixel? A brake
        to a stand changes the shift by a third a frame, and a chance peak does not line up."""
        tol = max(1.0, self.p.agree * max(abs(d) for d in dvs))
        return all(abs(a - 2 * b + c) <= 2 * tol for a, b, c in zip(dvs, dvs[1:], dvs[2:]))

    def _frame_shift(self, roi: np.ndarray):
        small8 = cv2.resize(roi, self._size, interpolation=cv2.INTER_AREA)
        # a low-contrast wall is copied unchanged from frame to frame by the video encoder: such a
        # frame says nothing about the motion (not even that there was none), unless the wall was
        # just seen slowing to a crawl (`shift`). A faint wall that moves still changes most pixels
        # a little (a copied block changes none)
        frozen = self._prev_small is not None and encoder_copy(small8, self._prev_small, self.p.min_changed)
        self._frozen = frozen
        self._prev_small = small8
        small = small8.astype(np.float32)
        if self.maps is not None:
            small = cv2.remap(small, self.maps[0], self.maps[1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        # a plain average at first: the first frame must not linger in it
        a = 1.0 if self._mean is None else max(self.p.memory, 1.0 / (self._frames + 1))
        if self._mean is None:
            self._mean = small.copy()
        else:
            cv2.addWeighted(self._mean, 1.0 - a, small, a, 0.0, dst=self._mean)
        seen = self._clipped(small >= self.p.clipped_dn, a)
        flat = cv2.GaussianBlur(small / (self._mean + 1.0), (0, 0), self.p.blur)
        if seen is None:
            flat -= float(flat.mean())
        prev, self._prev = self._prev, (flat, seen)
        self._frames += 1
        if prev is None or self._frames <= self.p.warmup or frozen:
            return None
        (du, dv), response = self._correlate(prev, self._prev)
        if response < self.p.min_response:
            return None
        return (du * self._scale, dv * self._scale), float(response)

    def _clipped(self, clipped: np.ndarray, a: float):
        """Where a frame the running mean still holds (weight a for this one) was clipped: its mean
        there is no wall's (None: nowhere, the running mean has forgotten any clip)."""
        if self._clip is None and not clipped.any():
            return None
        clip = clipped.astype(np.float32)
        if self._clip is None:
            self._clip = clip * a
        else:
            cv2.addWeighted(self._clip, 1.0 - a, clip, a, 0.0, dst=self._clip)
        seen = self._clip >= self.p.clip_forgotten
        if not seen.any():
            self._clip = None
            return None
        return seen

    def _correlate(self, then, now):
        """((du, dv) at this level, response) from one flat-fielded frame to another (response 0:
        too little of them is not clipped)."""
        pair = unclipped(then, now, self.p)
        if pair is None:
            return (0.0, 0.0), 0.0
        a, b, keep = pair
        if keep is None:
            (du, dv), response = coarse_shift(a, b, self._window, 1.0)
        else:
            (du, dv), response = coarse_shift(a * keep, b * keep, self._window, 1.0)
        if response >= self.p.min_response and self.p.refine:
            du, dv = refine(a, b, (du, dv), self.p.refine, keep)
        return (du, dv), response


def unclipped(a, b, p: DenseParams):
    """Two flat-fielded frames, each (frame, clipped pixels), ready to correlate: (a, b, keep), a
    and b zero-mean over the pixels clipped in neither, keep (None: nothing clipped) the kept pixels
    blurred, which weighs those clipped in either down (at the disc's edge a clipped pixel keeps up
    to a quarter of its weight: zeroing them there read worse); None: too little is left. A
    saturated highlight is flat in every frame: left in, its disc stands out of the textured wall
    around it by its own level and, staying put while the wall moves, pulls the correlation to next
    to no shift (a wet brick run: 1-2 px a frame read where the wall moved 30). One mask for both
    frames: a disc that breathes with the car's pose must not leave an edge of its own either."""
    (fa, ca), (fb, cb) = a, b
    if ca is None and cb is None:         # (each then zero-mean already)
        return fa, fb, None
    clipped = (cb if ca is None else ca if cb is None else ca | cb).astype(np.uint8)
    if p.clipped_margin:
        k = 2 * p.clipped_margin + 1
        clipped = cv2.dilate(clipped, np.ones((k, k), np.uint8))
    keep = clipped == 0
    if np.count_nonzero(keep) < (1.0 - p.max_clipped) * keep.size:
        return None
    fade = cv2.GaussianBlur(keep.astype(np.float32), (0, 0), p.clipped_fade)
    return fa - float(fa[keep].mean()), fb - float(fb[keep].mean()), fade


def refine(prev: np.ndarray, cur: np.ndarray, guess, passes: int = 1, keep=None) -> tuple[float, float]:
    """The shift prev -> cur (cur(x) = prev(x - d)) to a hundredth of a pixel, from a guess within one.

    OpenCV's phase correlation reads a shift of a few pixels several % off, and the same way at every
    frame of a steady speed: its sub-pixel step is a centroid of the peak (which locks towards whole
    pixels), and its window stays put while the wall moves under it (which pulls towards zero, the
    more so the coarser the shading). Here the window on `cur` moves with the guess, so both windows
    see the same wall; the spectra are whitened only halfway (the faint fine grain is noise, not
    signal); and the peak is found on the correlation as a continuous function of the shift, by
    Newton's method from the guess. For a pure shift that correlation is symmetric about the true
    shift, so its peak is the shift itself: on exactly shifted textures it reads within 0.3 %
    (tests/test_dense.py). The wall's motion is such a shift on wall_grid's grid, not in the image.
    `keep` (`unclipped`'s): a mask that stays put in the image, as the window would; each frame is
    weighted by what is kept in both at the same wall points, the mask moved with the guess too."""
    h, w = prev.shape
    ky, kx, half, win_y, win_x = _spectrum_axes(h, w)
    dx, dy = float(guess[0]), float(guess[1])
    fa = None if keep is not None else np.conj(_half_white(np.fft.rfft2(prev * np.outer(win_y, win_x))))
    for _ in range(passes):
        if abs(dx) > w / 2 or abs(dy) > h / 2:
            break
        if keep is None:
            r = _half_white(np.fft.rfft2(cur * np.outer(_hann(h, dy), _hann(w, dx)))) * fa
        else:                     # what is kept in both, at the same wall points in each
            wp = np.outer(win_y, win_x) * keep * _moved(keep, -dx, -dy)
            wc = np.outer(_hann(h, dy), _hann(w, dx)) * keep * _moved(keep, dx, dy)
            r = _half_white(np.fft.rfft2(_centred(cur, wc))) * np.conj(_half_white(np.fft.rfft2(_centred(prev, wp))))
        for _ in range(2):
            dx, dy = _newton(r, ky, kx, half, dx, dy)
    if not (abs(dx - guess[0]) <= 1.0 and abs(dy - guess[1]) <= 1.0):
        return float(guess[0]), float(guess[1])   # another peak (a periodic wall): OpenCV's stands
    return dx, dy


@lru_cache(maxsize=4)
def _spectrum_axes(h: int, w: int):
    """The angular frequencies of a real 2-D FFT's rows and columns, the weight of each column in
    the full spectrum (the half stored stands for both halves but its first and Nyquist columns),
    and the still window."""
    half = np.full(w // 2 + 1, 2.0)
    half[0] = 1.0
    if w % 2 == 0:
        half[-1] = 1.0
    return 2 * np.pi * np.fft.fftfreq(h), 2 * np.pi * np.fft.rfftfreq(w), half, _hann(h, 0.0), _hann(w, 0.0)


def _moved(img: np.ndarray, dx: float, dy: float) -> np.ndarray:
    """img moved by (dx, dy) pixels, zero where nothing moved in."""
    m = np.float32([[1, 0, dx], [0, 1, dy]])
    return cv2.warpAffine(img, m, (img.shape[1], img.shape[0]), flags=cv2.INTER_LINEAR, borderValue=0.0)


def _centred(img: np.ndarray, weight: np.ndarray) -> np.ndarray:
    """img weighted, less its weighted mean: a level left in would correlate with the weight."""
    return (img - float((img * weight).sum() / max(float(weight.sum()), 1e-9))) * weight


def _half_white(f: np.ndarray) -> np.ndarray:
    return f / (np.sqrt(np.abs(f)) + 1e-12)


def _hann(n: int, shift: float) -> np.ndarray:
    """OpenCV's Hanning window over n samples, moved by `shift` (zero where it moved off)."""
    i = np.arange(n) - shift
    win = 0.5 - 0.5 * np.cos(2 * np.pi * i / (n - 1))
    win[(i < 0) | (i > n - 1)] = 0.0
    return win


def _newton(r, ky, kx, half, dx, dy) -> tuple[float, float]:
    """One Newton step towards the peak of c(d) = Re sum r e^(i k.d) over the full spectrum (r its
    real FFT's half), from (dx, dy); at most half a pixel. Two small matrix products give c's
    gradient and Hessian."""
    ex = half * np.exp(1j * kx * dx)
    ey = np.exp(1j * ky * dy)
    m = np.array([ey, ky * ey, ky * ky * ey]) @ (r @ np.array([ex, kx * ex, kx * kx * ex]).T)
    gy, gx = -m[1, 0].imag, -m[0, 1].imag
    hyy, hxx, hxy = -m[2, 0].real, -m[0, 2].real, -m[1, 1].real
    det = hyy * hxx - hxy * hxy
    if not (det > 0 and hyy < 0):            # not at a maximum's shoulder: stay
        return dx, dy
    sy, sx = (hxx * gy - hxy * gx) / det, (hyy * gx - hxy * gy) / det
    return dx - float(np.clip(sx, -0.5, 0.5)), dy - float(np.clip(sy, -0.5, 0.5))
