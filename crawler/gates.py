"""What a frame must pass before the odometer believes it. Pure: no I/O.

- Texture: a frame with too little fine texture for features (an LED blackout, a wet or smooth wall,
  a frame the encoder left flat) is not tracked at all; features found on it would be noise or
  texture that does not move with the wall.
- Light: a frame much darker than the lit wall has nothing to see, not even for the dense shift.
- Agreement: tracks that disagree far more than lately, both in metres and per metre of step, mean
  a corrupt frame (model errors grow with the step; noise does not), until the new level has held.
- Motion: a measured speed that changed faster than any crawler can since the last good frame
  (texture that stays put in the image while the wall moves: a specular highlight, blocks the encoder
  copied) is refused, until it has said the same long enough to be a real stop (a collision). What
  counts as faster allows for the jitter the believed speeds show lately: a car that pitches reads
  its pitch as a few pixels of speed a frame. Under shading that stays put (a keyframe tracked
  flat-fielded) tracks read a stand whatever the crawler does: there a stand must be seen coming.
- Copies: after a gap, a faint frame the video encoder copied from the last one (almost no pixel
  changed) is no news of the motion. A camera's own frames always differ (sensor noise), and a
  moving textured wall cannot be copied (its copy is a stand); a smooth wall under a fixed
  highlight can, and its copied blocks read as a stand. The motion gate cannot tell that from a
  stop in the gap, so a faint copy never ends one.
  Nor, from a gap until the wall is seen to move, or on a keyframe under shading that stays put,
  do tracks on faint patches the encoder copied while it coded the rest of the frame anew.
- Stands: a standstill keeps the picture. Tracks that read no motion while the frame grows less
  like the picture where the stand began than like the frame before read an encoder that lost the
  motion (CRF 40 at a recording's start re-codes the still picture frame after frame as the crawler
  drives), not a stand: sensor noise and light leave both likenesses the same.
"""

from __future__ import annotations

import math
from collections import deque

import cv2
import numpy as np

from .codec import REF_TEXTURE_DN
from .consensus import FadingMean, median
from .flow import encoder_copy

SPEED_NOISE_RATE = 0.05   # the speed's jitter is remembered over ~20 believed frames...
SPEED_NOISE_MIN = 10      # ...and counts once 10 have shown it
LIGHT_STEP = 0.1          # a blind frame this much brighter or darker than the last measured: the light changed
DRIVE_MEMORY_S = 5.0      # the fastest believed speed is the drive's for this long
COPY_TEXTURE_DN = 2.0     # a copied frame with more fine texture stood (copies of moving walls: <= 1.1 DN, 309 stress runs)
REMATCH_NCC = 0.3         # a match across a gap whose patches' fine texture correlates less is not the wall's...
REMATCH_AFTER_S = 0.2     # ...once this long blind: over a few frames the guess stays on the wall, and at CRF 40
                          # the encoder leaves a wall's fine texture only as blocks


def reacquired(c, n_visible: int, p, m_per_px: float) -> bool:
    """After a restart the wide search against the saved frame can lock onto a chance match on
    other wall: the first measurement must be a clear one (most visible features, tight).
    (Between frames of one run the motion gates already refuse such a match.)"""
    return c.n_in >= p.reacquire_share * n_visible and c.sigma <= p.reacquire_spread_px * m_per_px


