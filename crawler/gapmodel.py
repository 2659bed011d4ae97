"""The motion model of one gap the camera did not see, for the gap bridge (gaps.py). Pure.

What a crawler did while blind is read from the speeds, rates and stops seen at its two ends: how
far it went (`travel` while blind; `gapsettle.settled_travel` once the speed after is known) and how
unsure that is (`model_var`, `stand_var`). A crawler's drive ramps at a constant rate and cruises; it may
stand where an operator stops to look.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from .drive import edge_time


@dataclass(frozen=True)
class BridgeParams:
    scale_sigma: float = 2e-3         # relative error of one keyframe step (pose jitter, bounce, geometry)
    step_floor_m: float = 2e-5        # a keyframe step is never known better than this (LK, compression)
    speed_diffusion: float = 0.02     # m^2/s^3: how fast an unseen speed change grows (a random walk)
    speed_sigma_m_s: float = 0.005    # 1-sigma error of a measured speed (0.25 s least squares)
    unknown_speed_m_s: float = 0.5    # 1-sigma speed of a crawler never measured yet (a run starting blind)
    max_accel_m_s2: float = 1.0       # the model never extrapolates a stronger acceleration
    hard_accel_m_s2: float = 3.0      # ...but a crawler can brake or start this hard: what sigma must cover
    hidden_stand_s: float = 0.3       # an operator's stop lasts this long at least (one a gap may hide)
    history_s: float = 0.3            # speed and acceleration before a gap: fitted over this much
    min_history_s: float = 0.1        # ...and a speed measured over less than this settles no gap alone
    brief_still_m_s: float = 0.05     # ...nor, with the speed before known, one under this (gapends.py)
    min_accel_m_s2: float = 0.15      # a fitted acceleration below this is noise: constant speed
    ramp_dv_m_s: float = 0.05         # a speed change across a gap below this is the fits' error, not a ramp
    settle_s: float = 0.25            # after a fresh start, measure the speed this long before settling
    across_s: float = 0.15            # a step measured across more unseen time is checked against the speeds
    across_speed_m_s: float = 0.05    # ...at its ends, each known within this, at the rates the model allows
    max_bridge_s: float = 30.0        # beyond this the model is a guess: the speed fades to 0 over it
    pose_sigma_m: float = 0.0         # the camera's pitching on the car, as wall metres (measurement.py)
    jitter_memory: float = 0.05       # weight of each frame in the running jitter estimate (~1 s at 30 fps)
    min_drive_accel_m_s2: float = 0.25   # the gentlest brake or start into or out of a stand the video showed
    min_stand_s: float = 0.5          # a stand shown for less is none (the encoder copied a moving wall)
    shown_end_sigma_s: float = 0.05   # ...and one's end is known this well (stands.py: within a frame or two)


@dataclass
class Gap:
    """One gap, as seen at its start, and the stands the frames showed inside it."""

    t0: float                         # the last measured frame before it
    d0: float                         # the distance published then
    v0: float | None                  # speed then (None: never measured)
    a0: float                         # acceleration then (0 if unknown)
    sa: float = 0.0                   # ...and its 1-sigma error
    up: float = 0.0                   # the rate of a crawler speeding up into it: not carried, it settles it
    lag: float = 0.0                  # v0 read over a moment: how far it may be from the speed at t0
    stood_s: float = 0.0              # the stands the frames showed, closed (crawler/stands.py), with their edges
    stand: tuple | None = None        # an open one: (since, until)
    edges_var: float = 0.0            # the variance of the brakes and starts into and out of them
    confirmed: bool = False           # ...the open one has been shown for min_stand_s
    held_from: float = 0.0            # ...and the frame it was first shown at
    last_end: float | None = None     # where the last stand shown ended
    before_last: float = 0.0          # ...and the model's time up to its start
    edge_s: float = 0.0               # half the time of the start out of the stand shown (_edge)
    vis0: float = 0.0                 # the odometer's own distance at t0
    cruise: float | None = None       # the last steady speed measured before it (gaps.py)
    drive: tuple = (None, None)       # the rates the drive was seen to set off and brake at (drive.py)
    resumed: tuple | None = None      # (model time, speed, until): after a stand shown, it drove on at that
                                      # speed (a braking gap: until another stand shown; else inf)
    carried_m: float = 0.0            # a braking gap: what it drove between stands shown before that
    open_at_close: bool = False       # a stand was still shown when the wall was measured again
    before_reset_m: float = 0.0       # the model's travel up to an operator's reset inside it
    either_way: bool = False          # it set off as it opened, which way not seen (gaps.py _setting_off)
    set_off_var: float | None = None  # ...its variance (a stand shown from before it takes it back)
    across: bool = False              # the odometer measured across it: its step, checked by the speed after
    rejoin: float | None = None       # a frame measured inside a stand shown, and lost again: when
    alias: tuple | None = None        # ...and the stand shown again after it: (its since, the kept since)

    def measured_again(self, scale: float, gain_before_m: float):
        """Tilt auto measured the steps its speeds came from again (gaps.py): every speed and rate
        scales, and the distance at its start gains what the steps before it did."""
        self.v0 = None if self.v0 is None else self.v0 * scale
        self.a0, self.sa, self.up = self.a0 * scale, self.sa * scale, self.up * scale
        self.cruise = None if self.cruise is None else self.cruise * scale
        self.drive = tuple(None if r is None else r * scale for r in self.drive)
        self.resumed = None if self.resumed is None else (self.resumed[0], self.resumed[1] * scale, self.resumed[2])
        self.carried_m, self.edges_var = self.carried_m * scale, self.edges_var * scale ** 4   # (v * v / a)^2
        if self.before_reset_m:               # kept over an operator's reset: the count starts there
            self.d0 -= (scale - 1.0) * self.before_reset_m
            self.before_reset_m *= scale
        else:
            self.d0, self.vis0 = self.d0 + gain_before_m, self.vis0 + gain_before_m


_STAND_STATE = ("stand", "confirmed", "stood_s", "before_last", "last_end", "resumed", "edges_var", "edge_s", "held_from")
REJOIN_S = 0.5                         # a stand shown again this soon after a frame measured inside it is that one


def stand_state(g: Gap) -> tuple:
    """What see_stand keeps of the stands shown, to be put back (`rejoin`)."""
    return tuple(getattr(g, f) for f in _STAND_STATE)


def rejoin(g: Gap, state: tuple, t_s: float):
    """The gap reopened after one frame measured at t_s (a fresh start, lost again at once) while a
    stand was shown: the measurement ended the stand, not the crawler. Its state goes back to before,
    and a stand shown again within REJOIN_S is the same one (taken as a start and a new stand's brake,
    a frame measured in a 4.5 s stand cost 205 mm at 0.3 m/s)."""
    for field, value in zip(_STAND_STATE, state):
        setattr(g, field, value)
    g.rejoin = t_s


def see_stand(p: BridgeParams, g: Gap, stand: tuple | None, t_s: float | None = None):
    """Account a blind frame (at t_s) that shows a stand (since, until), or none (crawler/stands.py). The
    frames show it from where the crawler stopped to where it set off again; a brake from v at rate a
    covers what v covers in half its time, so the model, which carries v up to the stand, takes it
    to begin v / 2a earlier, and to end as much later for the start out of it. The rate is not seen:
    anything from min_drive_accel_m_s2 to max_accel_m_s2, so the middle, with its uniform variance.
    A stand shown for less than min_stand_s is none: an encoder that stopped coding a faint wall
    for a moment copied it while the crawler drove on (a lobe run: -0.03 -> -12.4 %); but in a gap
    whose model brakes to a stop, its end says when the crawler set off (settled_travel). Until then
    the model holds (its clock stops, nothing is taken back); from then the stand and its brake
    count, and the distance steps back by what the brake was worth."""
    if g.rejoin is not None and g.stand is not None:   # a frame measured inside the stand shown:
        if stand is None and t_s is not None and t_s <= g.rejoin + REJOIN_S:
            return                                      # not shown either way yet, it holds
        if stand is not None and stand[0] <= g.rejoin + REJOIN_S:
            g.alias = (stand[0], g.stand[0])            # shown again: the same stand
        g.rejoin = None
    if g.alias is not None and stand is not None and stand[0] == g.alias[0]:
        stand = (g.alias[1], stand[1])
    if g.stand is not None and (stand is None or stand[0] != g.stand[0]):   # it ended
        if g.confirmed:                                # the start out of it
            before = max(0.0, max(g.stand[0], g.t0) - g.t0 - g.stood_s)
            g.before_last, g.last_end = max(before, g.before_last), g.stand[1]   # (one inside the last's start)
            if g.resumed is None and g.v0 is not None and not braking(g):
                g.resumed = (g.before_last, speed_after_stand(p, g), math.inf)
            g.stood_s += g.stand[1] - max(g.stand[0], g.t0)
            _edge(p, g, 3.0)
        if braking(g) and g.stand[1] - g.t0 >= -g.v0 / g.a0:   # the stop it implies, shown: it set
            if g.resumed is None:                      # off then, and drove on at its cruise (travel)
                g.last_end, v = g.stand[1], speed_after_stand(p, g)
                g.resumed = (g.last_end - g.t0 + edge_time(p, v, g), v, math.inf)
            elif g.confirmed and g.resumed[2] != math.inf:   # another stand shown ended: on again
                (T0, v, until), g.last_end = g.resumed, g.stand[1]
                g.carried_m += v * (faded(p, until) - faded(p, T0))
                g.resumed = (max(until, g.last_end - g.t0 + edge_time(p, v, g)), v, math.inf)
        g.stand, g.confirmed = None, False
    if stand is not None:
        if g.stand is None:
            g.held_from = stand[1]                     # first shown at this frame
        g.stand = stand
        if not g.confirmed and stand[1] - max(stand[0], g.t0) >= p.min_stand_s:
            g.confirmed = True                         # the brake into it
            if g.set_off_var is not None and stand[0] - g.t0 <= g.resumed[0]:   # the set-off taken as the
                g.edges_var = max(0.0, g.edges_var - g.set_off_var)   # gap opened is not: it stood on (a start after
                g.resumed, g.either_way, g.set_off_var = None, False, None     # the stand is its own)
            _edge(p, g, 1.0)
            if braking(g) and g.resumed is not None and g.resumed[2] == math.inf:   # it stood again:
                T0, v, _ = g.resumed                   # the carry ends, its brake taken off
                g.resumed = (T0, v, max(T0, stand[0] - g.t0 - edge_time(p, v, g, start=False)))


def speed_after_stand(p: BridgeParams, g: Gap) -> float:
    """The speed a crawler sets off to after a stand the frames showed: its drive's cruise, the last
    steady speed measured before the gap, where the gap opened slower the same way (a brake no fit
    read, or a speed read over a moment: a stop run opened one at 0.062 m/s from three frames of a
    brake, and was carried at that where it drove 0.1: -25 mm), or standing; else the speed before."""
    c, v = g.cruise, g.v0
    if c is None or v is None or abs(c) <= abs(v):
        return v
    return c if c * v > 0 or standing(p, v) else v


def moving_speed(g: Gap) -> float:
    """The speed the model carries the crawler at now: the speed before the gap, or after a stand."""
    return g.v0 if g.resumed is None else g.resumed[1]


def set_off(p: BridgeParams, g: Gap, t1: float, v1: float, a1: float) -> float | None:
    """After a stand shown, a crawler still speeding up when the wall is measured again (at t1, v1,
    at a1) set off from rest v1 / a1 before: the gap's distance is the model's up to that stand and
    the ramp since. None: no stand ended in the gap, it is not seen speeding up, or the ramp did not
    begin as the stand ended (within 0.1 s: the end is seen a frame or two late). A speed at t1
    against the ramp, within 0.1 s of rate of none, is a crawler that sets off just then."""
    if g.last_end is None or g.stand is not None or not a1 or braking(g):
        return None
    if a1 * v1 <= 0:
        return travel(p, g, g.before_last) if abs(v1) <= 0.1 * abs(a1) and t1 - g.last_end <= 0.1 else None
    if abs(t1 - abs(v1 / a1) - g.last_end) > 0.1:     # it set off as the stand ended, not long after
        return None
    return travel(p, g, g.before_last) + math.copysign(v1 * v1 / (2 * abs(a1)), v1)


def braking(g: Gap) -> bool:
    """Does the gap's model brake to a stop by itself (a brake seen before it)? Then a stand shown is
    the one it implies: it keeps its own clock."""
    return g.v0 is not None and g.a0 * g.v0 < 0


def _edge(p: BridgeParams, g: Gap, share: float):
    """One brake or start: half its time as stood, the rate's range as variance. A stand's two are
    one drive's error twice: the start adds three times the brake's variance, the stand's (2 x)^2."""
    v = abs(moving_speed(g) or 0.0)
    g.stood_s += edge_time(p, v, g, start=False)
    after = g.resumed[1] if g.resumed is not None else speed_after_stand(p, g)
    g.edge_s = edge_time(p, after or 0.0, g)              # the start out of it: the clock waits for it
    g.edges_var += share * rate_range_var(p, v, v)


