"""Fits of a crawler's motion to a few dozen measured distances, for the gap bridge (gaps.py). Pure.

A crawler's drive ramps at a constant rate and then cruises: `ramp` fits that, with where the ramp
ends found by least squares, and says how sure its rate is; `slope` is the plain speed, and
`brief_speed` the speed of a few frames with its error.
"""

from __future__ import annotations

import math

import numpy as np


MAX_RESCALE = 0.01     # a re-measure up to this share of its metres is a plain scale (is_rescale)
TIME_EPS = 1e-6        # frame times are sums of intervals: 3 / 30 s may come out under 0.1 s


def slope(ts, ds) -> float | None:
    """Least-squares speed of distances ds at times ts (None: fewer than two times)."""
    n = len(ts)
    if n < 2:
        return None
    mt, md = sum(ts) / n, sum(ds) / n
    den = sum((t - mt) ** 2 for t in ts)
    return None if den <= 0 else sum((t - mt) * (d - md) for t, d in zip(ts, ds)) / den


def brief_speed(samples, frame_var: float) -> tuple[float, float] | None:
    """(speed, its 1-sigma error) of (t, distance) samples measured too briefly for a gap's speed
    after (a few frames between two gaps): least squares, each distance known within frame_var
    (m^2: the frame's jitter and the car's pitch, which over a few frames is no straight line).
    None: fewer than two times."""
    ts = [t for t, _ in samples]
    v = slope(ts, [d for _, d in samples])
    if v is None:
        return None
    mt = sum(ts) / len(ts)
    return v, math.sqrt(frame_var / sum((t - mt) ** 2 for t in ts))


def ramp(ts, ds, min_s: float) -> tuple[float, float, float]:
    """(speed at t = 0, acceleration, its 1-sigma error) of a crawler that changes speed at a
    constant rate from t = 0 and then, perhaps, holds the speed it reached (its drive ramps, then
    cruises): least squares over where the ramp ends, min_s at least from t = 0 (once per gap: a
    few dozen points)."""
    t, d = np.abs(np.asarray(ts, float)), np.asarray(ds, float)
    best = None
    inner = np.sort(t)[4:-1]                     # five frames and min_s at least: a shorter ramp is noise's
    inner = inner[inner >= min_s]
    ends = inner[np.linspace(0, len(inner) - 1, min(len(inner), 12)).astype(int)] if len(inner) else inner
    for end in list(ends) + [None]:              # None: changing speed all along (a plain quadratic)
        shape = 0.5 * t * t if end is None else np.where(t < end, 0.5 * t * t, end * t - 0.5 * end * end)
        A = np.column_stack([np.ones_like(t), t, shape])
        coef, *_ = np.linalg.lstsq(A, d, rcond=None)
        rss = float(np.sum((A.dot(coef) - d) ** 2))
        if best is None or rss < best[0]:
            best = (rss, A, coef)
    rss, A, coef = best
    dof = len(t) - 3
    try:
        var_a = rss / dof * float(np.linalg.inv(A.T.dot(A))[2, 2]) if dof > 0 else np.inf
    except np.linalg.LinAlgError:
        var_a = np.inf
    return float(coef[1]), float(coef[2]), math.sqrt(max(var_a, 0.0))


def ramp_at(ts, ds, rate: float, k: float = 3.0, floor_m: float = 2e-5) -> float | None:
    """Speed at t = 0 of a crawler still speeding up at a known rate (its drive's, signed), from
    before t = 0 until it cruises, when the distances show that ramp k sigma clear of a plain cruise
    (a start seen late, the ramp too short for `ramp` to read its rate); else None. Least squares
    over where the ramp ends; floor_m: the distances are never known better than this."""
    t, d = np.asarray(ts, float), np.asarray(ds, float)
    if len(t) < 5 or not rate:
        return None
    A = np.column_stack([np.ones_like(t), t])

    def fit(y):
        coef, *_ = np.linalg.lstsq(A, y, rcond=None)
        return float(np.sum((A.dot(coef) - y) ** 2)), float(coef[1])

    cruise, _ = fit(d)
    best = None
    for end in np.linspace(t.min(), t.max(), 25)[1:]:      # d = c + v t - rate (end t - t^2 / 2) to the end
        lag = np.where(t < end, end * t - 0.5 * t * t, 0.5 * end * end)
        rss, v = fit(d + rate * lag)
        if best is None or rss < best[0]:
            best = (rss, v - rate * end)
    rss, v0 = best
    noise = max(rss, len(t) * floor_m * floor_m) / max(len(t) - 3, 1)
    return v0 if cruise - rss > k * k * noise else None


