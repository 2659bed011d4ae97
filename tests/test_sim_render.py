"""hw_sim rendering: motion measured from rendered images against the geometry, and each effect.

Image motion is measured by tracking, never read from the renderer's formulas: a coarse
phase correlation, then ECC (sub-pixel translation) on a small patch aligned to it.
"""
import math

import cv2
import numpy as np
import pytest

from hw_sim import SimConfig, Simulator
from hw_sim.geometry import centre_column_speed
from hw_sim.texture import TILE, WallTexture

CENTRE_WINDOW = (320, 240, 320, 240)   # the middle of the thesis sensor, full resolution: fast


def track(a: np.ndarray, b: np.ndarray, v: int, u: int, half: int = 24) -> tuple[float, float]:
    """Displacement (du, dv) in pixels of the content around (u, v) from image a to image b."""
    big = 3 * half
    pa = a[v - big:v + big, u - big:u + big].astype(np.float64)
    pb = b[v - big:v + big, u - big:u + big].astype(np.float64)
    (gx, gy), _ = cv2.phaseCorrelate(pa, pb, cv2.createHanningWindow(pa.shape[::-1], cv2.CV_64F))
    gx, gy = int(round(gx)), int(round(gy))
    ta = a[v - half:v + half, u - half:u + half].astype(np.float32)
    tb = b[v - half + gy:v + half + gy, u - half + gx:u + half + gx].astype(np.float32)
    warp = np.eye(2, 3, dtype=np.float32)
    crit = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 200, 1e-7)
    _, warp = cv2.findTransformECC(ta, tb, warp, cv2.MOTION_TRANSLATION, crit, None, 1)
    return gx + float(warp[0, 2]), gy + float(warp[1, 2])


def assert_same_image(a: np.ndarray, b: np.ndarray) -> None:
    """Equal up to cv2.remap's 1/32-texel fixed-point positions (maps built from other offsets)."""
    diff = np.abs(a.astype(np.float64) - b)
    assert diff.mean() < 1e-3 and diff.max() < 0.05


def test_zero_motion_gives_identical_frames():
    sim = Simulator(SimConfig(tilt_deg=24, speed_m_s=0.0, duration_s=0.2, window=CENTRE_WINDOW))
    frames = [f.image for f in sim.frames()]
    assert len(frames) == 7
    assert all(np.array_equal(frames[0], f) for f in frames[1:])
    assert frames[0].std() > 10                  # and they show texture, not a flat grey


def test_render_is_deterministic_and_seeded():
    a = Simulator(SimConfig(seed=3, window=CENTRE_WINDOW, noise_sigma=2)).render(0.5)
    b = Simulator(SimConfig(seed=3, window=CENTRE_WINDOW, noise_sigma=2)).render(0.5)
    c = Simulator(SimConfig(seed=4, window=CENTRE_WINDOW, noise_sigma=2)).render(0.5)
    assert np.array_equal(a, b) and not np.array_equal(a, c)


def test_tilt0_image_scale_matches_thesis_eq_3_1():
    """Centre row at tilt 0: pixels per metre = 1 / (2 H tan(VFOV/2) / height), within 0.5 %."""
    cfg = SimConfig(tilt_deg=0, speed_m_s=1.0)
    sim = Simulator(cfg)
    px_per_m = 1 / (2 * sim.camera_height_m * math.tan(math.radians(cfg.vfov_deg) / 2) / cfg.height)
    a = sim.render(0.0)
    for d in (0.004, 0.010):                     # ~19 and ~47 px
        b = sim.render(d)                        # speed 1 m/s: t is the distance
        du, dv = track(a, b, 360, 480)
        assert dv / d == pytest.approx(px_per_m, rel=0.005)
        assert abs(du) < 0.1                     # straight down the image (forward: v grows)