class FrameGates:
    def __init__(self, params):
        self.p = params               # OdometryParams (and its DenseParams)
        self.texture_ref = None       # fine texture of recent measured frames (flow.texture_energy)
        self.light_ref = None         # ...and their mean grey level
        self.v_ref = None             # the speed measured at the last good frame (m/s), None: not yet
        self.t_ref = 0.0              # ...and when
        self._refused_since = None    # the first of a run of refused measurements...
        self._refused_pulled = False  # ...and whether under shading that stays put (plausible)
        self._seen = 0
        self._grey_seen = None        # the last measured frame's mean grey
        self._rows = None             # every 8th row of the last frame, kept only inside a gap
        self._still = None            # (distance, picture where a stand began, its last frame's): _picture
        self._dv_var = FadingMean(SPEED_NOISE_RATE)   # the variance of a believed speed's change from the last one's
        self._dv = None                       # ...and that last change
        self._after_gap = False       # from a gap until the tracks see the wall move: copies say nothing
        self._recent: deque = deque() # (t, speed) believed in the last DRIVE_MEMORY_S: what a start sets off to

    def textured(self, energy: float) -> bool:
        ref = self.texture_ref
        return energy >= self.p.min_texture_dn and (ref is None or energy >= self.p.min_texture_share * ref)

    def dark(self, roi) -> bool:
        light = self.light_ref
        return light is not None and _grey(roi) < self.p.dense.dark_share * light

    def copied(self, roi, in_gap: bool, energy: float = 0.0) -> bool:
        """Is this frame (inside a gap) the encoder's copy of the one before, of a faint wall (fine
        texture `energy` under COPY_TEXTURE_DN)? A wall with texture is copied only if it stood: that
        copy is a stand (at CRF 32 a crawler standing in the light after a blackout, 3.5 DN, was
        copied frame after frame and carried on at 0.6 m/s: +47.9 %, a fifth review's run). Costs
        nothing while tracking: the rows are kept only inside a gap."""
        rows, prev = roi[::8], self._rows
        self._rows = rows.copy() if in_gap else None
        if not in_gap or prev is None or prev.shape != rows.shape or energy >= COPY_TEXTURE_DN:
            return False
        return encoder_copy(rows, prev, self.p.dense.min_changed)

    def tracks_say_nothing(self, kf, roi, c, gap_since: float | None, blind_s: float) -> bool:
        """After a gap, is the consensus c no news of the wall: tracks on faint copies
        (`copied_tracks`), or, blind_s after the last measured frame, a match that is not the
        wall's (`wall_matched`)?"""
        if self.copied_tracks(kf, roi, c, gap_since):
            return True
        return blind_s > REMATCH_AFTER_S and not self.wall_matched(kf, roi, c)

    def wall_matched(self, kf, roi, c) -> bool:
        """Do the tracks' patches show the keyframe's fine texture where they found it? Across a gap
        the wide search can lock onto what stays put in the image (the LED's highlight, the light's
        fall-off): smooth, so once the shading is taken out its patches correlate only by their
        noise, where a match on the wall keeps the wall's grain (a wet brick wall re-acquired on the
        highlight after 3 s: 0.21; a wall after a burst of dropped frames: 0.61)."""
        if not len(c.idx):
            return True
        now, then = _fine_patches(roi, c.pts), _fine_patches(kf.img, kf.pts.take(c.idx, 0))
        ncc = (now * then).sum(1) / np.sqrt((now * now).sum(1) * (then * then).sum(1) + 1e-9)
        return float(np.median(ncc)) >= REMATCH_NCC

    def copied_tracks(self, kf, roi, c, gap_since: float | None) -> bool:
        """From a gap (it began at gap_since) until the tracks see the wall move, are the consensus
        c's patches faint copies of the keyframe's, pixel for pixel? The encoder copies the blocks
        of a smooth wall under a fixed highlight while it codes the rest anew: the frame is no copy,
        but tracks on those blocks read a stand that says nothing, also against a keyframe started
        afresh in the gap. Patches of real texture (above REF_TEXTURE_DN, what the quantiser keeps)
        are copied only if the wall stood: those are a stand. On a keyframe tracked flat-fielded
        (shading that stays put was found pulling its features) the same holds at any time: after a
        set-off onto a wet wall at CRF 36, tracks on the highlight and the encoder's banding of the
        light read a stand for 1.6 s while the crawler drove at 0.3 m/s (-0.43 m, an independent
        stress run)."""
        self._after_gap = self._after_gap or gap_since is not None
        if not (self._after_gap or kf.flat) or not len(c.idx):
            return False
        at = kf.pts.take(c.idx, 0)
        if float(np.hypot(*np.median(c.pts - at, axis=0))) >= self.p.still_px:
            self._after_gap = False                     # the wall is seen to move: the gap is over
            return False
        ys, xs = _patches(at, roi.shape)
        now = roi[ys, xs]                               # n x 7 x 7
        if not encoder_copy(now.reshape(len(at), -1), kf.img[ys, xs].reshape(len(at), -1), self.p.dense.min_changed):
            return False
        fine = np.abs(np.diff(now.astype(np.int16), axis=2)).mean()   # as flow.texture_energy, every row
        return float(fine) < REF_TEXTURE_DN

    def morphed(self, kf, roi, at_m: float, still_m: float) -> bool:
        """Does a frame the tracks put within still_m of where the stand began (at_m: its distance)
        drift away from the picture then? The reference is kept across keyframes a stand renews;
        costs nothing while the crawler moves: frames are compared only while it stands."""
        last = self._still
        if last is not None and abs(at_m - last[0]) >= still_m:
            last = self._still = None                   # it moved: no stand
        if abs(at_m - kf.distance) >= still_m:
            return False
        cur = _picture(roi)
        if last is None:
            self._still = (kf.distance, _picture(kf.img), cur)
            return False
        self._still = (last[0], last[1], cur)
        return float(cur.dot(last[1])) < float(cur.dot(last[2])) - self.p.still_slack

    def remember(self, roi, energy: float):
        """A measured frame: what the lit, textured wall looks like lately (the light, which
        changes slowly, from every 4th), and how bright this one is (lit_as_before)."""
        a, tex, light = self.p.texture_memory, self.texture_ref, self.light_ref
        self.texture_ref = energy if tex is None else tex + a * (energy - tex)
        self._seen += 1
        self._grey_seen = grey = _grey(roi)
        if light is None or self._seen % 4 == 0:
            self.light_ref = grey if light is None else light + 4 * a * (grey - light)

    def lit_as_before(self, roi) -> bool:
        """Is a blind frame lit as the last measured one was (within LIGHT_STEP)? A picture that
        changed with the light (an LED going off or coming back: a blackout's first frame, half
        exposed, read 0.78 of the last) says nothing of the wall moving under the camera."""
        g = self._grey_seen
        return g is None or abs(_grey(roi) - g) <= LIGHT_STEP * g

    def measured(self, v: float, t_s: float, over_s: float = 0.0):
        """The speed of a frame that was believed, and how it jitters: a car that pitches and bounces
        moves the image by a few pixels a frame whatever it drives, which the tracks' raw step reads
        as speed (at 40 deg with 0.5 deg of pitch, ~0.1 m/s from one frame to the next). The change
        of the change drops a steady acceleration; clipped, one real stop does not widen the gate.
        A step over_s long, across frames lost or dropped (over across_s), is the mean speed over
        them, not the speed now: the reference stays the one before, its band grown since. (A
        periodic wall's alias across a reversal in a drop read the mean +0.05 m/s; held as the
        speed now, it refused the true -0.52 m/s after, and the tracks followed the alias: +17 %.)"""
        self._refused_since = None    # a believed frame ends any refusal
        across = self.p.across_s + 1e-6          # (frame times are sums of intervals)
        recent = 0.0 < t_s - self.t_ref <= across
        if over_s > across:
            self._dv = None           # ...and the change across it is no jitter
            return
        if self.v_ref is not None and recent:   # (a change from a speed before a gap is none either)
            dv = v - self.v_ref
            if self._dv is not None:
                d2 = dv - self._dv
                cap = 3.0 * max(math.sqrt(3.0 * self._dv_var.value), self.p.speed_tol_m_s)
                d2 = max(-cap, min(cap, d2))
                self._dv_var.add(d2 * d2 / 3.0)
            self._dv = dv
        else:
            self._dv = None
        self.v_ref, self.t_ref = v, t_s
        self._recent.append((t_s, v))
        while self._recent and self._recent[0][0] < t_s - DRIVE_MEMORY_S:
            self._recent.popleft()

    def set_off(self, t_s: float | None):
        """The frames showed the crawler set off out of a stand at t_s, blind (crawler/stands.py):
        from then on it is taken to drive as it did lately (the 90th percentile of the speeds
        believed in the last DRIVE_MEMORY_S, the way it last moved), so a stand read under a pull
        right after must be seen coming. Tracks on the wet edge, as the wall came back, read a stand
        where the crawler drove at 0.1 m/s, 0.3 s after the frames had shown it set off, and the gap
        after was carried at that standstill: -19 % (a stop run on a third seed)."""
        if t_s is None or self.v_ref is None or t_s <= self.t_ref:
            return
        tol = self.p.speed_tol_m_s
        way = next((v for _, v in reversed(self._recent) if abs(v) > tol), 0.0)
        moving = sorted(abs(v) for _, v in self._recent if v * way > 0)
        if moving:
            self.v_ref = math.copysign(moving[int(0.9 * (len(moving) - 1))], way)
            self.t_ref, self._dv = t_s, None

    def wraps(self, dv: float, rows: int, dt: float, rows_per_m: float, t_s: float) -> list[float]:
        """The shifts a phase correlation's dv rows (it wraps every `rows`) may stand for, dt after the
        last tracked frame: dv or the wrap on its other side, the one nearer what v_ref predicts;
        both, that one first, once the speed may have changed by half a wrap since it was measured.
        (A crawler reversed inside a blackout: the speed before, +0.63 m/s, chose the wrap 74 mm
        ahead of one backing at 0.7 m/s, and it was never tracked again, for 3 s: +71 %.)"""
        if self.v_ref is None or not rows_per_m or not dv:
            return [dv]
        # the frames overlap only if the shift is under a wrap: dv or the wrap on its other side
        both = sorted((dv, dv - math.copysign(rows, dv)), key=lambda d: abs(d - self.v_ref * dt * rows_per_m))
        change = (self.p.max_accel_m_s2 * max(t_s - self.t_ref, 0.0) + self.p.speed_tol_m_s) * dt * abs(rows_per_m)
        return both if change >= rows / 2 else both[:1]

    def plausible(self, v: float, t_s: float, pulled: bool = False, frame_s: float = 0.0,
                  set_off: float | None = None) -> bool:
        """Could the crawler have gone from v_ref (at t_ref) to v by t_s? `pulled`: read on a
        keyframe under shading that stays put in the image (flow.static_pull), which pulls the
        tracks toward a stand; there a stand must be seen coming, from a speed one frame (frame_s)
        of braking can stop, and a sudden one is never taken for a collision. `set_off`: when the
        frames showed it set off out of a stand since the last believed frame, if they did
        (set_off; one older than DRIVE_MEMORY_S says nothing of now)."""
        if set_off is not None and t_s - set_off <= DRIVE_MEMORY_S:
            self.set_off(set_off)
        p = self.p
        if self.v_ref is None:
            return True
        jitter = math.sqrt(self._dv_var.value) if self._dv_var.n >= SPEED_NOISE_MIN else 0.0
        tol = p.speed_tol_m_s + p.speed_jitter_k * jitter
        pulled = pulled or (self._refused_since is not None and self._refused_pulled)   # while refused
        since = t_s
        if pulled and abs(v) <= p.speed_tol_m_s:      # a stand read under a pull: a jitter is no stand
            since, tol = self.t_ref + frame_s, p.speed_tol_m_s
        if abs(v - self.v_ref) <= p.max_accel_m_s2 * (min(since, t_s) - self.t_ref) + tol:
            self._refused_since = None
            return True
        if self._refused_since is None:
            self._refused_since = t_s
        self._refused_pulled = pulled
        if t_s - self._refused_since >= p.max_refusal_s and not pulled:
            self._refused_since = None        # said the same long enough: a collision is real
            return True
        return False


