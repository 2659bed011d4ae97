import json
import math

import numpy as np
import pytest

from crawler.calibration import load_calibration
from crawler.errors import BadGeometry
from crawler.geometry import (Camera, Mount, PlaneProjection, camera_height, check_view,
                              make_projection)

THESIS = dict(pipe_diameter_m=0.30, car_width_m=0.151, camera_offset_m=0.054)


def thesis_camera(**kw):
    return Camera.from_fov(960, 720, 37.16, 53.50, **kw)


def test_camera_height_matches_thesis_eq_3_4():
    # thesis section 4.2: "Camera height relative to the surface (calculated) = 22.56cm"
    assert camera_height(0.30, 0.151, 0.054) == pytest.approx(0.2256, abs=5e-5)
    # by hand: 0.15 + sqrt(4*0.15^2 - 0.151^2)/2 - 0.054
    assert camera_height(0.30, 0.151, 0.054) == pytest.approx(0.15 + math.sqrt(0.09 - 0.022801) / 2 - 0.054)


def test_metres_per_pixel_matches_eq_3_1():
    cam = thesis_camera()
    h = camera_height(**THESIS)
    eq31 = 2 * h * math.tan(math.radians(37.16 / 2)) / 720     # thesis Eq. 3.1
    assert eq31 == pytest.approx(0.2107e-3, rel=1e-3)            # "0.3 mm/pixel" was at lower resolution
    pixel = make_projection("pixel", Mount(0.15, h, 0.0))
    a, b = pixel.to_wall(cam.normalise([[480, 400], [480, 401]]))
    assert abs(a[1] - b[1]) == pytest.approx(eq31, rel=1e-9)


def test_plane_matches_thesis_eq_3_2_and_3_3():
    cam = thesis_camera()
    h, tilt = 0.2256, 40.0
    plane = make_projection("plane", Mount(0.15, h, math.radians(tilt)))
    for v in (360.0, 500.0, 719.0):
        p_rel = (v - cam.cy) / (cam.height / 2)                        # p'/p
        beta = math.atan(p_rel * math.tan(math.radians(37.16 / 2)))    # Eq. 3.2
        alpha = math.radians(90 - tilt)                                # camera angle to the wall
        y = h / math.tan(alpha + beta)                                 # Eq. 3.3
        got = plane.to_wall(cam.normalise([[cam.cx, v]]))[0, 1]
        assert got == pytest.approx(y, rel=1e-9)


@pytest.mark.parametrize("method", ["pixel", "plane", "cylinder"])
@pytest.mark.parametrize("tilt", [0.0, 24.0, 40.0])
@pytest.mark.parametrize("distortion", [(), (-0.2, 0.05, 0.001, -0.001, 0.0)])
def test_image_wall_image_round_trip(method, tilt, distortion):
    cam = thesis_camera(distortion=distortion, vflip=tilt == 24.0)
    proj = make_projection(method, Mount.from_car(**THESIS, tilt_deg=tilt))
    u, v = np.meshgrid(np.linspace(300, 659, 7), np.linspace(360, 719, 7))
    px = np.column_stack([u.ravel(), v.ravel()])
    wall = proj.to_wall(cam.normalise(px))
    assert np.all(np.isfinite(wall))
    back = cam.to_pixels(proj.to_image(wall))
    assert np.abs(back - px).max() < 1e-6


def test_plane_equals_pixel_at_zero_tilt_and_cylinder_agrees_on_the_crown_line():
    cam, mount = thesis_camera(), Mount.from_car(**THESIS)
    xy = cam.normalise(np.column_stack([np.full(5, cam.cx), np.linspace(360, 719, 5)]))
    pix, plane, cyl = (make_projection(m, mount).to_wall(xy) for m in ("pixel", "plane", "cylinder"))
    assert np.allclose(pix, plane, atol=1e-12)
    assert np.allclose(cyl[:, 1], plane[:, 1], atol=1e-12)    # the crown line lies on both surfaces
    # off the crown line the real wall curves down toward the camera: less wall per pixel across
    side = cam.normalise([[659.0, 500.0]])
    assert 0 < make_projection("cylinder", mount).to_wall(side)[0, 0] < PlaneProjection(mount).to_wall(side)[0, 0]


def test_cylinder_hits_the_real_wall():
    mount = Mount.from_car(**THESIS, tilt_deg=30)
    proj = make_projection("cylinder", mount)
    xy = np.array([[0.3, 0.2], [-0.25, -0.1], [0.0, 0.0]])
    s, y = proj.to_wall(xy).T
    d = mount.ray(xy)
    r, zc = mount.pipe_radius_m, mount.pipe_radius_m - mount.height_m
    t = y / d[:, 1]
    x, z = t * d[:, 0], zc + t * d[:, 2]
    assert np.allclose(x ** 2 + z ** 2, r ** 2)
    assert np.allclose(r * np.arctan2(-x, z), s)


def test_window_intrinsics_see_the_same_rays():
    full = Camera.from_fov(3280, 2464, 48.8, 62.2)
    win = full.window(1000, 1200, 960, 720, 480, 360)    # 2x downscaled sensor crop
    out = np.array([[0.0, 0.0], [479.0, 359.0], [240.0, 100.0]])
    sensor = np.column_stack([1000 + (out[:, 0] + 0.5) * 2 - 0.5, 1200 + (out[:, 1] + 0.5) * 2 - 0.5])
    assert np.allclose(win.normalise(out), full.normalise(sensor), atol=1e-12)


def test_calibration_json(tmp_path):
    path = tmp_path / "cam.json"
    path.write_text(json.dumps({"camera_matrix": [[900, 0, 470], [0, 905, 350], [0, 0, 1]],
                                "dist_coeffs": [-0.1, 0.01, 0, 0, 0], "image_size": [960, 720]}))
    cam = load_calibration(path)
    assert (cam.fx, cam.fy, cam.cx, cam.cy, cam.width) == (900, 905, 470, 350, 960)
    assert cam.distortion[0] == -0.1


def test_impossible_geometry_is_refused_with_the_value_named():
    with pytest.raises(BadGeometry, match="car_width_m = 0.31"):
        camera_height(0.30, 0.31, 0.05)
    with pytest.raises(BadGeometry, match="camera_offset_m = 0.5"):
        camera_height(0.30, 0.151, 0.5)
    with pytest.raises(BadGeometry, match="height_m = 0.4"):
        Mount.from_height(0.30, 0.4)
    cam = thesis_camera()
    roi = (0, 0, 960, 720)
    with pytest.raises(BadGeometry, match="above the horizon"):
        check_view(cam, make_projection("plane", Mount(0.15, 0.2256, math.radians(80))), roi, 89.0)
    with pytest.raises(BadGeometry, match="max_incidence_deg"):
        check_view(cam, make_projection("cylinder", Mount(0.15, 0.2256, math.radians(60))), roi, 70.0)
    assert check_view(cam, make_projection("cylinder", Mount(0.15, 0.2256, math.radians(40))),
                      (300, 360, 360, 360), 70.0) < 45
