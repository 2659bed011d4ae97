"""What a measured frame's distance is unsure of that does not carry on, for the gap bridge
(gaps.py). Pure.

The tracks' spread over their number is the frame's own noise. What moves all tracks at once (the
camera pitching on a bouncing car, compression) is the frame's jitter: each frame's pose error
cancels between the keyframe steps that end and start there, so it is the measured distance's
scatter about a straight line, and it is not summed. The pitch the tracks showed lately counts
when it is above the configured one.
"""

from __future__ import annotations

import math

from .consensus import FadingMean


class FrameNoise:
    """The measured distance's frame-by-frame noise: its jitter and the tracks' spread."""

    def __init__(self, params):
        self.p = params
        self._jitter = FadingMean(params.jitter_memory)   # the frame's pose/compression jitter (m^2)
        self._last3: list = []        # the last measured (t, vision distance) in a row, for that
        self.pitch_m = 0.0            # the pitch the tracks showed lately (wall metres)

    def lost(self):
        """A frame not measured: the next three in a row start again."""
        self._last3 = []

    def track(self, est):
        """The measured distance's scatter about a straight line over three frames in a row: the
        residual of the third against the line through the first two has 1 + (1 + r)^2 + r^2 times
        the frame's variance (r: the ratio of the intervals). Accelerations count too, which errs
        on the safe side."""
        self.pitch_m = getattr(est, "pitch_m", 0.0)    # (a plain estimate has none)
        if not est.continuous:
            self._last3 = []
        self._last3.append((est.t_s, est.distance_m))
        if len(self._last3) < 3:
            return
        (t0, d0), (t1, d1), (t2, d2) = self._last3[-3:]
        del self._last3[0]
        if t1 <= t0 or t2 <= t1:
            return
        r = (t2 - t1) / (t1 - t0)
        resid2 = (d2 - d1 - (d1 - d0) * r) ** 2 / (1 + (1 + r) ** 2 + r * r)
        v = self._jitter.value
        self._jitter.add(min(resid2, 9 * v) if v > 0 else resid2)    # one bad frame does not set the level

    @property
    def pose_var(self) -> float:
        """The jitter and the pitch, as a variance of the distance now (not carried on)."""
        return self._jitter.value + max(self.p.pose_sigma_m, self.pitch_m) ** 2

    def tracks(self, est) -> float:
        """The tracks' spread over their number, never below the step floor."""
        spread = (est.spread_mm or 0.0) / 1000.0
        return max(spread / math.sqrt(max(est.inliers, 1)), self.p.step_floor_m)

    def white(self, est) -> float:
        """For the fusion: the white part only (the pose term is slow, a filter must not average it)."""
        return math.hypot(self.tracks(est), math.sqrt(self._jitter.value))
