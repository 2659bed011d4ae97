"""A camera turned while the crawler stands or creeps: the flow is the turn's, not travel. Pure: no I/O.

The operator stops to inspect and turns the camera: every feature moves along the wall as if the car
had driven (24 -> 34 deg at a stand read +5 cm). Travel moves every feature by the same wall metres;
a turn moves each by what its row sees (far rows more), the pattern the pose estimator reads as the
frame's pitch against its keyframe (crawler/pose.py). Frames in a row whose pitch explains the step
the tracks show, one way, 1.5 deg of it, are a turn, not the car's jitter (which turns back, and
which a moving car's step dwarfs).
From then on each frame's travel and turn are solved together, exactly: the keyframe at its tilt, the
frame at the tilt that makes the features agree on one step. The mount follows (crawler/autotilt.py),
and once the tilt holds still the readings take over from the tilt reached. docs/odometry.md, "Pose".
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .posemodel import PITCH, prior_free


@dataclass(frozen=True)
class TurnParams:
    arm_deg: float = 1.5          # frames in a row turned the camera this far one way...
    arm_share: tuple = (0.7, 1.6)   # ...each turn explaining this share of the step the tracks show
    sure_z: float = 3.0           # (a frame's pitch within this many of its sigmas says nothing)
    arm_z: float = 10.0           # the frame that starts it is this sure of its pitch
    retro_z: tuple = (10.0, 5.0)  # a step closed before is solved again if a turn shows this sure in it,
    retro_share: float = 0.2      # the second where it explains this share of the step (a moving
                                  # car's jitter: a tenth)
    still_deg: float = 0.1        # the turn is over once the tilt's trend moves it less than this...
    still_s: float = 0.5          # ...over this long (or the car drives: the turn explains under
    drive_share: float = 0.5      # this share of the step all that while)
    remount_deg: float = 3.0      # the mount follows the turn in strides this long (each a keyframe)
    half_deg: float = 0.25        # the exact solve's parabola: this either side of its guess
    sigma_share: float = 0.03     # the tilt reached is known to this share of the turn, at best...
    sigma_floor_deg: float = 0.1  # ...and this


def turn_pitch(read, hh, hz, zz, rows, means, kept=(PITCH,)):
    """The frame's pitch against its keyframe, its sigma, and the share of the tracks' step it
    explains, or None. `read`: the pose filter's prior-free (pitch, variance), or None where the
    pitch is not estimated: then read here from the model's normal equations with the states
    `kept` (crawler/posemodel.py; `means`: of its columns: the first is the step per radian of
    pitch, the seventh the step)."""
    if read is None:
        solved = prior_free(hh, hz, zz, rows, sorted({PITCH, *kept}))
        if solved is None:
            return None
        read = solved[0][PITCH], solved[1][PITCH]
    pitch, var = read
    share = means[0] * pitch / means[6] if means[6] else math.inf
    return pitch, math.sqrt(max(var, 0.0)), share


def solve_turn(at, kf_tilt: float, xy_k: np.ndarray, xy_c: np.ndarray, guess: float, half: float, shift=None):
    """The frame's tilt less its keyframe's (radians) at which the features agree on one step, and
    their displacements there ((n, 2): the keyframe's wall position less the frame's) of the
    features kept (a mask: strays, far from the rest at that turn, left out), or None.
    `at(tilt)`: the projection at a tilt. Travel
    only shifts every feature alike, so the spread of the displacements is the turn's alone; its
    least is found by parabolas from the guess, and again without the strays. (The car's bounce
    and sway are not fitted with it: a height's pattern is too like a turn's in half a frame, and
    fitted, it cost the clean turns more than it gave the shaking one.) `shift`: (N, 2) added to
    each displacement (a rolling shutter's: rows read later were turned further)."""
    wk = at(kf_tilt).to_wall(xy_k)
    if shift is not None:
        wk = wk + shift
    delta = _least_spread(at, kf_tilt, wk, xy_c, guess, half)
    if delta is None:
        return None
    d = wk - at(kf_tilt + delta).to_wall(xy_c)
    keep = _agreeing(d)
    if not keep.all() and np.count_nonzero(keep) >= 5:
        again = _least_spread(at, kf_tilt, wk[keep], xy_c[keep], delta, half)
        if again is not None:         # (else the first, with the strays in)
            return again, wk[keep] - at(kf_tilt + again).to_wall(xy_c[keep]), keep
    return delta, d, np.ones(len(d), bool)


def _least_spread(at, kf_tilt, wk, xy_c, delta, h):
    def spread(delta):
        d = wk - at(kf_tilt + delta).to_wall(xy_c)
        if not np.all(np.isfinite(d)):
            return math.inf
        d = d - d.mean(axis=0)
        return float(np.sum(d * d))

    fine = h / 16.0                   # the spread is a parabola only near its least: close in
    for _ in range(12):               # a turn of some degrees between two frames: a few strides
        lo, mid, hi = spread(delta - h), spread(delta), spread(delta + h)
        a = lo + hi - 2.0 * mid
        if not (a > 0 and math.isfinite(a)):
            return None
        shift = max(-8.0 * h, min(8.0 * h, h * (lo - hi) / (2.0 * a)))
        delta += shift
        if abs(shift) < 0.1 * h:
            if h <= fine:
                return delta
            h /= 4.0
    return None                       # no least found


def _agreeing(d: np.ndarray, k: float = 6.0) -> np.ndarray:
    """The displacements within k robust sigmas of their median (a track on the wrong texture
    lands anywhere)."""
    dev = np.abs(d - np.median(d, axis=0))
    mad = np.median(dev, axis=0) * 1.4826 + 1e-9
    return np.all(dev <= k * mad, axis=1) & np.all(np.isfinite(d), axis=1)


def turned_before(at, kf_tilt: float, xy_k, xy_c, p: TurnParams):
    """A closed step's turn, when a turn is found just after it (it began there, and was small yet):
    (as solve_turn) if the features agree far better with it than without (retro_z), else None.
    Where the turn explains little of the step it must be surer: the step in which the car stopped
    and the turn began holds both (asked to explain a third of it, a 24 -> 34 deg turn read +0.21 %
    for +0.02 %), but on a moving car a bounce reads as a turn too (a shaking car's brake: -0.9 deg
    at 5.8 sigma); where the turn explains a good part, 5 sigma will do (a photographed gravel
    wall's 3 deg read at 8 sigma, left out: +0.9 %)."""
    solved = solve_turn(at, kf_tilt, xy_k, xy_c, 0.0, math.radians(p.half_deg))
    if solved is None:
        return None
    _, d, keep = solved
    plain = at(kf_tilt).to_wall(xy_k[keep]) - at(kf_tilt).to_wall(xy_c[keep])
    left, before = float(np.var(d[:, 0]) + np.var(d[:, 1])), float(np.var(plain[:, 0]) + np.var(plain[:, 1]))
    z2 = len(d) * (before - left) / max(left, 1e-18)      # the turn's reduction, in its noise's units
    step = float(np.mean(plain[:, 1]))
    share = 1.0 - float(np.mean(d[:, 1])) / step if step else 1.0
    return solved if z2 >= p.retro_z[1 if share >= p.retro_share else 0] ** 2 else None


class CameraTurn:
    """A turn being followed: the keyframe's tilt and the frame's (radians, absolute), and the
    frames' tilts over the last `still_s`, to tell when it is over; before one, the frames in a row
    whose flow is mostly a turn one way, to tell when one begins."""

    def __init__(self, params: TurnParams | None = None):
        self.p = params or TurnParams()
        self.on = False
        self._run = (0, None, 0.0, 0.0)   # (its sign, keyframe, its keyframes' turns closed, this one's)
        self.kf_tilt = self.tilt = self.began = 0.0
        self._trail: list = []        # (t, tilt, share of the step) of the turn's frames: the last still_s
        self._delta = 0.0             # the last frame's tilt less its keyframe's: the next one's guess
        self._kf_rate = 0.0           # the turn's rate when the keyframe was taken (rad/s)

    def offer(self, serial, pitch: float, sd: float, share: float) -> bool:
        """This frame's pitch against its keyframe `serial` (the pose estimator's prior-free reading,
        its sigma, the share of the tracks' step it explains): True once the frames in a row whose
        flow is mostly a turn one way have turned the camera arm_deg. A car's pitch jitter, that
        explains a creeping car's step too (0.5 deg on a photographed wall at 4 cm/s), turns back
        within a fraction of a second; an operator's turn goes on. A frame unsure of its pitch
        neither counts nor breaks the run, and the frame that starts a turn is sure of it (arm_z: at
        0 deg, where a pitch is hardest to tell from travel, one frame read 2.3 deg at 5 sigma)."""
        sign, kf, closed, last = self._run
        if kf is not None and serial not in (kf, kf + 1):   # a keyframe passed unread: no run
            sign, kf, closed, last = self._run = (0, None, 0.0, 0.0)
        if abs(pitch) < self.p.sure_z * sd:
            return False
        lo, hi = self.p.arm_share
        way = 1 if pitch > 0 else -1
        if not lo <= share <= hi or (sign and way != sign):
            self._run = (0, None, 0.0, 0.0)
            return False
        if kf is not None and serial != kf:
            closed += last
        self._run = (way, serial, closed, pitch)
        return abs(closed + pitch) >= math.radians(self.p.arm_deg) and abs(pitch) >= self.p.arm_z * sd

    def forget(self):
        """Lost frames, or a turn begun: no run of frames before counts."""
        self._run = (0, None, 0.0, 0.0)

    @property
    def run_closed_rad(self) -> float:
        """The turn the run of frames showed in its keyframes closed (their pitches, summed)."""
        return self._run[2]

    def start(self, kf_tilt: float, began: float, guess: float, kf_t: float, t_s: float):
        """A turn found on the frame at t_s: its keyframe's tilt and time, the tilt before the turn
        (radians), the frame's turn as read. The turn's rate so far is the read turn over the time
        since the keyframe; the keyframe's, that too where the run began before it (else none)."""
        rate = guess / (t_s - kf_t) if t_s > kf_t else 0.0
        self.on, self.kf_tilt, self.tilt, self.began = True, kf_tilt, kf_tilt, began
        self._kf_rate = rate if self._run[2] else 0.0
        self.forget()
        self._trail, self._delta = [(min(kf_t, t_s - 1e-3), kf_tilt, 1.0)], guess

    @property
    def rates(self) -> tuple[float, float]:
        """(the turn's rate when the keyframe was taken, now) in radians a second, from its frames."""
        (t0, a, _), (t1, b, _) = self._trail[-2:] if len(self._trail) > 1 else ((0.0, 0.0, 0), (1.0, 0.0, 0))
        return self._kf_rate, (b - a) / (t1 - t0) if t1 > t0 else 0.0

    def frame(self, at, xy_k, xy_c, t_s: float, shift=None):
        """This frame's displacements with the turn solved (as solve_turn), or None."""
        solved = solve_turn(at, self.kf_tilt, xy_k, xy_c, self._delta, math.radians(self.p.half_deg), shift)
        if solved is None:
            return None
        self._delta, d, keep = solved
        self.tilt = self.kf_tilt + self._delta
        plain = at(self.kf_tilt).to_wall(xy_k[keep])[:, 1] - at(self.kf_tilt).to_wall(xy_c[keep])[:, 1]
        plain = float(np.mean(plain if shift is None else plain + shift[keep, 1]))
        share = 1.0 - float(np.mean(d[:, 1])) / plain if plain else 1.0   # of the step, the turn's
        self._trail.append((t_s, self.tilt, share))
        while len(self._trail) > 2 and self._trail[1][0] <= t_s - self.p.still_s:
            self._trail.pop(0)
        return d

    def keyframe(self):
        """A new keyframe, on the frame just measured: at that frame's tilt."""
        self.kf_tilt, self._delta, self._kf_rate = self.tilt, 0.0, self.rates[1]

    def still(self, t_s: float) -> bool:
        """The turn is over: over the last still_s the tilt's trend moved it less than still_deg (or
        than three of its standard errors: a car's jitter is no turn), or the car drove (the turn
        explained under drive_share of every step)."""
        if t_s - self._trail[0][0] < self.p.still_s or len(self._trail) < 4:
            return False
        t, tilt, share = np.array(self._trail).T
        if np.all(share < self.p.drive_share):
            return True
        tc = t - t.mean()
        sxx = float(tc.dot(tc))
        slope = float(tc.dot(tilt)) / sxx
        s2 = float(np.sum((tilt - tilt.mean() - slope * tc) ** 2)) / (len(t) - 2)
        moved = abs(slope) * self.p.still_s
        return moved < max(math.radians(self.p.still_deg), 3.0 * math.sqrt(s2 / sxx) * self.p.still_s)

    @property
    def sigma_rad(self) -> float:
        """The sigma of the tilt reached so far."""
        return max(self.p.sigma_share * abs(self.tilt - self.began), math.radians(self.p.sigma_floor_deg))

    def end(self) -> float:
        """The turn is over: the sigma (radians) of the tilt it reached."""
        self.on = False
        return self.sigma_rad
