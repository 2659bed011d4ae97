"""The camera contract, run on hw_sim's fake always and on the real CSI camera with CRAWLERD_HW=1.

On the crawler: `CRAWLERD_HW=1 pytest tests/hw` checks that the camera delivers what the odometry's
geometry assumes (the planned crop, the output size, monotonic sensor times at the planned rate).
"""

import os

import numpy as np
import pytest

from crawler.camera import Picamera2Source, import_picamera2
from crawler.settings import CameraSettings


def fake_classes():
    from hw_sim.picamera2_fake import MappedArray, SimWorld, make_picamera2

    return make_picamera2(SimWorld("imx219", speed_m_s=0.2)), MappedArray


def real_classes():
    if os.environ.get("CRAWLERD_HW") != "1":
        pytest.skip("real camera: set CRAWLERD_HW=1 on the crawler to run")
    return import_picamera2()


@pytest.mark.parametrize("classes", [fake_classes, real_classes], ids=["fake", "csi"])
def test_camera_delivers_the_planned_window(classes):
    camera_class, mapped_array = classes()
    src = Picamera2Source(CameraSettings(output_size=(240, 240), fps=60.0, exposure_us=1500), camera_class,
                          mapped_array=mapped_array)
    with src:
        plan = src.plan
        frames = []
        for frame in src.frames():
            frames.append((frame.t_s, frame.gray.shape, float(np.mean(frame.gray))))   # before release
            if len(frames) == 30:
                break
        md_crop = None
        request = src.cam.capture_request(wait=2.0)
        try:
            md_crop = tuple(request.get_metadata()["ScalerCrop"])
        finally:
            request.release()
    times = np.array([t for t, _, _ in frames])
    assert all(shape == (240, 240) for _, shape, _ in frames)
    assert np.all(np.diff(times) > 0)
    assert np.median(np.diff(times)) == pytest.approx(1 / plan.fps, rel=0.05)
    assert md_crop == tuple(plan.scaler_crop)
    assert 5 < np.mean([m for _, _, m in frames]) < 250          # neither black nor saturated