def test_tilt40_bottom_rows_move_faster_by_the_geometric_ratio():
    """Image speed along the centre column is proportional to cos^2(t - theta) / cos^2(theta)."""
    cfg = SimConfig(tilt_deg=40, speed_m_s=1.0)
    sim = Simulator(cfg)
    fy, cy, t = sim.intrinsics["fy"], sim.intrinsics["cy"], math.radians(40)
    a = sim.render(0.0)
    measured, predicted = [], []
    for d in (0.002, 0.003, 0.004):
        b = sim.render(d)
        speeds = {}
        for v in (360, 640):
            dv = track(a, b, v, 480)[1]
            theta = math.atan((v + dv / 2 - cy) / fy)     # ray angle halfway along the path
            speeds[v] = (dv, centre_column_speed(theta, t, sim.camera_height_m, fy))
        measured.append(speeds[640][0] / speeds[360][0])
        predicted.append(speeds[640][1] / speeds[360][1])
    assert np.mean(predicted) == pytest.approx(1.49, abs=0.01)   # a real difference to detect
    assert np.mean(measured) == pytest.approx(np.mean(predicted), rel=0.015)


def test_tilt_points_the_centre_at_h_tan_t_ahead():
    """The centre pixel at tilt t sees what a tilt-0 camera sees from H tan(t) further on."""
    tilted = Simulator(SimConfig(tilt_deg=12, window=CENTRE_WINDOW))
    y_ahead = tilted.camera_height_m * math.tan(math.radians(12))
    level = Simulator(SimConfig(tilt_deg=0, window=CENTRE_WINDOW, start_m=y_ahead))
    du, dv = track(tilted.render(0.0), level.render(0.0), 120, 160, half=16)
    assert abs(du) < 0.15 and abs(dv) < 0.15


def test_roll_moves_content_right_and_sway_too():
    base = SimConfig(window=CENTRE_WINDOW, speed_m_s=0.0)
    still = Simulator(base).render(0.0)
    # roll amplitude with a 0.25 Hz sine: at t = 1 s the roll is +amplitude
    rolled = Simulator(SimConfig(**{**base.to_dict(), "roll_deg": 1.0, "roll_hz": 0.25})).render(1.0)
    du, dv = track(still, rolled, 120, 160)
    px_per_m = Simulator(base).intrinsics["fx"] / Simulator(base).camera_height_m
    assert du == pytest.approx(0.15 * math.radians(1.0) * px_per_m, rel=0.05) and abs(dv) < 0.1
    swayed = Simulator(SimConfig(**{**base.to_dict(), "sway_mm": 2.0})).render(0.3)
    assert track(still, swayed, 120, 160)[0] > 1.0


def test_cropped_window_is_a_crop_of_the_full_sensor():
    full = Simulator(SimConfig(tilt_deg=10)).render_linear(0.1)
    win = Simulator(SimConfig(tilt_deg=10, window=(100, 60, 320, 240))).render_linear(0.1)
    assert_same_image(win, full[60:300, 100:420])


def test_scaled_window_reports_its_intrinsics():
    sim = Simulator(SimConfig(window=(160, 120, 640, 480), output_size=(320, 240)))
    assert (sim.width, sim.height) == (320, 240)
    fx, fy = 480 / math.tan(math.radians(53.5 / 2)), 360 / math.tan(math.radians(37.16 / 2))
    assert sim.intrinsics["fx"] == pytest.approx(fx / 2) and sim.intrinsics["fy"] == pytest.approx(fy / 2)
    assert sim.intrinsics["cx"] == pytest.approx(159.5) and sim.intrinsics["cy"] == pytest.approx(119.5)
    assert sim.render(0.0).shape == (240, 320)


def test_motion_blur_equals_averaging_many_subframes():
    blurred = Simulator(SimConfig(speed_m_s=0.5, exposure_ms=10, window=CENTRE_WINDOW)).render_linear(0.3)
    sharp = Simulator(SimConfig(speed_m_s=0.5, window=CENTRE_WINDOW))
    n = 100
    brute = np.mean([sharp.render_linear(0.3 + ((j + 0.5) / n - 0.5) * 0.010) for j in range(n)], axis=0)
    assert np.abs(blurred - brute).mean() < 0.002
    assert blurred.std() < 0.8 * sharp.render_linear(0.3).std()


