"""From the odometer's estimate to the distance a frame publishes: bridged gaps, then the wheel.

    odometer -> GapBridge (gaps.py: the motion model, sigma) -> WheelFusion (crawler/wheel: slip,
    the wheel through blind stretches) -> the published estimate

Without a wheel the fusion is skipped: `source` is `vision` while the camera measures and `model`
while the bridge carries the distance. With one, the fusion decides (`vision`, `fused`, `wheel`,
`model`) and flags slip. Pure: the wheel reading is handed in.
"""

from __future__ import annotations

import math
from dataclasses import replace

from .codec import CodecBias
from .gaps import GapBridge
from .wheel.fusion import VisionFix


class DistanceChain:
    """Per frame: the odometer's estimate (and the wheel's reading) in, the published estimate out."""

    def __init__(self, bridge: GapBridge | None = None, fusion=None, codec: CodecBias | None = None):
        self.bridge = bridge or GapBridge()
        self.fusion = fusion            # crawler.wheel.WheelFusion, or None without a wheel
        self.codec = codec or CodecBias(0.0)   # a compressed recording's systematic error (codec.py)
        self.last_event = None          # the latest slip event, for the status

    def update(self, est, wheel_reading=None, qp: float | None = None):
        """`qp`: the frame's mean quantiser when it comes from a compressed recording."""
        b = self.bridge.update(est)
        codec_m = self.codec.update(qp, est.keyframe and est.tracking and est.inliers > 0,
                                    est.texture_dn if est.tracking else None)
        scale_m = math.hypot(codec_m, est.scale_sigma_m)   # the codec's, the tilt's, the ride's: they scale steps
        out = replace(est, distance_m=b.distance_m, sigma_m=math.hypot(b.sigma_m, scale_m), bridged=b.bridged,
                      source="model" if b.bridged else "vision", gap_s=b.gap_s)
        if self.fusion is None:
            return out
        # the fusion weighs each frame's own noise; what carries on (closed keyframe steps) is the bridge's
        # (a step across a gap, not checked yet, is the wheel's to carry: an alias across dropped frames,
        # refused once the speed after is known, had read as a slip)
        fused = self.fusion.update(VisionFix(est.t_s, b.distance_m, b.step_sigma_m, est.tracking, b.bridged,
                                             b.corrected_m, b.across), wheel_reading)
        if fused.event is not None:
            self.last_event = fused.event
        speed = est.speed_m_s
        if speed is None and fused.source == "wheel" and math.isfinite(fused.speed_m_s):
            speed = fused.speed_m_s            # the camera is blind: the wheel's speed is the one there is
        return replace(out, distance_m=fused.distance_m,
                       sigma_m=math.hypot(self.bridge.sigma_meas_m, fused.sigma_m, scale_m),
                       source=fused.source, slip=fused.slip, wheel_distance_m=fused.wheel_distance_m,
                       wheel_scale=fused.wheel_scale, speed_m_s=speed)

    def set_distance(self, distance_m: float, vision_m: float):
        """The operator's reset: the published distance is distance_m, the odometer's vision_m."""
        self.bridge.reset(distance_m, vision_m)
        if self.fusion is not None:
            self.fusion.set_distance(distance_m, vision_m=vision_m)

    def state(self) -> dict:
        out = {"sigma_m": math.hypot(self.bridge.sigma_m, self.codec.sigma_m),   # a restart carries both
               "drive": self.bridge.drive.to_dict()}                              # ...and the drive's rates
        if self.fusion is not None:
            out["wheel"] = self.fusion.to_dict()
        return out

