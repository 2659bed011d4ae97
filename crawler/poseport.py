"""What the odometer asks of a camera pose estimate (crawler/pose.py): the fix it applies to a frame,
and the estimate of a camera whose mount is what the configuration says. Pure: no I/O."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class PoseFix:
    """What the odometer applies to a frame: metres added to its step and lateral step, to the
    keyframe's distance (earlier steps measured again), and the projection to move to."""

    step_m: float = 0.0
    lat_m: float = 0.0
    base_m: float = 0.0
    remount: object = None
    rescaled_m: float = 0.0    # of base_m, what a changed tilt gave (the rest: the keyframe's pose refined),
    rescaled_over_m: float = 0.0   # over this many metres of steps (the tilt's epoch), measured since
    rescaled_since_s: float | None = None


NO_FIX = PoseFix()


class NullPose:
    """The odometer without a pose estimate: the mount is what the configuration says."""

    active = False
    pitch_shown_rad = 0.0     # the car's pitch the tracks show: none read
    scale_sigma_m = 0.0

    def __init__(self, tilt_deg: float | None = None):
        self.tilt_deg = tilt_deg

    def keyframe(self, kf, px, t_s):
        pass

    def new_count(self, delta_m: float = 0.0):
        pass

    def measure(self, kf, c, t_s) -> PoseFix:
        return NO_FIX

    def status(self) -> dict:
        return {"tilt_deg": self.tilt_deg, "tilt_sigma_deg": None, "tilt_auto": False}

    def frame(self) -> dict:
        return {}

    def checkpoint(self) -> dict:
        return {}

    def resume(self, saved) -> None:
        return None
