"""`[mount] tilt_deg = "auto"`: find the camera's tilt from the flow, follow it, and keep the
distance measured meanwhile right. Pure: no I/O.

The tilt shows in how far and near features disagree on one step (for a cylinder, the wall metres
each row sees depend on the tilt). From a cold start, or after a step (the operator turned the
camera), the tilt is searched for with the exact projection over a grid (crawler/tilt.py's
TiltSearch); once found, each keyframe gives a reading (a parabola through the disagreement at
three tilts about the estimate, on its closing frame, the next keyframe's first, weighted by how
far its features moved: the car's pitch and bounce between a keyframe and its close bias the
reading by their change per step, and those changes telescope), fused by TiltTrack, whose step
detector opens the search again. The odometer measures with one mount (the
nominal tilt); the estimate's offset from it is corrected linearly in every step, and when it grows
beyond `remount_deg` the mount moves: the odometer takes a new keyframe there, and every step of the
epoch (since the start, or since the step began) is measured again at the new tilt, exactly.
docs/odometry.md, "Pose", has the math.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from .camturn import CameraTurn, TurnParams, turned_before
from .consensus import LATERAL_AXIAL, robust_step
from .odometry_params import OdometryParams
from .posefield import JacobianField
from .tilt import SweepWatch, TiltParams, TiltSearch, TiltTrack
from .tiltfit import MAD_K, disagreement, far_apart, not_stray, robust_mean
from .tiltport import FixedTilt, Hop


@dataclass(frozen=True)
class AutoTiltParams:
    remount_deg: float = 0.3          # the linear corrections hold to here (or 2 sigma); beyond, the mount moves
    acquire_px: float = 40.0          # a frame shows the tilt once its features moved this far
    found_sigma_deg: float = 1.0      # what the search leaves to the readings
    reading_half_deg: float = 0.5     # a reading's three tilts: the estimate and this either side
    max_hops: int = 400               # steps of an epoch kept to be measured again
    tilt: TiltParams = TiltParams()
    turn: TurnParams = TurnParams()   # a camera turned at a stand (crawler/camturn.py)


class AutoTilt(FixedTilt):
    """The tilt estimate, as an offset `tau` (radians) from the mount the odometer measures with."""

    auto = True

    def __init__(self, camera, projection, roi, params: AutoTiltParams | None = None):
        super().__init__(camera, projection, roi)
        self.p = params or AutoTiltParams()
        self.camera, self.roi = camera, roi
        self.tau = 0.0
        self.track: TiltTrack | None = None
        self.search = TiltSearch(projection.mount.tilt_rad, 3 * math.radians(self.p.tilt.start_sigma_deg))
        self.hops: list[Hop] = []
        self._last: Hop | None = None
        self._serial = None
        self._closing = None          # the current keyframe's last frame that shows the tilt: its sample
        self._guessed = None          # the keyframe whose first such frame gave the last provisional tilt
        self._break_t = -math.inf     # the first measured frame after lost frames
        self._after_break = False
        self.steps = 0
        self._kf_t = 0.0              # when the current keyframe was taken
        self.sweep = SweepWatch()     # a camera turned slowly: followed, the steps behind it left as measured
        self.turn = CameraTurn(self.p.turn)   # ...or turned while the crawler stands: solved frame by frame
        self._turn_over = False       # a turn just ended: the mount moves to the tilt it reached
        self._spread = self._scale_spread(self.p.tilt.start_sigma_deg)   # while the search has found nothing
        self._sensitivity = 0.0       # d(distance)/d(tilt) of the epoch's steps, once found
        # the odometer's inlier floor in metres at the ROI's centre (roughly: a floor, not a measure)
        self._floor_m = OdometryParams.inlier_floor_px * projection.mount.height_m / camera.fy

    @property
    def sigma_rad(self) -> float:
        if self.turn.on:
            return self.turn.sigma_rad
        if self.track is None:
            return math.radians(self.p.tilt.start_sigma_deg if not self.steps else self.p.tilt.step_sigma_deg)
        return math.sqrt(max(self.track.var, 1e-12))

    def update(self, serial, xy_k, xy_c, moved_px, t_s, shutter=None) -> float:
        """One measured frame of keyframe `serial`: search, or read the last keyframe's tilt. The
        metres the epoch's closed steps gain from a changed estimate. `shutter`: each track's
        rolling-shutter factor (the frame interval over the time between its two exposures): a
        rolling shutter moves the rows by different times, which would read as tilt."""
        if self.turn.on:              # the turn's frames are solved in follow_turn
            self._serial, self._closing = serial, None
            return 0.0
        if shutter is None:
            shutter = np.ones(len(xy_k))
        before = self.tau
        if serial != self._serial:
            self._read(t_s)
            self._serial = serial
        if moved_px >= self.p.acquire_px:
            if self.track is None:
                self._search_step(serial, moved_px, xy_k, xy_c, shutter)
            else:
                self._closing = (moved_px, xy_k, xy_c, shutter, t_s - self._kf_t)
        if self.sweep.moving and self.track is not None:   # between readings the camera turns on
            t0, tilt0, rate, _ = self.sweep.line
            self.tau = tilt0 + rate * (t_s - t0) - self.projection.mount.tilt_rad
        change = self.tau - before
        for hop in self.hops:
            hop.d += hop.g * change
        closed = sum(h.g for h in self.hops)
        self._sensitivity = closed + (self._last.g if self._last is not None else 0.0)   # and the open step
        return closed * change

    @property
    def epoch_m(self) -> float:
        """The signed metres of the epoch's steps: what a changed estimate re-measures."""
        return sum(h.d for h in self.hops) + (self._last.d if self._last is not None else 0.0)

    @property
    def epoch(self) -> tuple[float, float | None]:
        """(epoch_m, when the epoch's first step was measured): a gap bridged since then was carried
        at the speeds its steps had, and scales with them when they are measured again (crawler/gaps.py)."""
        first = self.hops[0] if self.hops else self._last
        return self.epoch_m, None if first is None else first.t_s

    @property
    def distance_sigma_m(self) -> float:
        """The 1 sigma the tilt's uncertainty leaves in the epoch's steps: before the search has
        found it, their metres times the spread of the scale over the prior (the linear term is
        nothing at 0 deg, where the scale is flat in the tilt); after, d(distance)/d(tilt) times sigma."""
        if self.track is None:
            return abs(self.epoch_m) * self._spread
        return abs(self._sensitivity) * self.sigma_rad

    def _scale_spread(self, sigma_deg: float) -> float:
        """The r.m.s. relative change of the metres per row at the ROI's centre over tilts about this
        mount's, Gaussian with sigma_deg (a view past the wall left out)."""
        m, kind = self.projection.mount, type(self.projection)
        x, y, w, h = self.roi
        c = self.camera.normalise(np.array([[x + w / 2.0, y + h / 2.0], [x + w / 2.0, y + h / 2.0 + 1.0]]))
        z = np.linspace(-2.5, 2.5, 21)
        rows = [kind(replace(m, tilt_rad=m.tilt_rad + math.radians(sigma_deg * v))).to_wall(c)[:, 1] for v in z]
        k = np.abs(np.diff(np.array(rows), axis=1)[:, 0])
        k0 = k[len(z) // 2]                       # the grid's middle: this mount's own tilt
        ok = np.isfinite(k)
        wt = np.exp(-0.5 * z[ok] ** 2)
        return float(np.sqrt(np.sum(wt * (k[ok] / k0 - 1.0) ** 2) / np.sum(wt)))

    def record(self, hop: Hop):
        self._last = hop
        if self._after_break:
            self._break_t, self._after_break = hop.t_s, False

    def new_count(self):
        """The operator's reset: the epoch's steps so far are the old count's; a better tilt found later
        measures only the steps after it again (the open one, partly before it, too)."""
        self.hops = []

    def closed(self, continuous: bool, t_s: float):
        """A new keyframe: the last measured step is closed, part of the epoch. One after lost
        frames (a turn of the camera loses every track) starts what a step found later may span:
        the steps before it were measured at the tilt before the turn, and its first step is the
        gap's, which crawler/gaps.py bridges with the motion model."""
        if not continuous:
            self.turn.forget()
        if self.turn.on:
            if continuous:
                self.turn.keyframe()
            else:                     # lost frames while the camera turned: the tilt it reached is unknown
                self.turn.end()
                self._search_again(self.turn.tilt)
        self._after_break = self._after_break or not continuous
        self._kf_t = t_s
        if not continuous:            # lost frames: a turn may have become anything (a step is found afresh)
            self.sweep.reset()
        if self._last is not None and not self.sweep.moving:   # a step measured while the camera turned
            self.hops.append(self._last)                          # stays at the tilt it had
            del self.hops[:-self.p.max_hops]
        self._last = None

    def checkpoint(self) -> dict:
        if self.track is None:
            return {}
        return {"tilt": {"deg": round(math.degrees(self.projection.mount.tilt_rad + self.tau), 4),
                         "sigma_deg": round(math.degrees(self.sigma_rad), 4)}}

    def resume(self, saved: dict):
        """A restarted run's tilt (a checkpoint's), as if the search had just found it: tracked from
        there (a camera turned while the daemon was down is a step, found as any other). The
        projection to use."""
        tilt_rad = math.radians(saved["deg"])
        m = self.projection.mount
        self.projection = type(self.projection)(replace(m, tilt_rad=tilt_rad))
        self.field = JacobianField(self.camera, self.projection, self.roi)
        self.tau = 0.0
        self.track = TiltTrack(tilt_rad, self.p.tilt, math.radians(self.p.found_sigma_deg))
        return self.projection

    def remount(self):
        """Beyond remount_deg, move the mount to the estimate and measure the epoch again there:
        (the new projection or None, metres the distance gains). A provisional tilt (`_guess`)
        moves it as a found one would. A turn's steps were solved at their tilts: none measured again."""
        if self.turn.on or self._turn_over:
            due, self._turn_over = self._turn_over, False
            if not due and abs(self.tau) <= math.radians(self.p.turn.remount_deg):
                return None, 0.0
            return self._move_mount(), 0.0
        sigma = self.sigma_rad if self.track is not None or self._guessed is None else math.radians(self.p.found_sigma_deg)
        if abs(self.tau) <= max(math.radians(self.p.remount_deg), 2 * sigma):   # not noise
            return None, 0.0
        new = self._move_mount()
        hops = [h for h in self.hops + [self._last] if h is not None and h.t_s != self._break_t]
        extra = sum(self._measure_again(h, new) for h in hops)
        return new, extra

    def keyframe_offset(self, since_kf_s: float) -> float:
        """The keyframe's tilt less this frame's, while the camera turns (radians): a turn moves
        the whole view along the wall as travel does (24 to 40 deg: ~9 cm at the wall)."""
        return -self.sweep.line[2] * since_kf_s if self.sweep.moving else 0.0

    turning = property(lambda self: self.sweep.moving or self.turn.on)

    def follow_turn(self, serial, xy_k, xy_c, read, t_s, rows=None):
        """A camera turned at a stand (crawler/camturn.py): `read` is the frame's pitch against its
        keyframe `serial`, its sigma and the share of the step it explains (None while a turn is followed).
        The frame's (step, lateral step, metres the steps just before gain) with the turn solved, or
        None: no turn. The steps before it stay at the tilt they were measured with; once the tilt
        holds still, its readings go on from the tilt reached, checked for a step (a turn solved wrong
        is searched for again). `rows`: the tracks' exposure times within their frames (keyframe,
        now; seconds), for a rolling shutter: the rows read later were turned further."""
        m = self.projection.mount
        kind, hm = type(self.projection), m.height_m + self.level_m
        earlier = 0.0
        if not self.turn.on:
            if self.track is None or read is None or not self.turn.offer(serial, *read):
                return None
            before = m.tilt_rad + self.tau + self.keyframe_offset(t_s - self._kf_t)   # the keyframe's
            earlier, turned = self._turned_before(lambda tilt: kind(replace(m, tilt_rad=tilt, height_m=hm)), read[0])
            run = self.turn.run_closed_rad            # the steps' turn unsure in them: the tilt still has it
            self.turn.start(before + (run if abs(run) > abs(turned) else turned), before, read[0], self._kf_t, t_s)
            self.hops, self._last, self._closing, self._sensitivity = [], None, None, 0.0
            self.sweep.reset()
        shift = None
        if rows is not None:
            kf_rate, rate = self.turn.rates
            shift = (self.field.at(xy_k)[:, 0:2] * (kf_rate * rows[0])[:, None]
                     - self.field.at(xy_c)[:, 0:2] * (rate * rows[1])[:, None])
        d = self.turn.frame(lambda tilt: kind(replace(m, tilt_rad=tilt, height_m=hm)), xy_k, xy_c, t_s, shift)
        if d is None:                 # the features no longer tell the turn: the tilt is searched for
            self.turn.end()
            self._search_again(self.turn.tilt)
            return None
        self.tau = self.turn.tilt - m.tilt_rad
        if self.turn.still(t_s):
            self.track = TiltTrack(self.turn.tilt, self.p.tilt, self.turn.end(), checked=True)
            self.steps += 1
            self._turn_over = True
        (lat, step), _, _ = robust_step(d.T * LATERAL_AXIAL, self._floor_m, MAD_K)
        return float(step), float(lat), earlier

    def _turned_before(self, at, way: float, most: int = 10) -> tuple[float, float]:
        """A turn found (`way`: its sign): the steps closed just before it (each on the next one's
        first frame) began it while it was too small to tell; solved again with it where it shows
        the same way (the other way, it is a car's jitter: a shaking car's brake read -0.9 deg at
        5.8 sigma). (Metres the distance gains, the turn they hold.)"""
        chain, start = [], self._kf_t
        for hop in reversed(self.hops[-most:]):
            if hop.t_s != start:
                break
            chain.append(hop)
            start = hop.kf_t_s
        gained = turned = 0.0
        for hop in reversed(chain):
            solved = turned_before(at, self.projection.mount.tilt_rad + self.tau + turned, hop.xy_k, hop.xy_c,
                                   self.p.turn)
            if solved is not None and solved[0] * way > 0:
                (_, step), _, _ = robust_step(solved[1].T * LATERAL_AXIAL, self._floor_m, MAD_K)
                gained, turned = gained + float(step) - hop.d, turned + solved[0]
        return gained, turned

    # -- internals ----------------------------------------------------------------------------------

    def _search_step(self, serial, moved_px, xy_k, xy_c, shutter):
        if not self.search.offer(serial, moved_px, (xy_k, xy_c, shutter)):
            if serial != self._guessed:
                self._guess(serial)
            return
        m = self.projection.mount
        found = self._solve()
        self.track = TiltTrack(found, self.p.tilt, math.radians(self.p.found_sigma_deg))
        self.tau = found - m.tilt_rad
        # the closed keyframes' samples read again as readings: the search's median spread finds the
        # tilt where a track may be far off; the readings' variance, strays cut, is the sharper measure
        for key, (moved_px, sample) in self.search.samples.items():
            if key != serial:
                a, slope, at, sigma = self._reading(moved_px, *sample)
                self.track.add(a, slope, at, 0.0, sigma)
                self.tau = self.track.value - m.tilt_rad

    def _solve(self) -> float:
        m, kind = self.projection.mount, type(self.projection)
        return self.search.solve(lambda t, s: disagreement(kind(replace(m, tilt_rad=t)), *s, robust=True))

    def _guess(self, serial):
        """A provisional tilt from the samples so far, on the first frame of each keyframe that
        shows the tilt, till the search has its keyframes: measured at the start's 0 deg, a 40 deg
        camera's first metres read 30 % off (measured again once found, but wrong till then). Its
        sigma stays the search's: one keyframe's sample carries the car's pitch at it."""
        self._guessed = serial
        self.tau = self._solve() - self.projection.mount.tilt_rad

    def _read(self, t_s):
        """The finished keyframe's reading, on its closing frame, fused; a step opens the search
        again. Read on the close, not averaged over the keyframe's frames: the next keyframe starts
        on that frame, so the car's pose at this reading's close is the next one's at its start."""
        closing, self._closing = self._closing, None
        if self.track is None or closing is None:
            return
        a, slope, at, sigma = self._reading(*closing[:4])
        turning, corrected = self.sweep.moving, None
        if turning:                                        # the keyframe at the tilt the turn gave it
            corrected = self._reading(*closing)
        level = corrected[2] - corrected[1] / (2 * corrected[0]) if corrected and corrected[0] > 0 else None
        if a > 0 and self.sweep.add(t_s, at - slope / (2 * a), level, sigma):
            t0, tilt0, rate, s = self.sweep.line          # the camera turns: the steps so far stay at the
            self.hops = []                                 # tilt they were measured with, and the tilt is the
            self.track = TiltTrack(tilt0, self.p.tilt, s, checked=True)   # line's (a fresh track, which
            self.tau = tilt0 - self.projection.mount.tilt_rad              # checks its first reading for a step)
            return
        began = self.track.add(a, slope, at, t_s, sigma)
        if began is None:
            self.tau = self.track.value - self.projection.mount.tilt_rad
            return
        self.hops = [h for h in self.hops if h.t_s >= began and h.t_s > self._break_t]   # the tilt was right
        self._search_again(self.projection.mount.tilt_rad + self.tau)

    def _search_again(self, centre: float):
        """A step of the camera: its tilt searched for afresh about `centre` (a turn: anywhere)."""
        self.steps += 1
        self.search = TiltSearch(centre, 3 * math.radians(self.p.tilt.start_sigma_deg))
        self.track = None
        self.sweep.reset()
        self._spread = self._scale_spread(self.p.tilt.step_sigma_deg)

    def _move_mount(self):
        """The mount moved to the estimate: the new projection."""
        m = self.projection.mount
        new = type(self.projection)(replace(m, tilt_rad=m.tilt_rad + self.tau))
        self.projection, self.field = new, JacobianField(self.camera, new, self.roi)
        self.tau = 0.0
        return new

    def _reading(self, moved_px, xy_k, xy_c, shutter, since_kf_s: float = 0.0):
        """The parabola through the disagreement at the estimate and either side of it: (curvature,
        slope at the estimate, the estimate), scaled to weigh by the features' travel, and the
        reading's own sigma (radians). A change of
        the car's pitch or height between the two frames puts a row profile into the steps: a tilt
        error of the change over the travel times the geometry's own factor. Weighed by travel,
        the keyframes' changes sum to the last frame's pose less the first's; weighed alike (the
        curvature does not grow with the travel) they would add up as a random walk. A sway is
        taken out of the disagreement: its pattern is unlike a tilt's, and left in, its lateral
        spread reads as a tilt whichever side the car swayed to (2 mm: 1 deg at 40 deg)."""
        m, kind = self.projection.mount, type(self.projection)
        t0, h = m.tilt_rad + self.tau, math.radians(self.p.reading_half_deg)
        hm = m.height_m + self.level_m         # read at the height ridden (a ride height's level applied)
        keep = not_stray(kind(replace(m, tilt_rad=t0, height_m=hm)), xy_k, xy_c)
        xy_k, xy_c, shutter = xy_k[keep], xy_c[keep], shutter[keep]
        sway = self.field.at(xy_c)[:, 4:6]
        sway = sway - sway.mean(axis=0)
        turned = self.sweep.line[2] * since_kf_s if self.sweep.moving else 0.0   # the keyframe's tilt was this less

        def at(tilt):
            return kind(replace(m, tilt_rad=tilt, height_m=hm))
        c_lo, c0, c_hi = (disagreement(at(t0 + d), xy_k, xy_c, shutter, sway,
                                       at_keyframe=at(t0 + d - turned) if turned else None) for d in (-h, 0.0, h))
        a, slope = (c_lo + c_hi - 2 * c0) / (2 * h * h), (c_hi - c_lo) / (2 * h)
        if not a > 0:                  # no least: no reading (TiltTrack.add refuses it)
            return 0.0, 0.0, t0, math.inf
        weight = moved_px / (self.p.acquire_px * a)
        least = c0 - slope * slope / (4 * a)    # what no tilt explains: over the curvature and the tracks, its sigma
        return a * weight, slope * weight, t0, math.sqrt(max(least, 0.0) / (a * len(xy_k)))

    def _measure_again(self, hop: Hop, new) -> float:
        """The hop's step at the new mount: the change in metres. Its pitch and height are kept when
        the tilt moved little; read at a tilt far off, they were the tilt's error, and are dropped."""
        old = hop.projection
        if far_apart(old, new, self.p.found_sigma_deg):   # (a turn's keyframe tilt is no error: kept)
            hop.pose = (0.0, 0.0, hop.turn, 0.0)
        wk0, wk1 = old.to_wall(hop.xy_k), new.to_wall(hop.xy_k)
        wc0, wc1 = old.to_wall(hop.xy_c), new.to_wall(hop.xy_c)
        dy = hop.dy + (wk1[:, 1] - wk0[:, 1]) - (wc1[:, 1] - wc0[:, 1])
        jk, jc = self.field.at(hop.xy_k).mean(axis=0), self.field.at(hop.xy_c).mean(axis=0)
        pc, hc, pk, hk = hop.pose
        ride = 1.0 + hop.scale
        d = (robust_mean(dy, self._floor_m) + jk[1] * pk - jc[1] * pc - jc[3] * (hc - hk)) * ride
        if not math.isfinite(d):
            return 0.0
        change, hop.d, hop.g, hop.projection, hop.dy = d - hop.d, d, float(jk[1] - jc[1]) * ride, new, dy
        return change
