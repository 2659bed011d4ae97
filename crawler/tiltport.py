"""What the pose estimator asks of the camera's tilt (crawler/pose.py): the configured tilt, which
never moves (FixedTilt; crawler/autotilt.py's AutoTilt estimates it), and a closed keyframe step kept
to be measured again at a better tilt (Hop). Pure: no I/O."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .posefield import JacobianField


@dataclass
class Hop:
    """A closed keyframe step of the epoch, kept to be measured again at a better tilt."""

    t_s: float
    projection: object
    xy_k: np.ndarray
    xy_c: np.ndarray
    dy: np.ndarray           # per-feature axial displacement the odometer measured
    pose: tuple              # (pitch, height, keyframe pitch, keyframe height) used
    d: float                 # the step as it stands in the distance now
    g: float                 # d step / d tilt
    scale: float = 0.0       # the ride height's scale of the step (crawler/ride.py): kept when measured again
    turn: float = 0.0        # a sweep's keyframe tilt less the frame's (in pose's keyframe pitch too)
    kf_t_s: float = -1.0     # when its keyframe was taken (the step before closed then)


class FixedTilt:
    """The configured tilt: the mount never moves."""

    auto = False
    tau = 0.0
    level_m = 0.0             # the ride height's level the readings are taken at (AutoTilt)
    sigma_rad = 0.0
    distance_sigma_m = 0.0    # what the tilt's uncertainty leaves in the distance: none, configured
    steps = 0

    def __init__(self, camera, projection, roi):
        self.projection = projection
        self.field = JacobianField(camera, projection, roi)

    def update(self, serial, xy_k, xy_c, moved_px, t_s, shutter=None) -> float:
        return 0.0

    def record(self, hop: Hop):
        pass

    def new_count(self):
        pass

    def closed(self, continuous: bool, t_s: float):
        pass

    def remount(self):
        return None, 0.0

    def keyframe_offset(self, since_kf_s: float) -> float:
        return 0.0

    def checkpoint(self) -> dict:         # what a restarted daemon starts from: nothing, configured
        return {}

    def resume(self, saved: dict):
        return None

    turning = False           # a sweep under way (AutoTilt)
