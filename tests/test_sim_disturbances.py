"""hw_sim's disturbances for the never-lose-distance work, other wall textures, and pose schedules:
what each does to the pixels and the ground truth, in render and through the Picamera2 fake."""
import json
import math
import pickle

import cv2
import numpy as np
import pytest

from hw_sim import ConfigError, SimConfig, Simulator, read_ground_truth, read_h264, read_pts, write_run
from hw_sim.cli import main
from hw_sim.light import led_light
from hw_sim.patterns import seamless
from hw_sim.picamera2_fake import ManualClock, SimWorld, make_picamera2
from hw_sim.texture import WallTexture

CENTRE = (320, 240, 320, 240)          # the middle of the thesis sensor at full resolution


def _texture_std(img):
    """Texture contrast without the large shading: std of the image minus its 31 px blur."""
    f = img.astype(np.float32)
    return float((f - cv2.blur(f, (31, 31))).std())


# --- LED blackouts -----------------------------------------------------------------------------------

def test_blackout_frames_are_dark_noisy_and_faintly_textured():
    lit = SimConfig(window=CENTRE, speed_m_s=0.2, duration_s=3, exposure_ms=2.0, noise_sigma=1.0)
    dark = SimConfig(**{**lit.to_dict(), "window": CENTRE, "led_blackouts": ((1.0, 2.0),)})
    a, b = Simulator(lit), Simulator(dark)
    assert np.array_equal(a.render(0.5), b.render(0.5))          # outside the blackout: untouched
    img = b.render(1.5)
    assert 1.0 < img.mean() < 5.0                                 # ambient 2 % of 128 DN, no LEDs
    assert 1.5 < img.std() < 4.0                                  # mostly sensor noise
    assert np.corrcoef(a.render_linear(1.5).ravel(), img.ravel().astype(float))[0, 1] > 0.05   # faint wall
    assert np.array_equal(b.render(2.5), a.render(2.5))           # the LEDs are back at once


def test_blackout_edge_crosses_a_rolling_shutter_frame_with_the_led_decay():
    cfg = SimConfig(window=CENTRE, speed_m_s=0.0, duration_s=1, exposure_ms=1.0, readout_ms=20.0,
                    led_blackouts=((0.505, 0.9),), blackout_decay_ms=2.0, blackout_noise_sigma=0.0)
    rows = Simulator(cfg).render(0.5).mean(axis=1)       # row v exposed at 0.5 + 20 ms * v / 239
    assert rows[:40].mean() > 100 and rows[-40:].mean() < 4
    edge = np.flatnonzero(rows < 64)[0] * 20e-3 / 239 + 0.5
    assert 0.5053 < edge < 0.5075                         # half the light ~1.4 ms after switching off
    assert np.all(np.diff(rows[55:110]) < 1.0)            # it fades, never brightens, in the dark


def test_led_light_is_the_exact_mean_over_the_exposure():
    t = np.linspace(0.99, 1.02, 301)
    got = led_light(t, 0.004, ((1.0, 1.01),), 0.001)
    sub = np.linspace(-0.002, 0.002, 4001)[None, :] + t[:, None]     # brute force: average the light
    inst = np.where((sub >= 1.0) & (sub < 1.01), np.exp(-(sub - 1.0) / 0.001), 1.0)
    np.testing.assert_allclose(got, inst.mean(axis=1), atol=1e-3)


# --- wet patches ---------------------------------------------------------------------------------------

def test_wet_patch_is_smooth_with_a_saturated_highlight_fixed_in_the_image():
    cfg = SimConfig(tilt_deg=0, speed_m_s=0.1, duration_s=5, wet_patches=((0.0, 1.0),), lighting=True)
    sim = Simulator(cfg)
    dry = Simulator(SimConfig(tilt_deg=0, speed_m_s=0.1, duration_s=5, lighting=True)).render(2.0)
    a, b = sim.render(2.0), sim.render(2.1)               # 10 mm apart, both on the wet patch
    far = (slice(0, 150), slice(0, 200))                  # a corner away from the highlight
    assert 0.02 < _texture_std(a[far]) / _texture_std(dry[far]) < 0.15    # faint grain only
    hot = a == 255
    assert 0.005 < hot.mean() < 0.2                        # partly saturated
    v, u = np.argwhere(hot).mean(axis=0)                   # at tilt 0 the LED's mirror point is the centre
    assert abs(v - 359.5) < 3 and abs(u - 479.5) < 3
    hot_b = b == 255                                       # it stays where it is while the wall moves
    assert (hot & hot_b).sum() / (hot | hot_b).sum() > 0.9
    assert np.abs(np.argwhere(hot_b).mean(axis=0) - (v, u)).max() < 0.5
    assert not (a[far] == b[far]).all()