def rate_range_var(p: BridgeParams, dv: float, v: float) -> float:
    """The variance of a change of speed by dv, at a rate anywhere from min_drive_accel_m_s2 to
    max_accel_m_s2, in metres at v: the time it takes, uniform over that range's."""
    quick, gentle = dv / (2 * p.max_accel_m_s2), dv / (2 * p.min_drive_accel_m_s2)
    return (v * (gentle - quick)) ** 2 / 12.0


def start_rate_seen(p: BridgeParams, g: Gap) -> bool:
    """Did the frames before the gap show a start at a rate a drive can have (`up`)?"""
    return p.min_drive_accel_m_s2 <= g.up <= p.max_accel_m_s2


def model_time(g: Gap, t: float) -> tuple[float, float]:
    """The motion model's time from the gap's start to t, and the variance it adds: the time the
    frames did not show the crawler standing (a stand still open counts up to its last still frame:
    what came after it is not seen), and the variance of the brakes and starts into and out of the
    stands they showed. A gap whose model brakes to a stop by itself keeps all its time (the stand
    shown is the one it implies; the start after it is read from the speed after). After a stand
    the clock goes on once the start's own time is over, and never takes back the time before the
    stand: a wall seen again, or frames moving again, within it are the start's (counted from
    the stand's end at once, a start of 0.1 s took 12 mm back from a crawler at 0.1 m/s), nor does a
    stand shown inside the last one's start. (The one step back is a stand's confirmation: to where
    it began, see_stand.)"""
    if braking(g):
        return t - g.t0, 0.0
    if g.stand is not None and g.confirmed:            # frames past its last still one: the start's
        before = max(0.0, max(g.stand[0], g.t0) - g.t0 - g.stood_s, g.before_last)
        return before + max(0.0, t - g.stand[1] - g.edge_s), g.edges_var
    open_s = 0.0
    if g.stand is not None:                            # (one not yet shown min_stand_s: held, from where it was)
        open_s = max(0.0, g.stand[1] - max(g.held_from, g.t0))
    T = max(0.0, t - g.t0 - g.stood_s - open_s)
    return (T if g.last_end is None else max(T, g.before_last)), g.edges_var


