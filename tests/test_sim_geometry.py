"""hw_sim geometry and motion: pure functions against closed forms and docs/conventions.md."""
import math

import cv2
import numpy as np
import pytest

from hw_sim import geometry as geo
from hw_sim.motion import Motion, Trapezoid

THESIS_K = geo.pinhole(960, 720, 53.50, 37.16)


def test_camera_height_thesis_car():
    assert geo.camera_height(0.30, 0.151, 0.054) == pytest.approx(0.22562, abs=1e-5)


def test_pinhole_centre_convention():
    fx, fy, cx, cy = THESIS_K
    assert (cx, cy) == (479.5, 359.5)
    assert 2 * math.degrees(math.atan(360 / fy)) == pytest.approx(37.16)
    assert 2 * math.degrees(math.atan(480 / fx)) == pytest.approx(53.50)


@pytest.mark.parametrize("window,out", [((0, 0, 960, 720), (480, 360)), ((200, 120, 640, 480), (320, 240)),
                                        ((100, 50, 300, 200), (300, 200))])
def test_window_intrinsics_match_the_pixel_mapping(window, out):
    """Projecting a ray with the output intrinsics lands where the sensor mapping says."""
    fx, fy, cx, cy = THESIS_K
    ofx, ofy, ocx, ocy = geo.window_intrinsics(THESIS_K, window, out)
    u_out = np.array([0.0, 17.3, out[0] - 1.0])
    v_out = np.array([0.0, 42.8, out[1] - 1.0])
    u, v = geo.output_to_sensor(u_out, v_out, window, out)
    xn, yn = (u - cx) / fx, (v - cy) / fy
    np.testing.assert_allclose(ofx * xn + ocx, u_out, atol=1e-9)
    np.testing.assert_allclose(ofy * yn + ocy, v_out, atol=1e-9)


def test_distorted_grid_reprojects_onto_its_pixels():
    dist = (-0.25, 0.08, 0.001, -0.0005, -0.01)
    window, out = (0, 0, 96, 72), (96, 72)
    K = geo.pinhole(96, 72, 53.5, 37.16)
    xn, yn = geo.normalised_grid(K, window, out, dist)
    pts = np.stack([xn.ravel(), yn.ravel(), np.ones(xn.size)], axis=1)
    Km = np.array([[K[0], 0, K[2]], [0, K[1], K[3]], [0, 0, 1]])
    proj, _ = cv2.projectPoints(pts, np.zeros(3), np.zeros(3), Km, np.array(dist))
    uu, vv = np.meshgrid(np.arange(96.0), np.arange(72.0))
    np.testing.assert_allclose(proj.reshape(72, 96, 2)[..., 0], uu, atol=1e-6)
    np.testing.assert_allclose(proj.reshape(72, 96, 2)[..., 1], vv, atol=1e-6)


def test_camera_axes_follow_conventions():
    t = math.radians(30)
    # optical axis pitched toward +y; image top (yn < 0) looks further toward +y; image right is -x
    assert np.allclose(geo.ray_directions(0.0, 0.0, t), (0.0, math.sin(t), math.cos(t)))
    assert geo.ray_directions(0.0, -0.1, t)[1] > geo.ray_directions(0.0, 0.1, t)[1]
    assert geo.ray_directions(0.1, 0.0, t)[0] < 0


def test_wall_hits_lie_on_the_cylinder_and_crown_line():
    r, H = 0.15, 0.22562
    rng = np.random.default_rng(0)
    xn, yn = rng.uniform(-0.5, 0.5, 200), rng.uniform(-0.3, 0.3, 200)
    d = geo.ray_directions(xn, yn, math.radians(25))
    lam, X, Y, Z = geo.intersect_wall(0.004, r - H, d, r)
    assert np.all(lam > 0)
    np.testing.assert_allclose(X**2 + Z**2, r * r, rtol=1e-12)
    # the centre column at tilt t hits the crown line at y = H tan(t - theta)
    y, s, _, cos_inc = geo.wall_coords(np.zeros(3), np.array([-0.2, 0.0, 0.2]), math.radians(25), 0.0, r - H, r)
    theta = np.arctan([-0.2, 0.0, 0.2])
    np.testing.assert_allclose(y, H * np.tan(math.radians(25) - theta), rtol=1e-12)
    np.testing.assert_allclose(s, 0, atol=1e-15)
    np.testing.assert_allclose(cos_inc, np.cos(math.radians(25) - theta), rtol=1e-12)


