"""A stand the frames show where nothing can be measured. Pure: no I/O.

On a wall too faint for features and for the dense shift (a wet stretch under the LED's highlight)
the frames still say one thing: how much they change. While the crawler drives, a faint wall changes
the picture as it moves under the camera; when it stands, what is left is the sensor's noise or the
video encoder's (a still wall is copied, or coded again at a keyframe). A picture that changes far
less than it did while the crawler drove over the same texture is a crawler that stopped.

What it changed by before is only a yardstick on the same texture: a wall fading into a wet patch
changes the picture less and less while the crawler drives on, but its texture (the frame's fine
detail of the compared picture) fades with it, where a stand keeps it; and the changes it
is read from must agree as a drive's do, with the light's level taken out (an LED coming back after
a blackout changes every frame more than the last). A wall whose motion
never showed above the noise (an encoder that flattens it, a live camera on a wall fainter than its
noise) shows no stand, and the gap is bridged as before (crawler/gaps.py).
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import cv2
import numpy as np

from .consensus import median


@dataclass(frozen=True)
class StandParams:
    still: float = 0.3                # a frame that changed less than this share of what the wall's motion
                                      # changed frames by lately is still...
    frames: int = 3                   # ...this many in a row: the crawler stands...
    evidence: int = 5                 # ...measured against at least this many that changed with the motion,
    alike: float = 0.25               # ...their texture within this share of the frame's
    moves: int = 4                    # a stand ends at this many changed frames in a row, one of them at
                                      # `slow` at least (a drive's); else at twice as many (a crawl's)
    memory: int = 9                   # the changes the yardstick is the median of
    slow: float = 0.6                 # a frame that changed less than this share of it is slow (a brake's)...
    slow_frames: int = 6              # ...and becomes part of it only this many in a row (a slower drive)
    lag: int = 3                      # a frame's change: against the frame this many before it
    steady: float = 1.6               # the yardstick's changes: within this factor of their median...
    min_change_dn: float = 0.3        # ...which is at least this (grey levels a pixel; 8-bit rounding alone
                                      # changes the compared picture by a sixth of one)
    light_step: float = 0.02          # a frame this much brighter or darker: the light changed, not the wall
    detail_px: float = 1.5            # the texture: what a Gaussian of this sigma (compared pixels) smooths


class StandWatch:
    """Fed the dense shift's quarter-size frames (a lit wall too faint for features), in order: since
    when the crawler stands."""

    def __init__(self, params: StandParams | None = None):
        self.p = params or StandParams()
        self.reset()

    def reset(self):
        """The odometer's reset: what was seen says nothing of what comes."""
        self.since = None             # the stand's start, or None
        self.until = None             # ...and its end so far
        self._seen: deque = deque(maxlen=self.p.lag + 2)   # (time, picture, light) of the last frames
        self._moved: list = []        # (change, texture) of the recent frames that changed with the motion
        self._stills = 0              # still frames in a row
        self._from = None             # ...since when (half way from the frame before the first of them)
        self._moves = 0               # changed frames in a row
        self._slow = 0                # ...of them slow ones (the last, in a row: all of them if as many)
        self._stand_yardstick = None  # the yardstick the open stand was seen against
        self._broken = False          # a dark or flattened frame since the last still one
        self.set_off = None           # where a stand ended because the frames moved again (take_set_off)

    def unseen(self):
        """A dark or flattened frame: nothing to compare across it. What the drive changed frames by,
        and a stand, stay: a stand goes on if the frames after it are still, and ends if not; what
        the crawler did meanwhile is the gap bridge's (it counts a stand only up to its last still
        frame)."""
        self._seen.clear()
        self._stills = self._moves = self._slow = 0
        self._broken = True           # a stand's end is not dated across it

    def recoded(self):
        """A recording's I-frame: the encoder coded the picture anew, and compared with the frames
        before it, all of it changed (a still wet wall at CRF 38: by 0.3-0.33 of what the drive's
        motion changed frames by, where it had changed by 0.06-0.09; a stand of 1.5 s ended there, and
        the bridge drove on through the rest: +18.5 % of the path). Nothing is compared across it; a
        stand goes on. The P-frames after it settle over a few frames (0.19-0.23 of the yardstick,
        four in a row): a stand ends on changes a drive makes (`moves`)."""
        self._seen.clear()
        self._stills = self._moves = self._slow = 0

    def measured(self):
        """A frame measured: any stand is over, but what the motion changed the frames by (the drive
        into the gap) stays the yardstick. Nothing is compared across it."""
        self.since, self._stills, self._moves, self._slow = None, 0, 0, 0
        self._seen.clear()

    @property
    def stand(self) -> tuple | None:
        """(since, until) of the stand the frames show now, or None."""
        return None if self.since is None else (self.since, self.until)

    def update(self, t_s: float, small: np.ndarray) -> tuple | None:
        """One frame (grey, at the dense shift's quarter size); returns `stand`. (Frames the odometer
        measured, or tried features on, in between are not fed: a keyframe coded sharper changes
        `lag` comparisons at most, fewer than end a stand.)"""
        seen = self._seen
        if min(small.shape) < 4:      # (no picture to halve)
            return self.stand
        f = small.astype(np.float32)
        # compared at half that size: the wall's grain is a few pixels wide, a sensor's noise and an
        # 8-bit picture's rounding (a third of a grey level, each pixel its own) are one
        coarse = cv2.resize(f, (f.shape[1] // 2, f.shape[0] // 2), interpolation=cv2.INTER_AREA)
        if seen and seen[-1][1].shape != coarse.shape:
            seen.clear()
        light = cv2.mean(coarse)[0]
        seen.append((t_s, coarse, light))
        if len(seen) <= self.p.lag:
            return self.stand
        # against the frame `lag` before: a faint grain a crawl moves by less than its width a frame
        # changes the picture little from one frame to the next, but all of it over a few
        _, before, light_before = seen[-1 - self.p.lag]
        if abs(light - light_before) > self.p.light_step * max(light, light_before, 1.0):
            return self.stand         # the light changed (an LED coming back): not the motion's change
        # with the light's level taken out: an LED dimming or coming back scales the whole picture
        level = 0.5 * (light + light_before)
        change = cv2.norm(coarse * (level / max(light, 1.0)), before * (level / max(light_before, 1.0)),
                          cv2.NORM_L1) / coarse.size
        t_prev = seen[-2][0]
        texture = float(cv2.meanStdDev(coarse - cv2.GaussianBlur(coarse, (0, 0), self.p.detail_px))[1][0, 0])
        # the crawler stopped (or set off) between two frames: half way, as near as the frames say
        yardstick = self._yardstick(texture)
        if yardstick is None and self.since is not None:
            yardstick = self._stand_yardstick     # the still picture coded anew, its texture changed
        if yardstick is None or change >= self.p.still * yardstick:
            if self.since is not None and not self._moves and not self._broken:
                self.until = max(0.5 * (t_prev + t_s) - self._edge_s(), self.since)
            self._moves, self._stills = self._moves + 1, 0
            # a slow frame (a brake's) is a drive's only when it goes on: taken at once, a brake's
            # frames pulled the yardstick down until a stand's noise passed for a drive
            slow = yardstick is not None and change < self.p.slow * yardstick
            self._slow = self._slow + 1 if slow else 0
            if self.since is None and (not slow or self._slow >= self.p.slow_frames):
                self._moved = (self._moved + [(change, texture)])[-self.p.memory:]
            elif self.since is not None and self._moves >= self.p.moves * (2 if self._slow == self._moves else 1):
                self.since, self.set_off = None, self.until   # (inside a stand a change is not yet the
                                                              # drive's: a keyframe's)
            return self.stand
        if not self._stills:          # still since the frame `lag` before, not since the one before that
            self._from = 0.5 * (seen[max(0, len(seen) - 2 - self.p.lag)][0] + seen[-1 - self.p.lag][0])
        self._stills, self._moves, self._slow, self.until = self._stills + 1, 0, 0, t_s
        self._broken = False
        if self.since is None and self._stills >= self.p.frames:
            self.since, self._stand_yardstick = min(self._from + self._edge_s(), t_s), yardstick
            self.set_off = None
        return self.stand

    def take_set_off(self) -> float | None:
        """When the frames last showed the crawler set off out of a stand (once: the odometer's gates
        take it, crawler/gates.py), or None."""
        t, self.set_off = self.set_off, None
        return t

    def _edge_s(self) -> float:
        """How far inside the frames still to the comparison the stand itself lies, at each end: a
        brake's last frames and a start's first move the wall by less than its grain, and compared
        `lag` frames apart they change the picture as little as a stand does. So the frames show a
        stand from before the stop to after the start, by about half the comparison's span at each
        end (on the stop runs 1.5 frames at both ends of all nine stands, 0.1-0.2 m/s at 0.5 m/s^2;
        1.5-3.5 on synthetic brakes of 4-20 frames, the longer ones more). Said from half a span in,
        the brake and the start the gap bridge adds to it are not counted twice (they cost 7 mm a
        stand at 0.1 m/s, all one way: -6 % on a stop run)."""
        seen = self._seen
        return 0.5 * self.p.lag * (seen[-1][0] - seen[0][0]) / (len(seen) - 1) if len(seen) > 1 else 0.0

    def _yardstick(self, texture: float) -> float | None:
        """What the motion changed frames of this texture by lately (a fading wall's are not alike),
        if they agree as a drive's do (a light coming back, a fade, do not) and stand out of an 8-bit
        picture's rounding; None: no yardstick."""
        like = [c for c, tx in self._moved if abs(tx - texture) <= self.p.alike * texture]
        if len(like) < self.p.evidence:
            return None
        mid = median(like)
        steady = sum(mid / self.p.steady <= c <= mid * self.p.steady for c in like)
        return mid if steady >= self.p.evidence and mid >= self.p.min_change_dn else None
