"""The motion at a gap's two ends, from the frames measured before and after it, for the gap bridge
(gaps.py): `motion_before` reads the speed and rate a gap opens at, `speed_after` the speed that
settles it (and the rate it still changes at). Pure.
"""

from __future__ import annotations

import math

from .drive import blurred
from .gapmodel import braking, stops
from .motionfit import TIME_EPS, brief_speed, ramp, ramp_at, ramp_rate, slope


def motion_before(p, hist, t0: float, settled_v=None, remeasured_at=None):
    """(speed, acceleration, its 1-sigma error[, the rate of a crawler speeding up[, how far the speed
    may be from the speed at t0]]) at t0 from the measured (t, distance) samples hist (speed None:
    never measured). p: the bridge's parameters (gapmodel.BridgeParams); settled_v: (t, speed) of
    the last gap settled; remeasured_at: when the odometer last measured its steps again at a new
    tilt."""
    def short(h):
        return len(h) < 2 or h[-1][0] - h[0][0] < p.min_history_s - TIME_EPS

    h = before_a_hole([(t, d) for t, d in hist if t >= t0 - p.history_s], p.min_history_s)
    if short(h):                  # a gap just before cut the stretch short: the longer memory
        h = list(hist)
    if short(h):
        # one frame interval of a video that may be lying (a bad start); but a gap that opens
        # as the one before it settled goes on at the speed that settled it
        if settled_v is not None and settled_v[0] >= t0 - TIME_EPS:
            return settled_v[1], 0.0, 0.0
        return None, 0.0, 0.0
    ts, ds = [t - t0 for t, _ in h], [d for _, d in h]
    if len(h) < 5 or ts[-1] - ts[0] < 0.5 * p.history_s:
        # read over a moment: its mean is the speed at its middle, which at t0 may have changed by
        # what a hard start or brake makes of half that (a start at 2.5 m/s^2: 0.17 m/s for 0.33)
        span = ts[-1] - ts[0]     # (only a moment: over 0.15 s at a low frame rate, its slope as before)
        return slope(ts, ds), 0.0, 0.0, 0.0, p.hard_accel_m_s2 * span / 2 if span < 0.5 * p.history_s else 0.0
    # back in time from t0: a ramp that began inside the window, after a cruise (a quadratic
    # over the window blurs a late brake). Only a brake is carried into the gap (it ends in a
    # stop); a crawler speeding up goes on at the speed seen, which the speed after settles.
    # Distances a remount measured again in the window have the re-measure's shape; a refined
    # tilt's plain scale (is_rescale) is taken out of them, and the ramp is read
    v_back, a, sa = ramp(ts, ds, p.min_history_s)
    rate = ramp_rate(p, a, sa)
    again = remeasured_at is not None and remeasured_at >= h[0][0]
    if again or rate is None:
        return slope(ts, ds), 0.0, 0.0
    if a * v_back < 0:            # speeding up: the speed at t0, not the window's mean, which lags
        return -v_back, 0.0, 0.0, abs(rate)
    return -v_back, rate, sa


def speed_after(p, g, t1: float, samples: list, T: float, frame_var: float):
    """(the speed measured since the gap, the speed at the gap's end and the rate read there (0:
    none), and if it was measured too briefly to settle the gap on its own word: (its own sigma,
    the speed at the last sample, the rate it goes on at)), or (None, ...), from the (t, distance)
    samples measured since t1, each known within frame_var (m^2); T: the model's time over the gap.

    The speed after must have been measured for min_history_s: with no speed before it settles
    all of the gap alone, and the first frames seen again are the least sure (the wall half wet
    or half lit): one frame interval's reading, times a gap of seconds over it, is anything. With
    the speed before known, a briefer one still shows how the crawler moved between two gaps,
    within the frames' noise over its few samples (a brake and a reversal in the frames between
    three bursts of drops: -5.6 % where the gap was carried through them as one), unless it reads
    no motion: a wall half seen again shows the light and what stays put with it (a highlight, the
    mortar lines along the motion) more than the wall, which reads as standing; nor inside a stand
    the frames showed (their jitter is no motion). Its sigma: the frames' noise over the samples'
    spread in time, and a hard brake over half of them (a moment's mean is its middle's speed)."""
    span = samples[-1][0] - samples[0][0] if len(samples) >= 2 else 0.0
    if span < p.min_history_s - TIME_EPS:
        brief = None if g.v0 is None or g.open_at_close else brief_speed(samples, frame_var)
        if brief is None or abs(brief[0]) < p.brief_still_m_s:
            return None, None, 0.0, None
        v, sigma = brief              # (the speed at the samples' middle; still braking, at the brake's
        rate = g.a0 if braking(g) and 0.0 < v / g.v0 < 1.0 else 0.0      # rate either side of it)
        sigma = math.hypot(sigma, p.hard_accel_m_s2 * span / 2)         # (a hard brake over half of them)
        mid = sum(t for t, _ in samples) / len(samples)
        return v, v + rate * (t1 - mid), 0.0, (sigma, v + rate * (samples[-1][0] - mid), rate)
    v1 = v_end = slope([t for t, _ in samples], [d for _, d in samples])
    a1 = 0.0
    stopped = stops(g, T, v1, p.hard_accel_m_s2) is not None
    if len(samples) >= 5 and span >= 0.5 * p.history_s:
        # speeding up or slowing down since it was seen again: the speed at the gap's end, and
        # the rate (a crawler still speeding up started not long before). After a stop inside
        # the gap, a ramp too short for its rate is read at the braking's rate (the drive's)
        ts, ds = [t - t1 for t, _ in samples], [d for _, d in samples]
        v, a, sa = ramp(ts, ds, p.min_history_s)
        drive = math.copysign(g.a0, v1)       # the braking's rate, the way it moves after
        if (rate := ramp_rate(p, a, sa)) is not None:
            v_end, a1 = v, rate           # (a few frames' rate is rough: the drive's, if seen that way)
            seen = g.drive[0 if a * v > 0 else 1]
            if blurred(seen, rate) and (v := ramp_at(ts, ds, math.copysign(seen, a))) is not None:
                v_end, a1 = v, math.copysign(seen, a)
        elif stopped and (v := ramp_at(ts, ds, drive)) is not None:
            v_end, a1 = v, drive
        if stopped and v_end * v1 <= 0:       # a speed at t1 against the motion after: it stood then
            v_end, a1 = 0.0, 0.0
    return v1, v_end, a1, None


def before_a_hole(h: list, min_s: float) -> list:
    """The window's samples a speed and a rate are read from. A frame measured across lost frames
    and lost again within min_s (caught between two gaps, at the edge of what the camera can see)
    gives the distance, not the motion's shape: one such frame read 2.6 mm short at a wet stretch's
    edge was fitted as a brake, and the gap after it carried to a stop (a lobe run: -27.7 %). The
    samples before the hole give the shape, as a speed needs min_s of measuring after any gap."""
    ts = [t for t, _ in h]
    if len(ts) < 6:
        return h
    frame = sorted(b - a for a, b in zip(ts, ts[1:]))[(len(ts) - 1) // 2]     # the (upper) median interval
    k = max((i + 1 for i in range(len(ts) - 1) if ts[i + 1] - ts[i] > 1.5 * frame), default=0)
    return h[:k] if k >= 5 and ts[-1] - ts[k] < min_s - TIME_EPS else h