def test_highlight_only_where_the_wall_is_wet_and_at_a_chosen_pixel():
    cfg = SimConfig(tilt_deg=24, speed_m_s=0.1, duration_s=5, wet_patches=((0.5, 0.6),),
                    wet_highlight_at=(480, 600), wet_highlight=3.0)
    sim = Simulator(cfg)
    assert not (sim.render(1.0) == 255).any()               # before the patch
    img = sim.render(4.8)                                   # the patch is under the lower image half
    v, u = np.argwhere(img == 255).mean(axis=0)
    assert abs(v - 600) < 6 and abs(u - 480) < 6
    g = sim.truth(4.8)
    assert 0 < g["wet"] <= 1 and sim.truth(1.0)["wet"] == 0


# --- dropped bursts, heavy compression ------------------------------------------------------------------

def test_dropped_burst_leaves_a_gap_in_the_stream_and_the_pts(tmp_path):
    cfg = SimConfig(window=(400, 300, 160, 120), duration_s=1.0, speed_m_s=0.3, dropped_bursts=((0.3, 0.5),))
    paths = write_run(cfg, tmp_path, "burst")
    pts, gt = read_pts(paths["pts"]), read_ground_truth(paths["csv"])
    assert len(pts) == 31 - 6 and len(list(read_h264(paths["h264"]))) == 25
    gap = np.flatnonzero(np.diff(pts) > 0.05)
    assert len(gap) == 1 and pts[gap[0]] == pytest.approx(0.2667, abs=1e-3) and pts[gap[0] + 1] == pytest.approx(0.5)
    assert gt["lost_before"][gap[0] + 1] == 6 and gt["lost_before"].sum() == 6
    assert json.loads(paths["json"].read_text())["dropped_frames"] == 6


@pytest.mark.parametrize("crf", [35, 40])
def test_heavy_compression_still_decodes_every_frame(tmp_path, crf):
    cfg = SimConfig(window=(320, 240, 320, 240), duration_s=1.0, speed_m_s=0.3, texture="masonry", crf=crf)
    paths = write_run(cfg, tmp_path, f"crf{crf}")
    decoded = list(read_h264(paths["h264"]))
    rendered = [f.image for f in Simulator(cfg).frames()]
    assert len(decoded) == len(rendered) == 31
    err = np.mean([np.abs(a.astype(float) - b).mean() for a, b in zip(rendered, decoded)])
    assert 1.0 < err < 12.0                               # visibly lossy, still the same picture
    assert paths["h264"].stat().st_size < 31 * 320 * 240 / 50


# --- textures ---------------------------------------------------------------------------------------------

def test_masonry_has_joints_blocks_and_wraps_exactly():
    cfg = SimConfig(texture="masonry", seed=3)
    tex = Simulator(cfg).texture
    n = tex.n_cols
    np.testing.assert_allclose(tex.region(0, 0, 64, n - 32, n + 32),
                               tex.albedo(np.arange(-32, 96), np.arange(n - 64, n + 64))[32:-32, 32:-32], atol=1e-5)
    wall = tex.region(0, 0, 3000, 0, 1600)                # 0.6 m x 0.32 m
    smooth = cv2.blur(wall, (21, 21))                     # 4 mm: the grain averages out, joints stay
    dark = smooth < np.median(smooth) - 0.2               # mortar: well below the blocks
    joints = 10 / 75 + 10 / 225 - 10 * 10 / (75 * 225)    # area share of 10 mm joints on 215 x 65 blocks
    assert abs(dark.mean() - joints) < 0.06
    course = np.round(np.mean(dark, axis=0), 2)            # whole columns of joint every 75 mm around
    assert (course > 0.8).sum() >= 4 * 2
    a, b = tex.region(0, 0, 256, 0, 256), tex.region(0, 1125, 1381, 0, 256)   # one block period apart
    assert abs(np.corrcoef(a.ravel(), b.ravel())[0, 1]) < 0.9                # block shades and grain differ