def test_rolling_shutter_row_time():
    """Row v is exposed at t + readout * v / (height - 1)."""
    rs = Simulator(SimConfig(speed_m_s=0.5, readout_ms=20, window=CENTRE_WINDOW))
    gs = Simulator(SimConfig(speed_m_s=0.5, window=CENTRE_WINDOW))
    a = rs.render_linear(0.2)
    assert_same_image(a[0], gs.render_linear(0.2)[0])
    assert_same_image(a[-1], gs.render_linear(0.22)[-1])
    assert_same_image(a[120], gs.render_linear(0.2 + 0.02 * 120 / 239)[120])
    assert np.abs(a[-1] - gs.render_linear(0.2)[-1]).mean() > 0.05      # and the shutter did matter


def test_a_camera_turned_during_the_readout_exposes_each_band_of_rows_at_its_own_tilt():
    """A rolling shutter on a turning camera: the rows read later were turned further (bands of
    at most 0.02 deg); a still camera, or one not turning then, renders as before."""
    turn = ((0.0, 24.0), (0.1, 34.0))                    # 100 deg/s: 2 deg over a 20 ms readout
    rs = Simulator(SimConfig(speed_m_s=0.0, tilt_schedule=turn, readout_ms=20, window=CENTRE_WINDOW))
    gs = Simulator(SimConfig(speed_m_s=0.0, tilt_schedule=turn, window=CENTRE_WINDOW))
    a = rs.render_linear(0.03)
    assert np.abs(a[:2] - gs.render_linear(0.03)[:2]).mean() < 0.04         # top rows: the tilt at 0.03 s
    assert np.abs(a[-2:] - gs.render_linear(0.05)[-2:]).mean() < 0.04       # bottom rows: at 0.05 s
    assert np.abs(a[-2:] - gs.render_linear(0.03)[-2:]).mean() > 0.15       # (2 deg apart: it mattered)
    held = rs.render_linear(0.5)                          # turned, now still: one tilt for every row
    assert_same_image(held, gs.render_linear(0.5))


def test_featureless_stretch_has_no_texture():
    cfg = SimConfig(tilt_deg=0, window=CENTRE_WINDOW, featureless=((0.05, 0.25),), speed_m_s=1.0)
    sim = Simulator(cfg)
    inside, outside = sim.render(0.15), sim.render(0.5)   # the camera over the patch, then past it
    assert inside.std() < 0.25 * outside.std()


def test_lighting_and_vignetting_darken_the_edges():
    lit = Simulator(SimConfig(tilt_deg=20, lighting=True, vignetting=True, contrast=0.0)).render(0.0)
    flat = Simulator(SimConfig(tilt_deg=20, contrast=0.0)).render(0.0)
    gain = lit.astype(float) / flat
    assert gain[350:370, 470:490].mean() == pytest.approx(1.0, abs=0.02)   # 1 at the principal ray
    assert gain[:40, :40].mean() < 0.6 and gain[-40:, -40:].mean() < 0.8


def test_noise_and_flicker():
    clean = Simulator(SimConfig(window=CENTRE_WINDOW)).render(0.3).astype(float)
    noisy = Simulator(SimConfig(window=CENTRE_WINDOW, noise_sigma=3.0)).render(0.3).astype(float)
    assert (noisy - clean).std() == pytest.approx(3.0, rel=0.1)
    fl = Simulator(SimConfig(window=CENTRE_WINDOW, speed_m_s=0.0, flicker_amp=0.1, flicker_hz=1.0))
    ratio = fl.render(0.25).astype(float).mean() / fl.render(0.75).astype(float).mean()
    assert ratio == pytest.approx(1.1 / 0.9, rel=0.02)