def travel(p: BridgeParams, g: Gap, T: float) -> float:
    """Distance over T at the speed and acceleration before the gap, and after a stand the frames
    showed at the speed it set off to (`resumed`); a crawler that was braking stops (it does not
    reverse); beyond max_bridge_s the speed fades to nothing over as long again."""
    if g.v0 is None:
        return 0.0
    v0, a = g.v0, g.a0
    if a and v0 * a < 0 and -v0 / a < T:          # braking: stops inside the gap, and sets off after a
        braked = -0.5 * v0 * v0 / a + g.carried_m   # stand the frames showed end, up to the next shown
        if g.resumed is None or T <= g.resumed[0]:
            return braked
        T0, v, until = g.resumed
        return braked + v * (faded(p, min(T, until)) - faded(p, T0))
    if g.resumed is not None and T > g.resumed[0]:   # after a stand shown: on at the speed it set off to
        T0, v = g.resumed[:2]
        return v0 * faded(p, T0) + v * (faded(p, T) - faded(p, T0))
    return v0 * faded(p, T) + 0.5 * a * min(T, p.max_bridge_s) ** 2


def travel_to(p: BridgeParams, g: Gap, t_s: float) -> float:
    """What the model carried the crawler from the gap's start to t_s."""
    return travel(p, g, model_time(g, t_s)[0])