def test_image_texture_wraps_and_tiles_without_seams(tmp_path):
    rng = np.random.default_rng(0)
    img = cv2.GaussianBlur(rng.uniform(0, 255, (96, 128)).astype(np.float32), (0, 0), 2)
    path = tmp_path / "wall.png"
    cv2.imwrite(str(path), np.clip((img - img.mean()) * 4 + 128, 0, 255).astype(np.uint8))
    t = seamless(cv2.imread(str(path), cv2.IMREAD_GRAYSCALE).astype(np.float32))
    step = np.abs(np.diff(t, axis=0)).mean()
    assert np.abs(t[0] - t[-1]).mean() < 2 * step and np.abs(t[:, 0] - t[:, -1]).mean() < 2 * step
    tex = Simulator(SimConfig(texture="image", texture_image=str(path), image_mm_per_px=1.0)).texture
    n = tex.n_cols
    np.testing.assert_allclose(tex.region(0, 0, 64, n - 32, n + 32),
                               tex.albedo(np.arange(-32, 96), np.arange(n - 64, n + 64))[32:-32, 32:-32], atol=1e-4)
    wall = tex.region(0, 0, 4000, 0, 512)
    grad = np.abs(np.diff(wall, axis=0)).mean(axis=1)
    assert grad.max() < 3 * grad.mean()                    # no seam rows
    a = wall[:480]                                         # the image is 480 texels long: half, one, two, four
    assert max(abs(np.corrcoef(a.ravel(), wall[k:k + 480].ravel())[0, 1]) for k in (240, 480, 960, 1920)) < 0.5
    b = wall[:96]                                          # nor at any shift, over a window the size of an ROI
    assert max(abs(np.corrcoef(b.ravel(), wall[k:k + 96].ravel())[0, 1]) for k in range(40, 3000, 8)) < 0.6


def test_texture_image_errors_name_the_field(tmp_path):
    with pytest.raises(ConfigError) as e:
        SimConfig(texture="image", texture_image=str(tmp_path / "missing.png"))
    assert e.value.field == "texture_image"
    bad = tmp_path / "bad.png"
    bad.write_text("not an image")
    with pytest.raises(ConfigError, match="not a readable image") as e:
        Simulator(SimConfig(texture="image", texture_image=str(bad)))
    assert e.value.field == "texture_image"
    back = pickle.loads(pickle.dumps(e.value))              # a render in a process pool raises it back
    assert type(back) is ConfigError and back.field == "texture_image" and str(back) == str(e.value)


# --- pose schedules -----------------------------------------------------------------------------------

def _close(a, b):
    """Same picture up to float32 rays (moving camera) against float64 ones (static)."""
    return np.abs(a.astype(float) - b).mean() < 0.5


def test_tilt_schedule_steps_and_sweeps():
    cfg = SimConfig(window=CENTRE, speed_m_s=0.2, duration_s=4, tilt_schedule=((1.0, 0), (1.05, 24), (3.0, 40)))
    sim = Simulator(cfg)
    assert cfg.tilt_deg == 0.0 and sim.truth(0.5)["tilt_deg"] == 0 and sim.truth(1.05)["tilt_deg"] == 24
    assert sim.truth(2.025)["tilt_deg"] == pytest.approx(32.0)
    for t, tilt in ((0.5, 0.0), (1.2, 24 + 16 * 0.15 / 1.95), (3.5, 40.0)):
        still = Simulator(SimConfig(window=CENTRE, speed_m_s=0.2, duration_s=4, tilt_deg=tilt))
        assert _close(sim.render(t), still.render(t))


def test_height_profile_lifts_the_camera_over_sediment(tmp_path):
    cfg = SimConfig(window=(400, 300, 160, 120), speed_m_s=0.2, duration_s=1.0,
                    height_profile=((0.05, 0.0), (0.1, 20.0), (0.15, 20.0), (0.2, 0.0)))
    H = cfg.H_m
    gt = read_ground_truth(write_run(cfg, tmp_path, "sediment")["csv"])
    i = np.argmin(np.abs(gt["t_s"] - 0.6))                 # the car at 0.12 m: 20 mm of sediment
    assert gt["camera_height_m"][i] == pytest.approx(H - 0.02) and gt["camera_height_m"][0] == pytest.approx(H)
    assert np.all(gt["tilt_deg"] == 0) and np.all(gt["led_light"] == 1) and np.all(gt["lost_before"] == 0)
    low = Simulator(SimConfig(window=(400, 300, 160, 120), speed_m_s=0.2, duration_s=1.0, camera_height_m=H - 0.02))
    assert _close(Simulator(cfg).render(0.6), low.render(0.6))


def test_version_1_ground_truth_still_reads(tmp_path):
    p = tmp_path / "old.csv"
    p.write_text("frame,t_s,distance_m,speed_m_s\n0,0.0,0.0,0.2\n1,0.033,0.0066,0.2\n")
    gt = read_ground_truth(p)
    assert list(gt["distance_m"]) == [0.0, 0.0066] and np.isnan(gt["tilt_deg"]).all() and (gt["lost_before"] == -1).all()


# --- through the Picamera2 fake ----------------------------------------------------------------------------

