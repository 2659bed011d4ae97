"""A gap settled: how far the crawler went while the camera was blind, once the speed after the gap
is known (`settled_travel`), and the variance the video cannot show. Pure.

The motion model while blind is crawler/gapmodel.py's; this reads it against the speed and the rate
measured after the gap (crawler/gapends.py `speed_after`): a constant change between the two
speeds, a ramp seen at one end, a stop the model braked to, the stands a gap may hide.
"""

from __future__ import annotations

import math

from .drive import drive_rate
from .gapmodel import BridgeParams, Gap, braking, moving_speed, standing, start_rate_seen, stops, travel


def settled_travel(p: BridgeParams, g: Gap, T: float, v1: float, a1: float = 0.0) -> tuple[float, float]:
    """The gap's distance once the speed after it is known, and the variance the video cannot show."""
    if g.v0 is None:      # a run that started blind: the speed after, constant (even odds it set off in it)
        return v1 * T, max(0.0, abs(v1) * T - v1 * v1 / (2 * p.hard_accel_m_s2)) ** 2 / 6.0
    stop = stops(g, T, v1, p.hard_accel_m_s2)
    if (between := _stood_between(p, g, T, v1, a1, stop)) is not None:
        return between
    if stop is not None:
        return _settled_after_stop(p, g, T, v1, a1, stop)
    # a constant acceleration over the gap; but a ramp seen at one end goes on at its rate to the
    # other end's speed, when the change is more than the speeds' own errors could make
    guess, gain, dv = 0.5 * (g.v0 + v1) * T, abs(v1) - abs(g.v0), v1 - g.v0
    ramped = abs(dv) >= p.ramp_dv_m_s    # a stand the frames showed, or a set-off as the gap opened (gaps.py)
    off = (g.resumed is not None and not start_rate_seen(p, g)      # (a start's rate seen: read at it below)
           and v1 * g.resumed[1] > 0 and abs(v1) - abs(g.v0) >= p.ramp_dv_m_s    # that the speed after bears out
           and not a1 * v1 > 0        # a crawler seen still speeding up after it: its ramp times the start
           and T >= g.resumed[0])     # ...and one at its cruise before the model's start is half done set off
    shown = (g.stood_s > 0 or g.stand is not None or off) and not braking(g)   # quicker: any time, at any rate
    dv_run = v1 - moving_speed(g)
    if shown and g.open_at_close and standing(p, v1):
        # still standing when the wall was measured again: it never set off (measuring again ended
        # the stand, not the crawler); the model up to where it stood, with no brake out of a start
        return travel(p, g, g.before_last), 0.0
    rate = drive_rate(p, g, start=abs(v1) > abs(moving_speed(g)))
    if shown and (moving_speed(g) * v1 >= 0 or standing(p, v1)) and abs(dv_run) < rate * T:
        # the frames showed it stand and drive again: between the stands it drove at the speed before
        # (after one, at the speed it set off to; the time it stood is not in T), and a change to the
        # speed after came at the end, at the drive's rate (the trapezoid spread a brake measured as
        # the wall came back over the gap)
        guess = travel(p, g, T) + 0.5 * dv_run * abs(dv_run) / rate
    elif ramped and g.up and g.v0 * v1 > 0 and 0 < gain < g.up * T:     # speeding up into it, then cruising
        guess = math.copysign(abs(g.v0) * T + gain * (T - 0.5 * gain / g.up), v1)
    elif ramped and a1 and dv * a1 > 0 and abs(dv) < abs(a1) * T:   # cruising, then the ramp seen after it
        guess = g.v0 * T + 0.5 * dv * abs(dv / a1)
    # ...but the speed changed at a moment the video does not show: at once to at the last, as hard
    # as a crawler can (uniform: range^2 / 12; at the model's bound, 1.5-3 m/s^2 brakes in drops read
    # 2-7 sigma off); or, in a gap long enough to brake to a stop, stand a moment and start again, a
    # stand it does not show either (an operator stops to look): down to braking and starting as
    # hard as a crawler can. Even odds of driving through and of a stand of any length
    a, v0 = p.hard_accel_m_s2, g.v0
    when = max(0.0, abs(dv) * (T - abs(dv) / a)) ** 2 / 12.0      # (the change takes |dv| / a of T)
    span = abs(v0) + abs(v1)          # (never less than a stand between brakes at the model's bound)
    if v0 * v1 >= 0 and T > min(span / a + p.hidden_stand_s, span / p.max_accel_m_s2):
        least = math.copysign((v0 * v0 + v1 * v1) / (2 * a), v0 + v1)
        return guess, max(when, (guess - least) ** 2 / 6.0)
    return guess, when