def test_pitch_jitter_moves_the_image_by_fy_per_radian():
    base = dict(window=CENTRE_WINDOW, speed_m_s=0.0, tilt_deg=10)
    still = Simulator(SimConfig(**base)).render(0.0)
    sim = Simulator(SimConfig(**base, pitch_jitter_deg=0.5))
    t = max(np.linspace(0, 1, 21), key=lambda t: abs(sim.pose(t)["tilt"] - sim.tilt_rad))
    dtilt = sim.pose(t)["tilt"] - sim.tilt_rad
    du, dv = track(still, sim.render(t), 120, 160)
    assert dv == pytest.approx(sim.intrinsics["fy"] * dtilt, rel=0.05)    # pitch forward: content down


def test_bounce_scales_the_image_about_the_centre():
    base = dict(window=CENTRE_WINDOW, speed_m_s=0.0)
    still = Simulator(SimConfig(**base)).render(0.0)
    sim = Simulator(SimConfig(**base, bounce_mm=5.0, bounce_hz=1.0))
    assert np.abs(sim.render(0.0).astype(int) - still).max() <= 1        # sin(0) = 0: no bounce
    up = sim.render(0.25)                                                # H + 5 mm: smaller image
    H, cy = sim.camera_height_m, 359.5 - 240                             # cy in window pixels
    for v in (60, 180):   # centre column: the crown line, now 5 mm further away
        assert track(still, up, v, 160, half=16)[1] == pytest.approx(-(v - cy) * 0.005 / (H + 0.005), rel=0.05)
    assert track(still, up, 120, 260, half=16)[0] < -1.5 and track(still, up, 120, 60, half=16)[0] > 1.5


def test_texture_tiles_join_and_wrap_without_seams():
    tex = WallTexture(seed=5, mm_per_texel=0.2, circumference_m=math.pi * 0.3)
    assert tex.n_cols % 16 == 0 and abs(tex.m_per_texel_circ / tex.m_per_texel - 1) < 0.01
    # a region across a tile corner equals the texture function evaluated there directly
    region = tex.region(0, TILE - 64, TILE + 64, TILE - 64, TILE + 64)
    direct = tex.albedo(np.arange(TILE - 96, TILE + 96), np.arange(TILE - 96, TILE + 96))[32:-32, 32:-32]
    np.testing.assert_allclose(region, direct, atol=1e-6)
    # around the pipe: column n_cols is column 0
    n = tex.n_cols
    np.testing.assert_array_equal(tex.region(0, 0, 8, n - 4, n + 4), tex.region(0, 0, 8, -4, 4))
    # and the wall function itself is periodic there
    direct = tex.albedo(np.arange(-32, 96), np.arange(n - 64, n + 64))[32:-32, 32:-32]
    np.testing.assert_allclose(tex.region(0, 0, 64, n - 32, n + 32), direct, atol=1e-5)
    # coarser levels equal the pyramid of one big region: no seams at tile borders
    big = tex.albedo(np.arange(-64, 320), np.arange(TILE - 192, TILE + 192))
    lv2 = cv2.pyrDown(cv2.pyrDown(big))[16:80, 16:80]          # global level-2 rows 0..64, cols 96..160
    np.testing.assert_allclose(tex.region(2, 0, 64, 96, 160), lv2, atol=1e-5)


def test_texture_does_not_repeat_along_the_pipe():
    tex = WallTexture(seed=1, mm_per_texel=0.2, circumference_m=math.pi * 0.3)
    a = tex.region(0, 0, 128, 0, 128)
    for k in (1, 2, 40, 1000):
        b = tex.region(0, k * TILE, k * TILE + 128, 0, 128)
        assert abs(np.corrcoef(a.ravel(), b.ravel())[0, 1]) < 0.2


def test_distortion_bends_the_edges_not_the_centre():
    plain = Simulator(SimConfig(tilt_deg=0)).render_linear(0.0)
    barrel = Simulator(SimConfig(tilt_deg=0, distortion=(-0.3, 0.1, 0, 0, 0))).render_linear(0.0)
    assert_same_image(barrel[350:370, 470:490], plain[350:370, 470:490])
    assert np.abs(barrel[:60, :60] - plain[:60, :60]).mean() > 0.05