def speed_to(p: BridgeParams, g: Gap, t_s: float, dt: float = 0.01) -> float:
    """The speed the model carried the crawler at, at t_s: the slope of its travel there."""
    return (travel_to(p, g, t_s + dt) - travel_to(p, g, t_s - dt)) / (2 * dt)


def standing(p: BridgeParams, v: float) -> bool:
    """A speed within a measured speed's own error: a standing crawler, whatever its sign."""
    return abs(v) <= p.speed_sigma_m_s


def faded(p: BridgeParams, T: float) -> float:
    """The model's time at full speed in T: beyond max_bridge_s the speed falls linearly to nothing
    over as long again (never back)."""
    m = p.max_bridge_s
    x = min(max(T - m, 0.0), m)
    return min(T, m) + x - x * x / (2 * m)


def stops(g: Gap, T: float, v1: float = 0.0, hard: float = math.inf) -> float | None:
    """When the model had the crawler stop inside the gap (s after its start), else None; None too
    where no start from there at `hard` gets to the speed after, v1, by T (the brake was the shake's)."""
    if g.v0 is None or not g.a0 or g.v0 * g.a0 >= 0 or -g.v0 / g.a0 >= T:
        return None
    return -g.v0 / g.a0 if abs(v1) <= hard * (T + g.v0 / g.a0) else None


