"""One frame's result, as the odometer gives it and the distance chain completes it."""

from __future__ import annotations

import math
from dataclasses import dataclass


def finite_round(v: float | None, digits: int) -> float | None:
    """A published number: rounded, or None where it is missing or not finite (a filter that
    diverged says nothing rather than NaN)."""
    return None if v is None or not math.isfinite(v) else round(float(v), digits)


@dataclass
class Estimate:
    """One frame's result. Distances are metres since the run start; quality in [0, 1]."""

    frame: int
    t_s: float
    distance_m: float
    speed_m_s: float | None
    lateral_m: float
    roll_deg: float | None
    tracking: bool
    quality: float
    tracks: int
    inliers: int
    spread_mm: float | None
    keyframe: bool
    continuous: bool = True           # False: a fresh start, the motion since the last tracked frame unknown
    rescaled_m: float = 0.0           # of distance_m, metres earlier steps gained when measured again at a
                                      # new tilt (crawler/autotilt.py): not motion of this frame
    rescaled_over_m: float = 0.0      # ...spread over this many metres of steps before it (0: unknown)...
    rescaled_since_s: float | None = None   # ...measured since then (a gap bridged after it scales with them)
    since: tuple | None = None        # a fresh start whose motion is known from an earlier frame on (a dense
                                      # shift confirmed over several): that frame's (t_s, distance_m)
    scale_sigma_m: float = 0.0        # of distance_m, the 1 sigma a tilt (tilt auto) or a ride height
                                      # (crawler/ride.py) not known exactly leaves in the steps
    texture_dn: float | None = None   # the frame's fine texture (flow.texture_energy): a faint wall loses
                                      # more to a video encoder (crawler/codec.py)
    pitch_m: float = 0.0              # the car's pitch the tracks show, as wall metres (crawler/pose.py): what
                                      # it moves a frame's distance by, when the estimate cannot follow it
    stand: tuple | None = None        # blind on a faint wall whose frames show a stand: (since, until) (stands.py)
    changed: bool = False             # blind as the lit picture changed (tracks gone, texture faded): a
                                      # standing crawler's does not (a gap opening so is a set-off, gaps.py)
    # filled in after the odometer (crawler/distance.py): the published distance's uncertainty and origin
    sigma_m: float | None = None
    bridged: bool = False
    source: str = "vision"
    slip: bool = False
    wheel_distance_m: float | None = None
    wheel_scale: float | None = None
    gap_s: float = 0.0

    def as_dict(self) -> dict:
        d = dict(self.__dict__)
        for k in ("rescaled_m", "rescaled_over_m", "rescaled_since_s", "since", "scale_sigma_m", "texture_dn", "pitch_m", "stand",
                  "changed"):
            del d[k]                  # internal: sigma_m holds what they say
        for k in ("distance_m", "lateral_m"):
            d[k] = round(d[k], 6)
        for k in ("speed_m_s", "roll_deg", "spread_mm", "sigma_m", "wheel_distance_m", "wheel_scale"):
            d[k] = finite_round(d[k], 6)
        d["gap_s"] = round(d["gap_s"], 4)
        d["t_s"] = round(d["t_s"], 6)
        d["quality"] = round(d["quality"], 3)
        return d
