"""Wheel odometry beside vision: an encoder port with three backends, and the fusion filter.

    settings = WheelSettings.from_dict(toml.get("wheel", {}), name=cfg.name)
    fusion = WheelFusion(settings.fusion_params())          # or WheelFusion.from_dict(saved, ...)
    with open_wheel(settings, clock=frame_clock) as wheel:
        for frame in frames:
            fused = fusion.update(vision_estimate, wheel.read())

docs/wheel.md describes wiring, the kernel overlay, the filter and its figures.
"""

from .fusion import FusedEstimate, FusionParams, SlipEvent, VisionFix, WheelFusion
from .port import NoWheel, WheelReading, WheelUnavailable, open_wheel
from .settings import BACKENDS, WheelSettings

__all__ = ["BACKENDS", "FusedEstimate", "FusionParams", "NoWheel", "SlipEvent", "VisionFix",
           "WheelFusion", "WheelReading", "WheelSettings", "WheelUnavailable", "open_wheel"]