class SpreadGate:
    """Recent track disagreement, in metres and per unit of step, to tell a corrupt frame."""

    def __init__(self, params, m_per_px: float):
        self.p = params
        self.m_per_px = m_per_px
        self._spreads: deque[float] = deque(maxlen=15)
        self._sigmas: deque[float] = deque(maxlen=15)
        self._refusals = 0

    def _moving(self, step: float) -> bool:
        return abs(step) > self.p.moving_px * self.m_per_px     # the ratio means nothing at a standstill

    def calm(self, step: float, sigma: float, ratio: float) -> bool:
        p = self.p
        jump = (self._moving(step) and len(self._spreads) >= 5 and len(self._sigmas) >= 5
                and ratio > p.spread_jump * median(self._spreads)
                and sigma > p.spread_jump * median(self._sigmas))
        calm = (not jump or sigma <= p.spread_floor_px * self.m_per_px
                or self._refusals >= p.max_spread_refusals)
        self._refusals = 0 if calm else self._refusals + 1
        return calm

    def accepted(self, step: float, sigma: float, ratio: float):
        self._sigmas.append(sigma)
        if self._moving(step):
            self._spreads.append(ratio)


def _grey(roi) -> float:
    return float(cv2.mean(roi[::8, ::8])[0])


def _patches(pts, shape, r: int = 3):
    """Row and column indices of the (2r + 1)^2 pixels around each point, kept inside the image."""
    h, w = shape
    x = np.clip(np.rint(pts[:, 0]).astype(np.intp), r, w - r - 1)
    y = np.clip(np.rint(pts[:, 1]).astype(np.intp), r, h - r - 1)
    off = np.arange(-r, r + 1)
    return y[:, None, None] + off[None, :, None], x[:, None, None] + off[None, None, :]