def test_fake_loses_a_burst_goes_dark_in_a_blackout_and_reports_the_pose():
    clock = ManualClock()
    world = SimWorld("imx219", clock=clock.ns, sleep=clock.sleep, speed_m_s=0.2, tilt_schedule=((0, 10), (1, 20)),
                     dropped_bursts=((0.2, 0.3),), led_blackouts=((0.5, 0.6),))
    cam = make_picamera2(world)(0)
    cam.configure(cam.create_video_configuration(main={"size": (160, 120), "format": "YUV420"}, raw=None,
                                                 controls={"FrameDurationLimits": (10000, 10000)}))
    cam.start()
    got = []
    for _ in range(70):
        with cam.captured_request(wait=1.0) as r:
            got.append((world.t_s(r.get_metadata()["SensorTimestamp"]), r.make_array("main")[:120, :160].mean()))
    t = np.array([g[0] for g in got])
    assert not ((t >= 0.2) & (t < 0.3)).any() and world.counts.lost == 10
    assert np.round(np.diff(t).max() * 100) == 11                 # the gap shows in the timestamps
    light = np.array([g[1] for g in got])
    assert (light[(t > 0.51) & (t < 0.585)] < 8).all() and (light[t < 0.45] > 60).all()   # 9 ms readout
    ts = int(world.start_ns + 0.55e9)
    assert world.truth(ts)["tilt_deg"] == pytest.approx(15.5) and world.truth(ts)["led_light"] < 1e-6
    assert world.truth(int(world.start_ns + 0.25e9))["dropped"] == 1
    cam.close()


# --- validation and the CLI ----------------------------------------------------------------------------

@pytest.mark.parametrize("field,value", [
    ("texture", "wood"), ("brick_mm", (1.0, 65.0)), ("brick_mm", (215.0,)), ("mortar_mm", -1.0),
    ("wet_patches", ((1.0, 0.5),)), ("wet_highlight_at", (5000.0, 1.0)), ("wet_contrast", 2.0),
    ("led_blackouts", ((2.0, 1.0),)), ("led_blackouts", "1:2"), ("blackout_ambient", 1.5),
    ("dropped_bursts", ((1.0, 1.0),)), ("tilt_schedule", ((1.0, 0.0), (0.5, 5.0))),
    ("tilt_schedule", ((0.0, 70.0),)), ("height_profile", ((0.0, 500.0),)), ("texture_image", 3),
])
def test_new_fields_refuse_bad_values_by_name(field, value):
    with pytest.raises(ConfigError) as e:
        SimConfig(**{field: value})
    assert e.value.field == field and str(e.value).startswith(f"{field}=")


def test_tilt_schedule_and_tilt_deg_must_agree():
    with pytest.raises(ConfigError, match="leave tilt_deg out") as e:
        SimConfig(tilt_deg=5.0, tilt_schedule=((0.0, 10.0),))
    assert e.value.field == "tilt_schedule"
    assert SimConfig(tilt_deg=10.0, tilt_schedule=((0.0, 10.0),)).tilt_deg == 10.0


def test_cli_flags_of_the_new_fields(tmp_path, capsys):
    rc = main(["render", "--out", str(tmp_path), "--name", "all", "--duration", "0.4", "--window", "400,300,160,120",
               "--tilt-schedule", "0:0,0.3:10", "--height-profile", "0:0,0.05:5", "--wet", "0.02:0.05",
               "--blackouts", "0.1:0.15", "--drop-bursts", "0.2:0.25", "--texture", "masonry", "--brick", "200,70",
               "--crf", "38"])
    assert rc == 0, capsys.readouterr().err
    meta = json.loads((tmp_path / "all.json").read_text())
    assert meta["config"]["tilt_schedule"] == [[0.0, 0.0], [0.3, 10.0]] and meta["config"]["brick_mm"] == [200.0, 70.0]
    assert meta["led_blackouts"] == [[0.1, 0.15]] and "lost_before" in meta["ground_truth_columns"]
    gt = read_ground_truth(tmp_path / "all.csv")
    assert gt["tilt_deg"][-1] == pytest.approx(10.0) and (gt["led_light"] < 0.1).sum() >= 1
    assert main(["render", "--out", str(tmp_path), "--name", "x", "--tilt-schedule", "0-3"]) == 2


def test_wall_texture_keeps_its_old_signature():
    tex = WallTexture(seed=5, mm_per_texel=0.2, circumference_m=math.pi * 0.3)
    assert tex.region(0, 0, 8, 0, 8).shape == (8, 8)


def test_skimage_textures_name_the_install_recipe_when_missing(monkeypatch):
    import sys
    cfg = SimConfig(texture="image", texture_image="skimage:gravel")     # a name, not a file: accepted
    monkeypatch.setitem(sys.modules, "skimage", None)                    # as if not installed
    with pytest.raises(ConfigError, match=r"pip install 'crawlerd\[textures\]'") as e:
        Simulator(cfg)
    assert e.value.field == "texture_image"
