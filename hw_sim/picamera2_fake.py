"""A fake of picamera2's Picamera2 that films hw_sim's pipe wall, paced in real time.

crawlerd drives the Pi camera through picamera2 (crawler/camera.py). This class copies picamera2's
API (names, signatures, config dicts, errors, array shapes, metadata units) and the real sensor-mode
tables of the OV5647, IMX219 and IMX708, and renders each frame with hw_sim's Simulator through the
sensor mode, ScalerCrop and output size in force, so the chain plan -> intrinsics -> odometry is
checked end to end against ground truth. Frame k has SensorTimestamp start + k * frame duration on
the world's clock (wall time by default), whatever the consumer does; like the real camera, a
consumer that falls behind gets the newest completed frame and the others are dropped, with at most
buffer_count buffers in use.

    world = SimWorld("imx219", tilt_deg=20, speed_m_s=0.2)     # any SimConfig field
    Picamera2 = make_picamera2(world)        # the class crawlerd injects; called as Picamera2(0)
    world.true_distance_m(request.get_metadata()["SensorTimestamp"])    # 0 at the first frame

On the wall clock a camera thread renders each frame (and the texture tiles ahead) before it
completes, as the ISP fills buffers, so a frame costs its consumer nothing; on an injected clock
(ManualClock) frames are rendered on demand, deterministically. Simplifications (docs/simulator.md):
no sensor flips, lores is main resized, raw buffers are zeros, controls act from the next frame to
start, captures are blocking only. The parts live in hw_sim/fake/; this module re-exports them.
"""
from .fake.camera import FakePicamera2, make_picamera2
from .fake.configs import AF_CONTROLS, CONTROLS, NR_FAST, NR_HIGH_QUALITY, NR_MINIMAL, RGB_BYTES, YUV_FORMATS
from .fake.crop import default_isp_crop, isp_crop, native_crop
from .fake.request import CompletedRequest, MappedArray
from .fake.sensors import (EXPOSURE_MIN_LINES, FRAME_LINES_MAX, ISP_MIN_CROP, REF_EXPOSURE, SENSORS, SensorFormat,
                           SensorMode, SensorSpec, Transform)
from .fake.world import ManualClock, SimWorld

__all__ = ["AF_CONTROLS", "CONTROLS", "EXPOSURE_MIN_LINES", "FRAME_LINES_MAX", "ISP_MIN_CROP", "NR_FAST",
           "NR_HIGH_QUALITY", "NR_MINIMAL", "REF_EXPOSURE", "RGB_BYTES", "SENSORS", "YUV_FORMATS",
           "CompletedRequest", "FakePicamera2", "ManualClock", "MappedArray", "SensorFormat", "SensorMode",
           "SensorSpec", "SimWorld", "Transform", "default_isp_crop", "isp_crop", "make_picamera2", "native_crop"]
