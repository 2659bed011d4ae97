"""The sensor-window arithmetic against the real cameras' sensor modes (OV5647, IMX219, IMX708).

The mode tables come from hw_sim's Picamera2 fake, which copies what picamera2 reports on Raspberry
Pi OS (docs/simulator.md); the line times are the kernel drivers' (line length / pixel rate).
"""

import math

import numpy as np
import pytest

from crawler.camera import SENSOR_FOV_DEG, plan_window, snap_to_mode, vblank_lines
from crawler.errors import BadConfig
from crawler.geometry import Camera
from crawler.settings import CameraSettings
from hw_sim.picamera2_fake import SimWorld, make_picamera2

LINE_US = {"ov5647": 33.673, "imx219": 18.904, "imx708": 9.209}     # of the modes chosen below


def sensor(name):
    cam = make_picamera2(SimWorld(name))(0)
    try:
        return cam.sensor_modes, tuple(cam.camera_properties["PixelArrayActiveAreas"][0][2:])
    finally:
        cam.close()


def plan(name, window=None, size=(240, 240), fps=200.0, vflip=False):
    modes, active = sensor(name)
    return plan_window(modes, active, window, size, fps, SENSOR_FOV_DEG[name],
                       lambda mode_size: vblank_lines(name, mode_size), vflip=vflip), active


@pytest.mark.parametrize("name,mode,fps,crop,mode_rows", [
    ("ov5647", (640, 480), 58.92, (816, 960, 960, 960), 240),     # 4:1 binned+skipped VGA
    ("imx219", (640, 480), 103.33, (1400, 1232, 480, 480), 240),  # 2x2 binned centre crop
    ("imx708", (1536, 864), 120.13, (1872, 1296, 864, 864), 432),  # 2x2 binned
])
def test_default_window_takes_the_fastest_mode_that_covers_it(name, mode, fps, crop, mode_rows):
    p, active = plan(name)
    assert tuple(p.mode["size"]) == mode and p.fps == pytest.approx(fps, abs=0.01)
    assert p.scaler_crop == crop
    x, y, w, h = crop
    assert y <= active[1] // 2 < y + h or y >= active[1] // 2 - 16      # at or just around the centre row
    # readout of the window: its rows in the mode, one line time each
    assert p.camera.readout_s * 1e3 == pytest.approx((mode_rows - 1) * LINE_US[name] / 1e3, rel=2e-3)


def test_window_intrinsics_are_the_sensors_seen_through_the_crop():
    p, (aw, ah) = plan("imx219")
    full = Camera.from_fov(aw, ah, 48.8, 62.2)
    x, y, w, h = p.scaler_crop
    out = np.array([[0.0, 0.0], [239.0, 239.0], [120.0, 30.0]])
    native = np.column_stack([x + (out[:, 0] + 0.5) * w / 240 - 0.5, y + (out[:, 1] + 0.5) * h / 240 - 0.5])
    assert np.allclose(p.camera.normalise(out), full.normalise(native), atol=1e-12)
    assert p.camera.fy == pytest.approx(full.fy * 240 / h)


def test_windows_snap_to_the_mode_grid_as_libcamera_applies_them():
    modes, _ = sensor("ov5647")
    vga = next(m for m in modes if tuple(m["size"]) == (640, 480))
    assert snap_to_mode((802, 502, 1003, 751), vga) == (800, 500, 1000, 748)
    p, _ = plan("ov5647", window=(802, 502, 1003, 751), size=(250, 186))
    assert p.scaler_crop == (800, 500, 1000, 748)


def test_fps_is_capped_by_the_mode_and_a_wide_window_needs_a_slower_mode():
    p, _ = plan("imx219", fps=60.0)
    assert p.fps == 60.0 and p.frame_duration_us == 16667
    p, _ = plan("imx219", window=(640, 1232, 2000, 1000), size=(400, 200))   # wider than the VGA crop
    assert tuple(p.mode["size"]) == (1640, 1232) and p.fps == pytest.approx(41.85, abs=0.01)


def test_upside_down_camera_looks_above_the_centre_in_sensor_rows():
    p, (_, ah) = plan("imx219", vflip=True)
    x, y, w, h = p.scaler_crop
    assert y + h <= ah // 2 + 2 and p.camera.vflip


def test_impossible_windows_name_the_value():
    with pytest.raises(BadConfig, match=r"sensor_window = \[3000, 2000, 900, 900\]"):
        plan("imx219", window=(3000, 2000, 900, 900))
    with pytest.raises(BadConfig, match="output_size"):
        plan("ov5647", size=(2048, 2048))
    with pytest.raises(BadConfig, match=r"\[camera\] fps = 0 must be between 0 and 1000"):
        CameraSettings(fps=0)                     # validated once, in the settings
    assert math.isfinite(plan("imx708")[0].camera.readout_s)


def test_imx708_blanking_is_per_mode():
    """The IMX708 driver blanks 58 lines at full resolution and 40 in its binned modes: the line
    time (and so the rolling-shutter readout) of each mode follows its own."""
    assert vblank_lines("imx708", (4608, 2592)) == 58 and vblank_lines("imx708_wide", (2304, 1296)) == 40
    assert vblank_lines("ov5647", (640, 480)) == 24 and vblank_lines("unknown", (1, 1)) == 0
    modes, active = sensor("imx708")
    full = next(m for m in modes if tuple(m["size"]) == (4608, 2592))
    p = plan_window([full], active, None, (240, 240), 10.0, SENSOR_FOV_DEG["imx708"],
                    lambda size: vblank_lines("imx708", size))
    # the fake's driver table: line = HTS / pixel rate = 15648 / 595.2 MHz
    assert p.line_time_s * 1e6 == pytest.approx(15648 / 595.2, rel=2e-3)