def _settled_after_stop(p: BridgeParams, g: Gap, T: float, v1: float, a1: float, stop: float) -> tuple[float, float]:
    """settled_travel for a gap whose model braked to a stop inside it (`stop` s after its start)."""
    braked = -0.5 * g.v0 * g.v0 / g.a0
    shown = g.last_end - g.t0 if g.last_end is not None and g.stand is None else None
    shown = shown if shown is not None and stop <= shown <= T else None
    before = braked if shown is None else travel(p, g, shown)    # (and what it drove between two stands)
    if not standing(p, v1) and a1 * v1 > 0 and T - v1 / a1 >= stop:
        # braked to a stop, still speeding up when seen again: it started from rest v1 / a1 before,
        # or where the frames showed its stand end, if a drive gets to v1 from there by then (the
        # fitted rate of a start seen for a few frames is rough: 0.30 m/s^2 where it was 0.5)
        if shown is not None and (p.min_drive_accel_m_s2 * (T - shown) <= abs(v1)
                                  <= p.max_accel_m_s2 * (T - shown + p.shown_end_sigma_s)):
            return before + math.copysign(0.5 * abs(v1) * (T - shown), v1), (0.5 * v1 * p.shown_end_sigma_s) ** 2
        return before + math.copysign(v1 * v1 / (2 * abs(a1)), v1), 0.0
    if not standing(p, v1):
        # braked to a stop inside the gap, stood, and started again at the same rate up to v1.
        # How long it stood is not in the video: anything from not at all to all the time left,
        # so the middle, with that range's uniform variance; unless the frames showed the stand
        # end (crawler/stands.py): then it set off then (a stop run on another seed: +32 mm when
        # the middle was taken for a start the frames had shown 0.6 s later)
        a = abs(g.a0)
        if shown is not None:
            ramp = min(abs(v1) / a, T - shown)
            moved = 0.5 * a * ramp * ramp + abs(v1) * (T - shown - ramp)
            return before + math.copysign(moved, v1), (v1 * p.shown_end_sigma_s) ** 2
        ramp = min(abs(v1) / a, T - stop)
        longest = T - stop - ramp         # the longest it can have stood
        moved = 0.5 * a * ramp * ramp + abs(v1) * longest / 2
        return braked + math.copysign(moved, v1), (v1 * longest) ** 2 / 12.0
    if g.resumed is None:              # stopped, and still stopped; after a set-off the frames showed,
        return braked, 0.0             # stopped again somewhere up to where the carry had it: the middle
    carried = travel(p, g, T) - braked - g.carried_m   # (what it drove between stands shown is known)
    return braked + g.carried_m + carried / 2, carried * carried / 12.0


def _stood_between(p: BridgeParams, g: Gap, T: float, v1: float, a1: float,
                   stop: float | None) -> tuple[float, float] | None:
    """A brake read before the gap, too gentle to stop before a start from rest read after it (slower
    than before or the other way, and speeding up): the crawler stood between (`stop`: where the
    brake at the rate read stops inside the gap; a start after that is _settled_after_stop's). A fit
    over a window that mostly cruised reads a brake's onset weak (0.31 m/s^2 for a drive braking at
    1.0: the trapezoid carried a stop-and-go in a 0.97 s burst of drops at 0.3 m/s, +188 mm). It was at rest
    by the time it set off (|v1 / a1| before the gap's end), braking at any rate from the one that
    just gets it there to the hardest a crawler brakes at: the middle of the times that takes, with
    their uniform variance. None: no such start, or none a drive (max_accel_m_s2) stops in time for."""
    if not (braking(g) and a1 * v1 > 0 and (v1 * g.v0 < 0 or abs(v1) <= abs(g.v0) - p.ramp_dv_m_s)):
        return None
    longest = T - abs(v1 / a1)                    # when it set off from rest
    if stop is not None and (longest >= stop or g.last_end is not None or g.stand is not None):
        return None
    shortest = abs(g.v0) / p.hard_accel_m_s2
    if longest <= 0 or abs(g.v0) / longest > p.max_accel_m_s2:
        return None                               # no drive stops by then: it slowed down, not to rest
    moved = 0.25 * g.v0 * (shortest + longest) + 0.5 * v1 * abs(v1 / a1)
    var = (0.5 * g.v0 * (longest - shortest)) ** 2 / 12.0
    # ...or it only slowed down: at most to where braking at the rate read and speeding up at the
    # rate read after meet (a slow-down to 0.08 m/s taken for a stop read 50 mm short, 2.4 sigma)
    brake, up = abs(g.a0), abs(a1)                # (a reversal went through rest)
    dip = (abs(g.v0) - abs(v1) + up * T) / (brake + up)
    low = abs(g.v0) - brake * dip
    if v1 * g.v0 > 0 and low > 0.0:
        most = 0.5 * (abs(g.v0) + low) * dip + 0.5 * (low + abs(v1)) * (T - dip)
        var += (most - abs(moved)) ** 2 / 12.0
    return moved, var
