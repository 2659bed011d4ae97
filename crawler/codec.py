"""What a lossy recording adds to the distance's error, from the encoder's own quantiser. Pure.

A keyframe's features are corners, found where the decoded frame is sharpest: largely where the
encoder has just coded detail. Frames later, the same wall is a motion-compensated copy whose
residual the quantiser dropped, and it sits a fraction of a pixel behind where it should be.
Measured against hw_sim's source frames at QP 43, the content lags 0.18 px at the corners just
found and 0.5 px elsewhere. So each keyframe's baseline reads short by about the difference, and it
does so at every keyframe: a systematic error that adds up linearly, not as a random walk, and that
no spread of the tracks shows (they all lag alike).

Its size follows the square of the quantiser step (the energy the quantiser drops), 2x per 3 QP.
On hw_sim's x264 recordings it was 0.03-0.07 px per keyframe at QP 34.5, 0.14-0.17 px at 40 and
0.38-0.43 px at 43 (40° and 24° tilt, 0.3 m/s; at 0.5 m/s and at 0° it is smaller, or of the other
sign). sigma takes 0.4 px per keyframe at QP 43, scaled by the step squared: what this version
cannot correct, it says (docs/accuracy.md, "Stress"). A live camera hands over raw frames: no
quantiser, no term. docs/odometry.md, "Compressed recordings", has the figures.

The energy the quantiser drops counts against the texture's own: a faint wall loses more of it. A
photographed brick wall at a third of its contrast (fine texture 1.4-1.7 grey levels, against ~4 on
the walls the model was fitted on) read 0.12 px short per keyframe at QP 28 and 0.30 px at QP 33,
7-10x the model. Below REF_TEXTURE_DN the term grows as the square of the ratio.
"""

from __future__ import annotations

import math


def qstep(qp: float) -> float:
    """H.264's quantiser step at this QP: it doubles every 6."""
    return 0.625 * 2.0 ** (qp / 6.0)


REF_QP = 43.0
REF_BIAS_PX = 0.4        # 1-sigma systematic shortfall of one keyframe's baseline at REF_QP
REF_TEXTURE_DN = 4.0     # ...on a wall with this much fine texture as decoded (flow.texture_energy)


def keyframe_bias_px(qp: float, texture_dn: float | None = None) -> float:
    """1-sigma systematic error of one keyframe's baseline (pixels) at this mean QP, on a wall with
    this much fine texture (None: as the model's)."""
    faint = 1.0 if not texture_dn or texture_dn >= REF_TEXTURE_DN else (REF_TEXTURE_DN / texture_dn) ** 2
    return REF_BIAS_PX * (qstep(qp) / qstep(REF_QP)) ** 2 * faint


class CodecBias:
    """The systematic part of sigma a compressed recording adds, summed over its closed keyframes.

    `m_per_px` is the odometer's scale at the ROI's centre (a turned camera changes it a little; the
    term is a bound, not a correction). The QP is averaged over recent frames: I-frames are
    quantised finer than the P-frames a keyframe is measured on."""

    def __init__(self, m_per_px: float, memory_frames: float = 10.0):
        self.m_per_px = float(m_per_px)
        self._a = 1.0 / max(memory_frames, 1.0)
        self.qp: float | None = None
        self.texture_dn: float | None = None
        self.sigma_m = 0.0
        self.keyframes = 0

    def update(self, qp: float | None, keyframe_closed: bool, texture_dn: float | None = None) -> float:
        """One frame: its mean QP (None: raw frames, or a decoder that does not say), whether a
        keyframe's baseline closed on it, and its fine texture (a tracked frame's; None: not read).
        The term so far, metres."""
        if qp is not None and math.isfinite(qp):
            self.qp = qp if self.qp is None else self.qp + self._a * (qp - self.qp)
        if texture_dn is not None and math.isfinite(texture_dn) and texture_dn > 0:
            tex = self.texture_dn
            self.texture_dn = texture_dn if tex is None else tex + self._a * (texture_dn - tex)
        if keyframe_closed and self.qp is not None:
            self.sigma_m += keyframe_bias_px(self.qp, self.texture_dn) * self.m_per_px
            self.keyframes += 1
        return self.sigma_m