def test_arc_is_positive_toward_image_right():
    r, H = 0.15, 0.22562
    y, s, _, _ = geo.wall_coords(np.array([0.2]), np.array([0.0]), 0.0, 0.0, r - H, r)
    assert s[0] > 0


def test_centre_column_speed_is_the_derivative_of_the_projection():
    """dv/dy from the closed form equals a finite difference of v(y) = cy + fy tan(t - atan(y/H))."""
    H, fy, t = 0.22562, 1071.6, math.radians(40)
    for theta in (-0.3, 0.0, 0.3):
        y = H * math.tan(t - theta)
        h = 1e-7
        v = lambda yy: fy * math.tan(t - math.atan(yy / H))
        numeric = -(v(y + h) - v(y - h)) / (2 * h)   # forward travel: the wall point's y falls
        assert geo.centre_column_speed(theta, t, H, fy) == pytest.approx(numeric, rel=1e-6)


def test_led_gain_and_vignette_are_one_on_the_principal_ray():
    r, H, t = 0.15, 0.22562, math.radians(20)
    y, s, rng, cos_inc = geo.wall_coords(np.array([0.0, 0.3]), np.array([0.0, -0.2]), t, 0.0, r - H, r)
    g = geo.led_gain(rng, cos_inc, H, t)
    assert g[0] == pytest.approx(1.0) and g[1] < 1.0
    assert geo.vignette(np.array(0.0), np.array(0.0)) == 1.0


# --- motion -------------------------------------------------------------------------------------

@pytest.mark.parametrize("profile", ["constant", "accel", "stopgo", "reverse"])
def test_speed_is_the_derivative_of_distance(profile):
    m = Motion(profile, 0.4, 6.0, accel=0.8, stopgo_period=2.0, stopgo_dwell=0.5)
    t = np.linspace(0.01, 5.99, 997)
    h = 1e-6
    np.testing.assert_allclose((m.distance(t + h) - m.distance(t - h)) / (2 * h), m.speed(t), atol=2e-5)
    assert m.distance(0.0) == 0.0


def test_profiles_shapes():
    acc = Motion("accel", 0.5, 4.0, accel=0.5)
    assert acc.speed(0.0) == 0 and acc.speed(2.0) == pytest.approx(0.5) and acc.speed(4.0) == pytest.approx(0)
    assert acc.distance(4.0) == pytest.approx(0.5 * (4.0 - 1.0))   # v (T - v/a)
    rev = Motion("reverse", 0.3, 5.0, accel=1.0)
    assert rev.distance(2.0) > 0 > rev.distance(5.0)                # forward, then back past the start
    assert min(rev.speed(np.linspace(0, 5, 501))) == pytest.approx(-0.3)
    sg = Motion("stopgo", 0.3, 6.0, accel=1.0, stopgo_period=2.0, stopgo_dwell=0.5)
    assert [sg.speed(t) for t in (1.75, 3.75, 5.75)] == [0, 0, 0]    # standing in every dwell
    assert sg.distance(6.0) == pytest.approx(3 * 0.3 * (1.5 - 0.3))
    assert sg.path_length() == pytest.approx(sg.distance(6.0))
    assert rev.path_length() > abs(rev.distance(5.0))


def test_short_trapezoid_becomes_a_triangle():
    tr = Trapezoid(0.0, 1.0, 1.0, 1.0)        # would need 2 s to reach 1 m/s and stop
    assert tr.peak == pytest.approx(0.5) and tr.length == pytest.approx(0.25)
    assert tr.distance(np.array(1.0)) == pytest.approx(0.25)
