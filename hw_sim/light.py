"""How much of the LEDs' light a row collects: 1 when lit, decaying to 0 in a blackout.

During a blackout a..b the LEDs' light falls as exp(-(t - a)/tau) (the last of the LED and its
driver) and is back at once at b. A row exposed over [t - e/2, t + e/2] collects the mean of that
over its exposure, in closed form, so a blackout edge crosses a rolling-shutter frame smoothly.
"""
from __future__ import annotations

import numpy as np


def led_light(t_rows, exposure_s: float, blackouts: tuple[tuple[float, float], ...], decay_s: float):
    """Mean LED light (0..1) over each row's exposure; t_rows are the rows' mid-exposure times."""
    t = np.asarray(t_rows, np.float64)
    if not blackouts:
        return np.ones_like(t)
    e = max(exposure_s, 1e-9)
    t0, t1 = t - e / 2, t + e / 2
    dark = np.zeros_like(t)                 # light missing, integrated over the exposure
    for a, b in blackouts:
        s0, s1 = np.clip(t0, a, b), np.clip(t1, a, b)
        lit = decay_s * (np.exp(-(s0 - a) / decay_s) - np.exp(-(s1 - a) / decay_s)) if decay_s > 0 else 0.0
        dark += (s1 - s0) - lit
    return np.clip(1.0 - dark / e, 0.0, 1.0)