def model_var(p: BridgeParams, T: float, v0: float | None, settled: bool = False, sa: float = 0.0, lag: float = 0.0) -> float:
    """Variance of a gap of T carried by the model. The speed wanders like a random walk the
    camera did not see (variance speed_diffusion * t): its integral over the gap has variance
    q T^3 / 3 with only the speed before known, q T^3 / 12 once the speed after settles it (a
    Brownian bridge). Add the measured speeds' own errors (and a speed before read over a moment's
    `lag`), or, for a run that starts blind, no speed at all."""
    q, sv = p.speed_diffusion, p.speed_sigma_m_s
    if v0 is None:
        sv = p.unknown_speed_m_s
    if settled:
        return 0.5 * (sv * T) ** 2 + (0.5 * lag * T) ** 2 + q * T ** 3 / 12.0
    return (sv * T) ** 2 + (lag * T) ** 2 + q * T ** 3 / 3.0 + stand_var(p, T, v0) + (0.5 * sa * T * T) ** 2


def stand_var(p: BridgeParams, T: float, v0: float | None) -> float:
    """Blind longer than it takes to brake, the crawler may stand (an operator stops to look):
    even odds of that, anywhere from braking its hardest to driving on (range^2 / 6)."""
    a = p.hard_accel_m_s2
    if v0 is None or T <= abs(v0) / a:
        return 0.0
    return (abs(v0) * T - v0 * v0 / (2 * a)) ** 2 / 6.0