def remeasured(samples: list, gain_m: float, over_m: float = 0.0, as_scale: bool = False,
               upto_m: float | None = None):
    """The odometer measured its steps again (a better tilt): (time, distance) samples a speed is
    read from (the speed filter's window, the speed after a gap) gain it too, in proportion to the
    distance each had covered (a scale error), so that the correction is not read as speed.
    over_m: the signed metres the gain was spread over, as they are after it (tilt auto's epoch,
    crawler/autotilt.py),
    so the newest sample gains all of it and one over_m before none; unknown (0), or a re-measure
    too large for a plain scale (`is_rescale`), the samples' own span; `as_scale`: a plain scale
    however large (samples the re-measure is known to have scaled as a whole). upto_m: the
    distance, before the re-measure, the gain is all of (the frame that brought it, not yet among
    the samples); else the newest sample's."""
    if not gain_m or len(samples) < 2:
        return samples
    d_last = samples[-1][1] if upto_m is None else upto_m
    if is_rescale(gain_m, over_m) or (as_scale and over_m):
        eps = gain_m / (over_m - gain_m)        # over_m is after the re-measure, the samples before it
        samples[:] = [(t, d + gain_m - eps * (d_last - d)) for t, d in samples]
    elif d_last != samples[0][1]:
        d0, span = samples[0][1], d_last - samples[0][1]
        samples[:] = [(t, d + gain_m * (d - d0) / span) for t, d in samples]
    return samples


def is_rescale(gain_m: float, over_m: float) -> bool:
    """A re-measure that only scales what was measured: a refined tilt moves the metres by a
    fraction of a percent. A larger one (the search's first find, a remount after a camera turn,
    whose steps lose their pose) changes the motion's shape, and no ramp is read across it."""
    return over_m != 0.0 and abs(gain_m) <= MAX_RESCALE * abs(over_m)



def reach(v0: float, v1: float, T: float, a: float) -> tuple[float, float] | None:
    """The least and the most a crawler travels in T going from speed v0 to v1 when its speed
    changes at most a per second (slowing down first, then speeding up; and the other way round).
    None: no such crawler gets from v0 to v1 in T."""
    k = (v1 - v0) / a
    if abs(k) > T * (1 + 1e-9):
        return None
    k = max(-T, min(T, k))                       # (a rate of |v1 - v0| / T itself, rounded)
    up, down = (T + k) / 2, (T - k) / 2          # the time speeding up first (the most), slowing first (the least)
    top, low = v0 + a * up, v0 - a * down
    return (0.5 * (v0 + low) * down + 0.5 * (low + v1) * (T - down),
            0.5 * (v0 + top) * up + 0.5 * (top + v1) * (T - up))


def could_go(step: float, v0: float, v1: float, T: float, a: float, speed_error: float) -> bool:
    """Could a crawler go `step` in T from speed v0 to v1, changing speed at up to a (each speed
    known within speed_error)? Speeds too far apart for a are first brought speed_error closer each,
    and if still, joined by the one ramp between them (a reversal at 1.2 m/s^2 against a = 1.0:
    any step had passed, an alias kept at 227 sigma)."""
    span = reach(v0, v1, T, a)
    if span is None:
        give = math.copysign(speed_error, v1 - v0)
        v0, v1 = v0 + give, v1 - give
        span = reach(v0, v1, T, max(a, abs(v1 - v0) / T))
    slack = speed_error * T
    return span[0] - slack <= step <= span[1] + slack


def ramp_rate(p, a: float, sa: float) -> float | None:
    """A fitted rate, clipped to p.max_accel_m_s2; None if lost in its fit's noise or beyond a
    drive's reach (a jump in the distances, not a ramp)."""
    if not max(p.min_accel_m_s2, 3 * sa) <= abs(a) <= 1.5 * p.max_accel_m_s2:
        return None
    return max(-p.max_accel_m_s2, min(p.max_accel_m_s2, a))