def _fine_patches(img, pts, r: int = 4) -> np.ndarray:
    """The (2r + 1)^2 pixels around each point of the image's fine texture (a Laplacian of a
    Gaussian of 0.8 px: the shading taken out), each patch zero-mean: n x (2r + 1)^2."""
    x0, y0 = np.maximum(np.floor(pts.min(0)).astype(int) - r - 3, 0)
    x1, y1 = np.ceil(pts.max(0)).astype(int) + r + 4
    crop = img[y0:y1, x0:x1].astype(np.float32)
    fine = cv2.Laplacian(cv2.GaussianBlur(crop, (0, 0), 0.8), cv2.CV_32F)
    ys, xs = _patches(pts - (x0, y0), fine.shape, r)
    out = fine[ys, xs].reshape(len(pts), -1)
    return out - out.mean(1, keepdims=True)


def _picture(img) -> np.ndarray:
    """The middle of a frame (half its width and height) at quarter size, as a zero-mean unit vector:
    the dot product of two is their normalised cross-correlation (1: the same picture up to light
    and gain). The middle only: shrinking the whole 240 x 240 window cost 0.6 M ARM instructions."""
    h, w = img.shape
    mid = img[h // 4:h // 4 + max(4, h // 2), w // 4:w // 4 + max(4, w // 2)]
    small = cv2.resize(mid, (max(1, mid.shape[1] // 4), max(1, mid.shape[0] // 4)), interpolation=cv2.INTER_AREA)
    v = small.ravel().astype(np.float32)
    v -= v.mean()
    return v / max(float(np.linalg.norm(v)), 1e-6)
