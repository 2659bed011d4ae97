"""Fits of a crawler's motion to a few dozen measured distances, for the gap bridge (gaps.py). Pure.

A crawler's drive ramps at a constant rate and then cruises: `ramp` fits that, with where the ramp
ends found by least squares, and says how sure its rate is; `slope` is the plain speed.
"""

from __future__ import annotations

import math

import numpy as np


def slope(ts, ds) -> float | None:
    """Least-squares speed of distances ds at times ts (None: fewer than two times)."""
    n = len(ts)
    if n < 2:
        return None
    mt, md = sum(ts) / n, sum(ds) / n
    den = sum((t - mt) ** 2 for t in ts)
    return None if den <= 0 else sum((t - mt) * (d - md) for t, d in zip(ts, ds)) / den


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
