"""The camera's true pose over time: nominal mount, tilt schedule, height profile, disturbances.

Pure functions of t (and of the car's position along the pipe for the height profile), shared by
the Simulator (to render) and the fake's SimWorld (to report ground truth).
"""
from __future__ import annotations

import math

import numpy as np

from .config import SimConfig
from .motion import Motion, jitter, sine


def keyframes(x, keys: tuple[tuple[float, float], ...], default: float) -> np.ndarray:
    """Piecewise-linear through (key, value) pairs, held before the first and after the last."""
    if not keys:
        return np.full(np.shape(x), default, np.float64)
    k, v = zip(*keys)
    return np.interp(x, k, v)


class PoseModel:
    """tilt, H (camera-to-crown), sway, roll of one SimConfig's camera at time t."""

    def __init__(self, cfg: SimConfig, motion: Motion):
        self.cfg, self.motion = cfg, motion
        self.H0 = cfg.H_m
        # anything that moves the camera in the pipe: the renderer then casts its rays every frame
        self.moves = bool(cfg.bounce_mm > 0 or cfg.pitch_jitter_deg > 0 or cfg.sway_mm > 0
                          or cfg.tilt_schedule or cfg.height_profile)

    def tilt_deg(self, t):
        """True tilt: the schedule (or tilt_deg), plus pitch jitter."""
        c = self.cfg
        return keyframes(t, c.tilt_schedule, c.tilt_deg) + jitter(t, c.pitch_jitter_deg, c.pitch_jitter_hz, c.seed, 1)

    def camera_height_m(self, t):
        """True H: nominal, less the height profile at the car's position, plus bounce."""
        c = self.cfg
        y_car = c.start_m + self.motion.distance(t)
        extra = keyframes(y_car, c.height_profile, 0.0)
        return self.H0 - extra / 1000.0 + sine(t, c.bounce_mm, c.bounce_hz) / 1000.0

    def at(self, t_s: float) -> dict[str, float]:
        """Camera pose at t: tilt (rad), H (m), sway x (m), roll (rad)."""
        c = self.cfg
        return {
            "tilt": math.radians(float(self.tilt_deg(t_s))),
            "H": float(self.camera_height_m(t_s)),
            "sway": float(sine(t_s, c.sway_mm, c.sway_hz, 1.0)) / 1000.0,
            "roll": math.radians(float(sine(t_s, c.roll_deg, c.roll_hz))),
        }
