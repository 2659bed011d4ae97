"""Issue 14: the camera's pose from the flow: tilt auto, a tilt step, calibrate check, the settings."""

import json
import math
import re

import numpy as np
import pytest

from crawler import settings as S
from crawler.errors import BadConfig
from hw_sim import read_ground_truth


def frames(log):
    return [json.loads(line) for line in log.read_text().splitlines()]


def replay(crawlerd, run, tmp_path, *argv):
    log = tmp_path / f"{run['h264'].stem}.jsonl"
    rc, summary, err = crawlerd("--replay", run["h264"], "--log", log, *map(str, argv))
    assert rc == 0, err
    return summary, frames(log), read_ground_truth(run["csv"])


def test_tilt_auto_finds_24_degrees_within_2_s_of_motion_and_measures_the_distance(render_run, crawlerd, tmp_path):
    run = render_run("auto24", tilt_deg=24, speed_m_s=0.3, duration_s=3.0, seed=54)
    s, rows, truth = replay(crawlerd, run, tmp_path, "--tilt", "auto")
    t = truth["t_s"][:len(rows)]
    tilt = np.array([r["tilt_deg"] for r in rows])
    assert rows[0]["tilt_deg"] == 0.0                        # the estimate starts at 0 degrees
    assert np.all(np.abs(tilt[t >= 2.0] - 24.0) < 0.3)       # ...and holds 24 from 2 s of motion on
    assert abs(s["pose"]["tilt_deg"] - 24.0) < 0.3 and 0 < s["pose"]["tilt_sigma_deg"] < 0.3
    assert 100 * abs(s["distance_m"] - run["truth"]["true_distance_m"]) / run["truth"]["path_length_m"] < 0.1


def test_tilt_auto_at_40_degrees_and_a_crawl_holds_within_0_3_degrees_from_2_s(render_run, crawlerd, tmp_path):
    """At 0.04 m/s a keyframe lasts 0.8 s and the search fires on the third: its median spread left
    0.5 deg there (within 0.3 only at 2.5 s). The closed keyframes' samples, read again as readings
    (strays cut, the variance), take it within 0.3 deg as it fires. Till then a provisional tilt,
    from the first frame of each keyframe whose features moved far enough, measures the distance:
    at 0 deg it read 20 % short for 1.6 s (14 mm at 1 s), now for 0.3 s."""
    run = render_run("auto40crawl", tilt_deg=40, speed_m_s=0.04, duration_s=3.0, seed=70)
    s, rows, truth = replay(crawlerd, run, tmp_path, "--tilt", "auto")
    t = truth["t_s"][:len(rows)]
    tilt = np.array([r["tilt_deg"] for r in rows])
    assert np.all(np.abs(tilt[t >= 2.0] - 40.0) < 0.3)
    err = np.abs(np.array([r["distance_m"] for r in rows]) - truth["distance_m"][:len(rows)])
    sigma = np.array([r["sigma_m"] for r in rows])
    searching = tilt == 0.0                             # before any frame showed the tilt: 20 % short
    assert 0 < searching.sum() < 15 and err[searching].max() > 0.001
    assert err[t >= 1.0].max() < 0.001
    assert np.all(err <= 2 * sigma)                     # sigma says what the provisional tilt may be off


def test_tilt_auto_with_the_pose_estimator_holds_the_pose_until_the_tilt_is_found(render_run, crawlerd, tmp_path):
    """Read at a tilt not yet found (the search starts at 0 deg), the pitch, height and sway take up
    its error, and their refinements of earlier steps stayed in the distance after the search:
    +1.0 % on a still 24 deg crawl. Until the tilt is found they are learnt again, not applied."""
    run = render_run("auto24crawl", tilt_deg=24, speed_m_s=0.04, duration_s=4.0, seed=54)
    s, rows, truth = replay(crawlerd, run, tmp_path, "--tilt", "auto", "--set", "odometry.estimate_pose=true")
    assert abs(s["pose"]["tilt_deg"] - 24.0) < 0.3
    assert 100 * abs(s["distance_m"] - run["truth"]["true_distance_m"]) / run["truth"]["path_length_m"] < 0.15


def test_a_tilt_step_is_detected_and_followed_within_1_s(render_run, crawlerd, tmp_path):
    run = render_run("step2440", tilt_deg=24, tilt_schedule=((2.0, 24.0), (2.0001, 40.0)), speed_m_s=0.2,
                     duration_s=4.0, seed=41)
    s, rows, truth = replay(crawlerd, run, tmp_path, "--tilt", "auto")
    t = truth["t_s"][:len(rows)]
    tilt = np.array([r["tilt_deg"] for r in rows])
    assert np.all(np.abs(tilt[(t > 1.0) & (t < 2.0)] - 24.0) < 0.3)
    assert np.all(np.abs(tilt[t >= 3.0] - 40.0) < 0.3)       # within 1 s of the step
    assert s["pose"]["tilt_steps"] == 1
    # the steps measured at the old tilt after the turn are measured again at the new one
    assert 100 * abs(s["distance_m"] - run["truth"]["true_distance_m"]) / run["truth"]["path_length_m"] < 0.2


def test_a_configured_tilt_estimates_pitch_and_height_unless_told_not_to(render_run, crawlerd, tmp_path):
    run = render_run("auto24", tilt_deg=24, speed_m_s=0.3, duration_s=3.0, seed=54)
    truth = run["truth"]
    s, rows, _ = replay(crawlerd, run, tmp_path, "--tilt", "24")
    assert s["pose"]["tilt_auto"] is False and s["pose"]["tilt_deg"] == 24.0
    assert rows[-1]["tilt_deg"] == 24.0 and abs(rows[-1]["pitch_deg"]) < 0.3 and rows[-1]["camera_height_m"] > 0
    assert 100 * abs(s["distance_m"] - truth["true_distance_m"]) / truth["path_length_m"] < 0.02
    s, rows, _ = replay(crawlerd, run, tmp_path, "--tilt", "24", "--set", "odometry.estimate_pose=false")
    assert "pose" not in s and "tilt_deg" not in rows[0]     # no estimator, no per-frame pose
    assert 100 * abs(s["distance_m"] - truth["true_distance_m"]) / truth["path_length_m"] < 0.02


def test_estimate_pose_unset_means_with_a_configured_tilt_only():
    from crawler.measurement import pose_params

    def params(*overrides):
        return pose_params(S.load(None, list(overrides)))

    assert params().bounce_sigma_mm == 1.0 and not params().auto_tilt            # the default
    assert params("odometry.estimate_pose=false") is None
    auto = params("mount.tilt_deg='auto'")      # tilt auto alone: the pose read for the ride height, not applied
    assert auto.auto_tilt and not auto.correct_pose and auto.bounce_sigma_mm == 1.0
    assert auto.ride_height and auto.ride_max_tilt_deg == 30.0
    both = params("mount.tilt_deg='auto'", "odometry.estimate_pose=true")
    assert both.auto_tilt and both.correct_pose and both.bounce_sigma_mm == 1.0
    bare = params("mount.tilt_deg='auto'", "odometry.estimate_pose=false")   # neither read nor applied
    assert bare.auto_tilt and not bare.ride_height and bare.bounce_sigma_mm == 0.0 and bare.pitch_sigma_deg == 0.0
    assert params("odometry.method='pixel'") is None                               # nothing to estimate
    with pytest.raises(BadConfig, match="estimate_pose = true needs"):
        params("odometry.method='pixel'", "odometry.estimate_pose=true")
    # the ride height: unset, on with a configured tilt up to 30 deg (steeper its readings drift)
    assert params().ride_height and params("mount.tilt_deg=24").ride_height
    assert not params("mount.tilt_deg=40").ride_height and not params("mount.tilt_deg=-31").ride_height
    assert not params("mount.tilt_deg=24", "odometry.ride_height=false").ride_height
    assert params("mount.tilt_deg=40", "odometry.ride_height=true").ride_height
    assert params("mount.tilt_deg=40", "odometry.ride_height=true").ride_max_tilt_deg == math.inf   # as set
    assert params("mount.tilt_deg='auto'", "odometry.ride_height=true").ride_max_tilt_deg == math.inf
    for without in ("odometry.estimate_pose=false", "odometry.method='pixel'"):
        with pytest.raises(BadConfig, match="ride_height = true sums the pose estimator's height changes"):
            params("odometry.ride_height=true", without)
    with pytest.raises(BadConfig, match="ride_height = true sums the pose estimator's height changes"):
        params("odometry.ride_height=true", "mount.tilt_deg='auto'", "odometry.estimate_pose=false")


def test_status_carries_the_tilt_and_its_sigma_finite(render_run):
    from crawler.service import Mode, RunOptions, Service

    run = render_run("auto24", tilt_deg=24, speed_m_s=0.3, duration_s=3.0, seed=54)
    with Service(S.load(None, ["mount.tilt_deg=auto"]), RunOptions(mode=Mode.REPLAY, video=str(run["h264"]))) as svc:
        svc.run()
        status = svc.daemon.status()
    for key in ("tilt_deg", "tilt_sigma_deg", "pitch_deg", "camera_height_m"):
        assert isinstance(status[key], float) and math.isfinite(status[key]), key
    assert status["tilt_auto"] is True and abs(status["tilt_deg"] - 24) < 0.3
    with Service(S.load(None, ["mount.tilt_deg=24"]), RunOptions(mode=Mode.REPLAY, video=str(run["h264"]),
                                                                  max_frames=5)) as svc:
        svc.run()
        status = svc.daemon.status()
    assert status["tilt_deg"] == 24.0 and status["tilt_sigma_deg"] is None and status["tilt_auto"] is False


def test_calibrate_check_passes_the_right_tilt_and_fails_a_wrong_one_with_the_fix(render_run, capsys):
    from crawler.calibrate import main

    run = render_run("auto24", tilt_deg=24, speed_m_s=0.3, duration_s=3.0, seed=54)
    assert main(["check", str(run["h264"]), "--set", "mount.tilt_deg=24", "--json"]) == 0
    ok = json.loads(capsys.readouterr().out)
    assert ok["tilt"]["verdict"] == "PASS" and abs(ok["tilt"]["estimated_deg"] - 24) < 0.3 and ok["set"] == []
    assert main(["check", str(run["h264"]), "--set", "mount.tilt_deg=20"]) == 1
    out = capsys.readouterr().out
    assert re.search(r"configured 20.0 deg, found 2[34]\.\d\d \+- 0\.\d\d deg   FAIL", out)
    assert "--set mount.tilt_deg=24.0" in out


def test_calibrate_check_fails_a_height_the_curvature_refutes(render_run, capsys):
    from crawler.calibrate import main

    run = render_run("height5", tilt_deg=24, speed_m_s=0.3, duration_s=5.0, seed=55)
    true_h = float(read_ground_truth(run["csv"])["camera_height_m"][0])          # 0.2256 m
    for configured in (0.20, 0.25):                                              # 26 mm low, 24 mm high
        assert main(["check", str(run["h264"]), "--set", "mount.tilt_deg=24", "--set",
                     f"mount.height_m={configured}", "--json"]) == 1
        h = json.loads(capsys.readouterr().out)["height"]
        assert h["verdict"] == "FAIL" and abs(h["estimated_m"] - true_h) < 0.008 and h["sigma_m"] < 0.008
    assert main(["check", str(run["h264"]), "--set", "mount.tilt_deg=24", "--json"]) == 0
    h = json.loads(capsys.readouterr().out)["height"]
    assert h["verdict"] in ("PASS", "UNDETERMINED")          # a 1.5 m drive shows it to about 7 mm


@pytest.mark.parametrize("value,ok", [('"auto"', True), ("24", True), ("-80", True), ('"up"', False),
                                      ("95", False), ("true", False)])
def test_tilt_is_degrees_or_auto(tmp_path, value, ok):
    path = tmp_path / "c.toml"
    path.write_text(f"[mount]\ntilt_deg = {value}\n")
    if ok:
        assert S.load(path).mount.tilt_auto == (value == '"auto"')
        return
    with pytest.raises(BadConfig, match=r"\[mount\] tilt_deg = .* must be"):
        S.load(path)


def test_tilt_auto_with_the_pixel_method_is_refused_with_the_fix(render_run, crawlerd):
    run = render_run("auto24", tilt_deg=24, speed_m_s=0.3, duration_s=3.0, seed=54)
    rc, _, err = crawlerd("--replay", run["h264"], "--tilt", "auto", "--method", "pixel")
    assert rc != 0 and 'needs [odometry] method = "cylinder" or "plane"' in err


def test_the_fields_match_the_exact_projection_to_1_percent():
    from crawler.geometry import make_projection
    from crawler.posefield import JacobianField, exact_derivatives

    from crawler.measurement import recording_camera, thesis_roi

    cam = recording_camera(S.CameraSettings())
    roi = thesis_roi(cam.width, cam.height)
    for tilt in (0.0, 24.0, 40.0):
        proj = make_projection("cylinder", S.MountSettings(tilt_deg=tilt).mount())
        field = JacobianField(cam, proj, roi)
        x, y, w, h = roi
        u, v = np.meshgrid(np.linspace(x, x + w - 1, 7), np.linspace(y, y + h - 1, 5))
        xy = cam.normalise(np.column_stack([u.ravel(), v.ravel()]))
        exact, fit = exact_derivatives(proj, xy), field.at(xy)
        scale = np.abs(exact).max(axis=0)
        assert np.all(np.abs(fit - exact) <= 0.01 * scale), tilt
        # the per-frame table (bilinear on an 8 px grid), off its grid points too
        px = np.column_stack([u.ravel(), v.ravel()]) + [3.3, 5.1]
        exact = exact_derivatives(proj, cam.normalise(px))
        assert np.all(np.abs(field.at_roi(px - [x, y]) - exact) <= 0.001 * scale), tilt


def test_the_filter_reads_the_stacked_model_from_one_gram_matrix():
    """pose.py builds H'H and H'z from one product and one Gram matrix (cheap on the Pi); they are the
    model written out row by row: axial rows (jc1, jc3, jc5, -jk1, -jc3, -jk5 | z = moved axial - d1 tau
    - d3 hk), lateral rows (jc0, jc2, jc4, -jk0, -jc2, -jk4 | z = -moved lateral - d0 tau - d2 hk), each
    column centred (fields: d(s, y)/d tilt, height, sway)."""
    from crawler.geometry import make_projection
    from crawler.measurement import recording_camera, thesis_roi
    from crawler.pose import K_HEIGHT, PoseEstimator

    cam = recording_camera(S.CameraSettings())
    roi = thesis_roi(cam.width, cam.height)
    pose = PoseEstimator(cam, make_projection("cylinder", S.MountSettings(tilt_deg=24.0).mount()), roi)
    rng = np.random.default_rng(3)
    jk, jc, moved = rng.normal(size=(23, 6)), rng.normal(size=(23, 6)), rng.normal(size=(2, 23))
    tau, hk = 0.013, -0.0021
    pose.s[K_HEIGHT] = hk
    hh, hz, zz, means = pose._information(jk, jc, moved, tau)

    def c(a):
        return a - a.mean()

    def rows(a, b):                                # a feature's axial row, then its lateral one
        return np.concatenate([c(a), c(b)])

    d = jc - jk
    z = rows(moved[1] - d[:, 1] * tau - d[:, 3] * hk, -moved[0] - d[:, 0] * tau - d[:, 2] * hk)
    H = np.column_stack([rows(jc[:, 1], jc[:, 0]), rows(jc[:, 3], jc[:, 2]), rows(jc[:, 5], jc[:, 4]),
                         -rows(jk[:, 1], jk[:, 0]), -rows(jc[:, 3], jc[:, 2]), -rows(jk[:, 5], jk[:, 4])])
    assert np.allclose(hh, H.T @ H, rtol=1e-12, atol=1e-12)
    assert np.allclose(hz, H.T @ z, rtol=1e-12, atol=1e-12)
    assert zz == pytest.approx(z @ z, rel=1e-12)
    assert np.allclose(means[:6], [jc[:, 1].mean(), jc[:, 3].mean(), jc[:, 5].mean(),
                                   -jk[:, 1].mean(), -jc[:, 3].mean(), -jk[:, 5].mean()])
    assert np.allclose(means[7:13], [jc[:, 0].mean(), jc[:, 2].mean(), jc[:, 4].mean(),
                                     -jk[:, 0].mean(), -jc[:, 2].mean(), -jk[:, 4].mean()])


def test_the_prior_free_reading_is_the_least_squares_solution():
    from crawler.posemodel import least_squares

    rng = np.random.default_rng(2)
    H, z = rng.normal(size=(40, 6)), rng.normal(size=40)
    hh, hz = H.T @ H, H.T @ z
    for k in ([0, 1, 2], [0, 2], [1]):             # all three in plain floats; fewer through OpenCV
        x = np.linalg.solve(hh[np.ix_(k, k)], hz[k])
        read, diag, explained = least_squares(hh, hz, k)
        assert np.allclose(read, x) and np.allclose(diag, np.diag(np.linalg.inv(hh[np.ix_(k, k)])))
        assert explained == pytest.approx(x @ hz[k])
    assert least_squares(np.zeros((6, 6)), hz, [0, 1, 2]) is None


def _synthetic_run(params, keyframes=6):
    """PoseFix of each frame of a smooth synthetic run: keyframes on the frame just measured, 90 fps."""
    from types import SimpleNamespace

    from crawler.geometry import make_projection
    from crawler.measurement import recording_camera, thesis_roi
    from crawler.pose import PoseEstimator

    cam = recording_camera(S.CameraSettings())
    roi = thesis_roi(cam.width, cam.height)
    pose = PoseEstimator(cam, make_projection("cylinder", S.MountSettings(tilt_deg=24.0).mount()), roi, params)
    rng = np.random.default_rng(5)
    pts = rng.uniform(30, 330, size=(25, 2)).astype(np.float32)
    both, idx = np.ones(25, bool), np.arange(25)
    fixes, t = [], 0.0
    for k in range(keyframes):
        kf = SimpleNamespace(pts=pts, t_s=t, distance=0.0)
        pose.keyframe(kf, pts.astype(np.float64) + roi[:2], t)
        for j in (1, 2, 3):
            t += 1 / 90
            moved = np.vstack([rng.normal(0, 1e-5, 25), 0.003 * j + rng.normal(0, 2e-5, 25)])
            c = SimpleNamespace(idx=idx, pts=pts + np.float32([0.0, 2.0 * j]), tracks=(idx, pts, moved, both),
                                sigma=2e-5, step=0.003 * j, lat=0.0)
            fixes.append((t, pose.measure(kf, c, t)))
    return fixes


def test_a_refined_keyframe_pose_is_not_a_rescale():
    """The estimator refines the step that ended at the keyframe as its pose becomes better known
    (base_m, micrometres, on most frames). That is no re-measure at a new tilt (rescaled_m): the
    gap bridge and the speed filter would read the re-measure's shape as a ramp (with it, a brake
    before a gap was never read: all-at-once +15 %), and rebuild their windows on every frame."""
    from crawler.pose import PoseParams

    fixes = [f for _, f in _synthetic_run(PoseParams(warm_up_s=0.0))]
    assert any(abs(f.base_m) > 0 for f in fixes)       # the keyframe's pose refined...
    assert all(f.rescaled_m == 0.0 for f in fixes)     # ...never a rescale at a configured tilt


def test_the_pitch_and_height_correct_nothing_while_their_levels_are_learned():
    """For warm_up_s after the first measured frame the levels are still the configured prior's: a
    smooth run's first keyframes would take up model noise as pitch (the demo: -0.023 % instead of
    -0.003 %), so nothing is corrected until then."""
    from crawler.pose import PoseParams

    fixes = _synthetic_run(PoseParams(warm_up_s=0.1), keyframes=12)
    early = [f for t, f in fixes if t < 0.1]
    late = [f for t, f in fixes if t >= 0.1]
    assert early and all(f.step_m == 0.0 and f.base_m == 0.0 for f in early)
    assert any(f.step_m != 0.0 for f in late)


def _keyframe(pose, cam, roi, seen, wall, t, frames, rng, projection=None):
    """A keyframe of these wall points at t and its next frames at 30 fps (`seen(wall, t)`: their
    ROI pixels then, 0.05 px of noise), each measured: (frame, consensus) per frame."""
    from types import SimpleNamespace

    kpx = seen(wall, t)
    kf = SimpleNamespace(pts=kpx.astype(np.float32), t_s=t, distance=0.0)
    pose.keyframe(kf, kpx + roi[:2], t)
    for j in range(1, frames + 1):
        px = seen(wall, t + j / 30) + rng.normal(0, 0.05, kpx.shape)
        yield j, _measured(pose, kf, cam, roi, projection or pose.projection, kpx, px, t + j / 30)


def _measured(pose, kf, cam, roi, projection, kpx, px, t_s):
    """One frame measured as the odometer does (every track an inlier, wall positions at the
    projection it measures with), handed to the pose estimator: the consensus."""
    from types import SimpleNamespace

    moved = (projection.to_wall(cam.normalise(kpx + roi[:2])) - projection.to_wall(cam.normalise(px + roi[:2]))).T
    moved *= [[-1.0], [1.0]]
    idx, both = np.arange(len(px)), np.ones(len(px), bool)
    c = SimpleNamespace(idx=idx, pts=px.astype(np.float32), tracks=(idx, px, moved, both),
                        sigma=float(np.std(moved[1])), step=float(moved[1].mean()), lat=float(moved[0].mean()))
    pose.measure(kf, c, t_s)
    return c


def _weaving_run(params, sway_mm=2.0, tilt_deg=40.0):
    """A car at 0.04 m/s, 30 fps, that weaves sway_mm across the pipe (0.5 Hz) and neither pitches
    nor bounces: exact image points of fixed wall points, measured as the odometer does (wall
    positions at the configured mount). (true pitch of the estimate, its worst pitch, the worst
    error of its corrected step against the truth)."""
    from dataclasses import replace

    from crawler.geometry import make_projection
    from crawler.measurement import recording_camera, thesis_roi
    from crawler.pose import PoseEstimator

    cam = recording_camera(S.CameraSettings())
    roi = thesis_roi(cam.width, cam.height)
    mount = S.MountSettings(tilt_deg=tilt_deg).mount()
    nominal = make_projection("cylinder", mount)
    pose = PoseEstimator(cam, nominal, roi, params)
    rng = np.random.default_rng(7)

    def seen(wall, t):                     # ROI pixels of wall points (s, y ahead of the car's start)
        true = make_projection("cylinder", replace(mount, sway_m=sway_mm / 1000 * math.sin(math.pi * t)))
        rel = wall - [0.0, 0.04 * t]
        return cam.to_pixels(true.to_image(rel)) - roi[:2]

    pitch, err, t = [], [], 0.0
    for k in range(12):                    # keyframes of 10 frames: 1 cm of wall each
        centre = nominal.to_wall(cam.normalise(np.array([[roi[0] + roi[2] / 2, roi[1] + roi[3] / 2]])))[0]
        wall = centre + rng.uniform(-1, 1, (30, 2)) * [0.012, 0.006] + [0.0, 0.04 * t]
        for j, c in _keyframe(pose, cam, roi, seen, wall, t, 10, rng, nominal):
            pitch.append(abs(math.degrees(pose.s[0])))
            err.append(abs(c.step - 0.04 * j / 30))
        t += 10 / 30
    return max(pitch[30:]), max(err[30:])


def test_a_weaving_car_is_not_read_as_pitching():
    """In a cylinder a sideways camera shift bends the view as well as shifting it along the arc:
    the rays meet the curved wall at other depths, an axial pattern across the image. Left out of
    the model (sway_sigma_mm = 0), 2 mm of weave at 40 deg are read as pitch (3x the pitch the
    model with the sway reads, where there is none) and the corrected steps err 3x as much."""
    from crawler.pose import PoseParams

    params = PoseParams(warm_up_s=0.0)
    pitch, err = _weaving_run(params)
    pitch_blind, err_blind = _weaving_run(PoseParams(warm_up_s=0.0, sway_sigma_mm=0.0))
    assert pitch < 0.02 and pitch_blind > 2 * pitch
    assert err < err_blind


def test_check_takes_no_abbreviated_flags_and_check_config_refuses_what_a_run_would(crawlerd, render_run):
    # `calibrate check --tilt 20` once read as --tilt-tolerance 20: a PASS for any tilt within 20 deg
    run = render_run("auto24", tilt_deg=24, speed_m_s=0.3, duration_s=3.0, seed=54)
    from crawler.calibrate import main as calibrate_main

    assert calibrate_main(["check", str(run["h264"]), "--tilt", "20"]) == 2
    rc, _, err = crawlerd("--check-config", "--tilt", "auto", "--method", "pixel")
    assert rc == 2 and "needs [odometry] method" in err



def test_tilt_auto_on_the_live_window_reads_the_rolling_shutter_as_time_not_tilt(crawlerd, tmp_path):
    # the simulated camera's live 240x240 window, read out over ~4.5 ms: rows read later moved for
    # longer, which, not undone in the tilt readings, read as 0.3 deg of tilt (+0.3 % of distance)
    rc, s, err = crawlerd("--sim", "--no-publish", "--max-frames", 400, "--tilt", "auto", "--sim-tilt", 24,
                          "--sim-sensor", "imx219", "--state-dir", tmp_path)
    assert rc == 0, err
    assert abs(s["pose"]["tilt_deg"] - 24.0) < 0.1
    assert abs(s["distance_m"] - s["sim_true_distance_m"]) / s["sim_true_distance_m"] < 0.001


def test_a_restarted_daemon_resumes_tilt_auto_at_its_estimate(crawlerd, tmp_path):
    # the checkpoint keeps the tilt once found: the next run measures at it from its first frame,
    # where a cold start would still be at 0 deg (the search needs three keyframes of motion, some 90 frames)
    args = ("--sim", "--no-publish", "--tilt", "auto", "--sim-tilt", 24, "--state-dir", tmp_path)
    rc, s, err = crawlerd(*args, "--max-frames", 240)
    assert rc == 0, err
    assert abs(s["pose"]["tilt_deg"] - 24.0) < 0.1
    saved = json.loads((tmp_path / "checkpoint.json").read_text())["tilt"]
    assert abs(saved["deg"] - 24.0) < 0.1 and saved["sigma_deg"] >= 0
    rc, s, err = crawlerd(*args, "--max-frames", 20)
    assert rc == 0, err
    assert abs(s["pose"]["tilt_deg"] - 24.0) < 0.3          # (the readings go on refining it)


def test_a_checkpoint_tilt_that_is_not_a_tilt_is_dropped_not_fatal():
    from crawler.checkpoint import validate

    base = {"distance_m": 1.0, "run_id": "abcdef12", "frames": 3}
    for bad in ({"deg": float("nan"), "sigma_deg": 0.1}, {"deg": 120.0, "sigma_deg": 0.1}, "24", {"deg": 24.0}):
        assert "tilt" not in validate(dict(base, tilt=bad))
    assert validate(dict(base, tilt={"deg": 24.0, "sigma_deg": 0.02}))["tilt"]["deg"] == 24.0


def test_the_ride_height_reads_a_bank_of_sediment_that_reads_long_without_it(render_run, crawlerd, tmp_path):
    """12 mm of sediment over 0.4 m lifts the camera 5 % nearer the wall: every metre there reads
    5 % long without `[odometry] ride_height`; with it (the default at 24 deg, and with tilt auto
    up to 30 deg) the chain of height changes carries the level."""
    run = render_run("sediment", tilt_deg=24, speed_m_s=0.2, duration_s=6.0, seed=63, bounce_mm=0.5,
                     height_profile=((0.2, 0.0), (0.4, 12.0), (0.8, 12.0), (1.0, 0.0)))
    path = run["truth"]["path_length_m"]

    def error_pct(s):
        return 100 * (s["distance_m"] - run["truth"]["true_distance_m"]) / path

    s, _, _ = replay(crawlerd, run, tmp_path, "--tilt", "24", "--set", "odometry.ride_height=false")
    assert error_pct(s) > 1.0                                  # the bank read long
    s, rows, truth = replay(crawlerd, run, tmp_path, "--tilt", "24")
    assert abs(error_pct(s)) < 0.3
    d = np.array([r["distance_m"] for r in rows])
    est, true = np.array([r["camera_height_m"] for r in rows]), truth["camera_height_m"][:len(rows)]
    plateau = (d > 0.5) & (d < 0.75)
    assert plateau.any() and np.all(np.abs(est[plateau] - true[plateau]) < 3e-3)
    err = np.abs(d - truth["distance_m"][:len(rows)])           # the level's own sigma is in sigma_m
    assert np.mean(err <= 2 * np.array([r["sigma_m"] for r in rows])) >= 0.95
    # with tilt auto too, once the tilt is found (before session 20 it had none: +2.59 %, 28 % within 2 sigma)
    s, rows, truth = replay(crawlerd, run, tmp_path, "--tilt", "auto")
    assert abs(error_pct(s)) < 0.5 and min(r["camera_height_m"] for r in rows) < 0.2256 - 0.008
    err = np.abs(np.array([r["distance_m"] for r in rows]) - truth["distance_m"][:len(rows)])
    assert np.mean(err <= 2 * np.array([r["sigma_m"] for r in rows])) >= 0.9


def test_tilt_auto_decides_the_ride_height_once_per_tilt_found(render_run, crawlerd, tmp_path, monkeypatch):
    """The bank's rise moves tilt auto's estimate up by ~0.7 deg. A gate on the estimate near the
    limit closed on the climb and lost the rise (a review: 29.5 deg +1.55 %, 30 deg +2.32 %); the
    limit put just above this 24 deg run's tilt shows it."""
    import crawler.measurement as measurement

    monkeypatch.setattr(measurement, "RIDE_MAX_TILT_DEG", 24.45)
    run = render_run("sediment", tilt_deg=24, speed_m_s=0.2, duration_s=6.0, seed=63, bounce_mm=0.5,
                     height_profile=((0.2, 0.0), (0.4, 12.0), (0.8, 12.0), (1.0, 0.0)))
    s, rows, _ = replay(crawlerd, run, tmp_path, "--tilt", "auto")
    assert max(r["tilt_deg"] for r in rows) > 24.45                    # the estimate crossed the limit...
    assert 100 * abs(s["distance_m"] - run["truth"]["true_distance_m"]) / run["truth"]["path_length_m"] < 0.5


def _shaking_tilt_run(pitch_deg=0.3, bounce_mm=1.0, sway_mm=2.0, tilt_deg=40.0, keyframes=60, seed=11):
    """Tilt auto on a car at 0.1 m/s, 30 fps, that pitches (3.1 Hz), bounces (2.3 Hz) and weaves
    (0.5 Hz): exact image points of fixed wall points, measured as the odometer does (wall
    positions at the mount it measures with), a keyframe every 6 frames (2 cm). Starts as a
    restarted daemon would, 0.5 deg off; the tilt it ends at, in degrees off the truth."""
    from dataclasses import replace

    from crawler.geometry import make_projection
    from crawler.measurement import recording_camera, thesis_roi
    from crawler.pose import PoseEstimator, PoseParams

    cam = recording_camera(S.CameraSettings())
    roi = thesis_roi(cam.width, cam.height)
    mount = S.MountSettings(tilt_deg=tilt_deg).mount()
    pose = PoseEstimator(cam, make_projection("cylinder", S.MountSettings(tilt_deg=0.0).mount()), roi,
                         PoseParams(auto_tilt=True, pitch_sigma_deg=0.0, bounce_sigma_mm=0.0, sway_sigma_mm=0.0))
    pose.resume({"deg": tilt_deg + 0.5})
    rng = np.random.default_rng(seed)
    speed = 0.1

    def seen(wall, t):                     # ROI pixels of wall points (s, y ahead of the car's start)
        true = make_projection("cylinder", replace(
            mount, tilt_rad=mount.tilt_rad + math.radians(pitch_deg * math.sin(2 * math.pi * 3.1 * t + seed)),
            height_m=mount.height_m + bounce_mm / 1000 * math.sin(2 * math.pi * 2.3 * t + 2 * seed),
            sway_m=sway_mm / 1000 * math.sin(math.pi * t)))
        return cam.to_pixels(true.to_image(wall - [0.0, speed * t])) - roi[:2]

    t = 0.0
    for k in range(keyframes):
        nominal = pose.projection
        x, y, w, h = roi
        start = np.column_stack([x + rng.uniform(0, w, 30), y + rng.uniform(0, h / 2, 30)])
        wall = nominal.to_wall(cam.normalise(start)) + [0.0, speed * t]
        for _ in _keyframe(pose, cam, roi, seen, wall, t, 6, rng):
            pass
        t += 6 / 30
    return pose.tilt_deg - tilt_deg


def test_tilt_auto_on_a_shaking_car_cancels_the_pitch_and_bounce_and_takes_out_the_sway():
    """A change of pitch or height between a keyframe and a frame puts a row profile into the
    steps that reads as a tilt (0.3 deg of pitch: ~2 deg at 40 deg). The next keyframe starts
    where a keyframe closes, so read on the close and weighed by travel those changes telescope;
    the sway's lateral pattern is fitted out (left in, 2 mm read as ~0.1 deg, always one way).
    Before, over the same four runs each: 0.60, 0.44 and 0.34 deg r.m.s., and the sway 0.1 deg."""
    def rms(**shake):
        return math.sqrt(np.mean([_shaking_tilt_run(seed=s, **shake) ** 2 for s in range(4)]))

    assert rms() < 0.3
    assert rms(bounce_mm=0.0, sway_mm=0.0) < 0.25           # the pitch alone
    assert rms(pitch_deg=0.0, sway_mm=0.0) < 0.15           # the bounce alone
    assert rms(pitch_deg=0.0, bounce_mm=0.0) < 0.03         # the weave alone


def test_the_tilt_sigma_counts_consecutive_readings_that_cancel():
    """Consecutive readings share a frame, so the car's pitch there pushes them apart alike: their
    mean is far better than their scatter over their count says, and the sigma knows it."""
    from crawler.tilt import TiltTrack

    rng = np.random.default_rng(3)
    p = np.radians(rng.normal(0.0, 0.3, 41))
    track = TiltTrack(0.0, sigma=math.radians(3.0))
    for n in range(40):
        least = 4.0 * (p[n] - p[n + 1])              # ~2.4 deg of scatter, telescoping
        assert track.add(1.0, -2.0 * least, 0.0, 0.2 * n) is None
    naive = math.sqrt(track._scatter / track._n)
    assert math.sqrt(track.var) < 0.5 * naive
    assert abs(track.value) < 3 * math.sqrt(track.var)


def test_a_step_measured_again_at_the_found_tilt_reads_its_tracks_as_the_odometer_does():
    """Found at 40 deg after measuring at 0, a keyframe's step is measured again with the tracks
    the odometer chose at 0 deg; one that agreed only there must not pull it (the inliers' mean)."""
    from crawler.autotilt import AutoTilt
    from crawler.tiltport import Hop
    from crawler.geometry import make_projection
    from crawler.measurement import recording_camera, thesis_roi
    from crawler.tilt import TiltTrack

    cam = recording_camera(S.CameraSettings())
    roi = thesis_roi(cam.width, cam.height)
    old = make_projection("cylinder", S.MountSettings(tilt_deg=0.0).mount())
    true = make_projection("cylinder", S.MountSettings(tilt_deg=40.0).mount())
    rng = np.random.default_rng(5)
    x, y, w, h = roi
    xy_c = cam.normalise(np.column_stack([x + rng.uniform(0, w, 20), y + rng.uniform(0, h / 2, 20)]))
    wall = true.to_wall(xy_c) + [0.0, 0.01]           # a 10 mm step
    wall[0, 1] += 0.004                                # one track found the wrong texture
    xy_k = true.to_image(wall)
    dy = old.to_wall(xy_k)[:, 1] - old.to_wall(xy_c)[:, 1]
    tilt = AutoTilt(cam, old, roi)
    tilt.track = TiltTrack(math.radians(40.0), sigma=math.radians(0.1))
    tilt.tau = math.radians(40.0)
    hop = Hop(0.7, old, xy_k, xy_c, dy, (0.0, 0.0, 0.0, 0.0), float(np.mean(dy)), 0.0)
    tilt.hops = [hop]
    new, extra = tilt.remount()
    assert new is not None and abs(new.mount.tilt_deg - 40.0) < 1e-9
    assert abs(hop.d - 0.01) < 1e-6                    # the plain mean: 0.0102
    assert abs(hop.d - float(np.mean(dy)) - extra) < 1e-12
    assert tilt.epoch == (hop.d, 0.7)                  # a gap bridged since 0.7 s scales with it (gaps.py)


def test_the_pitch_a_car_shows_beyond_the_configured_is_said_in_sigma():
    """The pose filter holds the car's pitch to the configured level (`pitch_jitter_deg`, 0.25 deg)
    so that a smooth run gets none it does not show; a car that pitches 0.6 deg moves each frame's
    distance by more than it can follow. What the tracks show goes into every frame's sigma
    (crawler/gaps.py): on photographed gravel with 0.5 deg of pitch 68-85 % of frames were within
    2 sigma before."""
    from dataclasses import replace

    from crawler.geometry import make_projection
    from crawler.measurement import recording_camera, thesis_roi
    from crawler.pose import PoseEstimator, PoseParams

    cam = recording_camera(S.CameraSettings())
    roi = thesis_roi(cam.width, cam.height)
    mount = S.MountSettings(tilt_deg=24.0).mount()

    def shown(pitch_deg):
        pose = PoseEstimator(cam, make_projection("cylinder", mount), roi, PoseParams(pitch_sigma_deg=0.25))
        rng = np.random.default_rng(4)

        def seen(wall, t):
            true = make_projection("cylinder", replace(
                mount, tilt_rad=mount.tilt_rad + math.radians(pitch_deg * math.sin(2 * math.pi * 1.5 * t))))
            return cam.to_pixels(true.to_image(wall - [0.0, 0.2 * t])) - roi[:2]

        t = 0.0
        for _ in range(40):
            x, y, w, h = roi
            start = np.column_stack([x + rng.uniform(0, w, 30), y + rng.uniform(0, h / 2, 30)])
            wall = pose.projection.to_wall(cam.normalise(start)) + [0.0, 0.2 * t]
            for _ in _keyframe(pose, cam, roi, seen, wall, t, 4, rng):
                pass
            t += 4 / 30
        return math.degrees(pose.pitch_shown_rad)

    assert shown(0.6 * math.sqrt(2)) > 0.45          # 0.6 deg r.m.s.: shown, beyond the 0.25 configured
    assert shown(0.0) < 0.05                          # a still car: nothing


def test_the_bridge_counts_the_pitch_shown_when_it_is_above_the_configured():
    from types import SimpleNamespace

    from crawler.gaps import BridgeParams, GapBridge

    def last_sigma(pitch_m):
        bridge = GapBridge(BridgeParams(pose_sigma_m=0.001))
        for k in range(30):
            b = bridge.update(SimpleNamespace(t_s=k / 30, distance_m=0.01 * k, tracking=True, continuous=True,
                                              keyframe=k % 5 == 0, spread_mm=0.02, inliers=40, speed_m_s=None,
                                              pitch_m=pitch_m))
        return b.sigma_m

    assert last_sigma(0.0) == last_sigma(0.0005) < 0.0015     # below the configured: the configured
    assert last_sigma(0.003) > 0.003                          # above it: what the tracks show


def test_an_operator_reset_ends_tilt_auto_s_epoch():
    """After a reset the distance counts afresh: a better tilt found later measures only the steps
    since it again (before, the steps of the old count were measured again into the new one)."""
    from crawler.tiltport import Hop
    from crawler.geometry import make_projection
    from crawler.measurement import recording_camera, thesis_roi
    from crawler.odometry import Odometer
    from crawler.pose import PoseEstimator, PoseParams

    cam = recording_camera(S.CameraSettings())
    roi = thesis_roi(cam.width, cam.height)
    projection = make_projection("cylinder", S.MountSettings(tilt_deg=0.0).mount())
    pose = PoseEstimator(cam, projection, roi, PoseParams(auto_tilt=True))
    odometer = Odometer(cam, projection, roi, pose=pose)
    hop = Hop(1.0, projection, np.zeros((3, 2)), np.zeros((3, 2)), np.zeros(3), (0.0,) * 4, 0.05, 0.01)
    pose.tilt.hops = [hop, hop]
    assert pose.tilt.epoch_m == pytest.approx(0.1)
    odometer.set_distance(0.0)
    assert pose.tilt.hops == [] and pose.tilt.epoch_m == 0.0


def test_a_reading_too_unsure_of_itself_is_no_turn_of_the_camera():
    """At a wet edge's keyframes, two readings in a row 4 deg off the tilt, each with 3.4-3.8 deg of
    its own (what no tilt explains in its tracks' disagreement), were taken for a turn: the search
    moved the camera 2 deg and the keyframe it forced read a stand (-29.9 % of the path). A reading
    within twice its own sigma says nothing; a sure one is a turn as before."""
    from crawler.tilt import TiltTrack

    def turned(own_deg):
        track = TiltTrack(0.0, sigma=math.radians(0.4))
        rng = np.random.default_rng(4)
        for n in range(10):                           # the tilt, read within 0.4 deg
            least = math.radians(rng.normal(0.0, 0.4))
            assert track.add(1.0, -2.0 * least, 0.0, 0.2 * n) is None
        off = math.radians(4.0)
        return [track.add(1.0, -2.0 * off, 0.0, 2.0 + 0.2 * k, math.radians(own_deg)) for k in range(2)]

    assert turned(3.6) == [None, None]
    assert turned(0.1)[1] is not None                # a turn (begun where the readings last agreed)


def test_an_operator_reset_carries_the_ride_height_s_keyframe_into_the_new_count():
    """The ride height reads each keyframe's travel from its distance at the keyframe before; a
    reset shifts the odometer's distances, and that one with them (a review: after a reset to 0 at
    1.4 m the next handover read 1.37 m of travel, and sigma_m tripled)."""
    from crawler.geometry import make_projection
    from crawler.measurement import recording_camera, thesis_roi
    from crawler.pose import PoseEstimator, PoseParams

    cam = recording_camera(S.CameraSettings())
    pose = PoseEstimator(cam, make_projection("cylinder", S.MountSettings(tilt_deg=24.0).mount()),
                         thesis_roi(cam.width, cam.height), PoseParams(ride_height=True))
    pose._kf_at = (1.4, 7.0)
    pose.new_count(-1.4)
    assert pose._kf_at == pytest.approx((0.0, 7.0))


def test_a_sweep_is_told_from_a_still_or_shaking_camera_by_its_trend():
    """tilt.SweepWatch: readings every 0.13 s along a turn of 2.7 deg/s (0.05 deg of noise) are a
    sweep within a second and give its rate; a shaking car's readings, alternating 2 deg about a
    still tilt (consecutive readings share a frame: its pitch pushes them apart), never are; the
    sweep ends when the readings stand still again."""
    from crawler.tilt import SweepWatch

    rng = np.random.default_rng(3)
    watch, t = SweepWatch(), 0.13 * np.arange(60)
    turn = np.radians(24 + 2.7 * np.clip(t - 1.0, 0, 4.0) + rng.normal(0, 0.05, len(t)))
    moving, rates = [], []
    for ti, yi in zip(t, turn):
        moving.append(watch.add(ti, yi))
        rates.append(math.degrees(watch.line[2]) if watch.line else None)
    first = moving.index(True)
    assert t[first] < 2.2 and not any(moving[:8])
    assert rates[first + 5] == pytest.approx(2.7, abs=0.2)
    during = [i for i in range(first, 40) if moving[i]]
    assert len(during) > 15
    assert not moving[-1]                                  # 3 s after the turn ended
    shake = SweepWatch()
    alternating = np.radians(24 + 2.0 * (-1) ** np.arange(60) + rng.normal(0, 0.3, 60))
    assert not any(shake.add(ti, yi) for ti, yi in zip(t, alternating))
    # a trend over keyframes of a few frames each, or of readings unsure of themselves, is none
    # (CRF 40 on a still camera: 25.6 -> 29.8 deg in 0.14 s, each reading 3 deg unsure)
    burst = np.radians([25.58, 26.41, 28.06, 29.55, 29.8])
    assert not any(SweepWatch().add(ti, yi) for ti, yi in zip(7.53 + 0.035 * np.arange(5), burst))
    unsure = SweepWatch()
    assert not any(unsure.add(ti, yi, None, math.radians(3.0)) for ti, yi in zip(t, turn))


def test_tilt_auto_follows_a_camera_turned_slowly_and_does_not_read_the_turn_as_travel(render_run, crawlerd, tmp_path):
    """A sweep (24 -> 30 deg over 3 s) is too slow for a step and too fast for a mount's creep. The
    turn moves the view along the wall as travel does, and the epoch measured again at the tilt
    reached took the steps before it there too: before session 20 +2.0 %, ending 0.5 deg short."""
    run = render_run("sweep", tilt_deg=24, tilt_schedule=((1.5, 24.0), (4.5, 30.0)), speed_m_s=0.2,
                     duration_s=6.0, seed=75)
    s, rows, truth = replay(crawlerd, run, tmp_path, "--tilt", "auto")
    assert abs(s["pose"]["tilt_deg"] - 30.0) < 0.3 and s["pose"]["tilt_turning"] is False   # over by the end
    assert 100 * abs(s["distance_m"] - run["truth"]["true_distance_m"]) / run["truth"]["path_length_m"] < 0.5


def test_a_sweep_ends_with_the_turn_and_a_jump_after_it_is_a_step():
    """SweepWatch ends a sweep within 0.75 s of the turn's end (a review saw the tilt run on past
    it: 43.5 deg for 40); the track it hands on checks its first readings for a step (a turn that
    ended in a jump of the camera ran to 49.9 deg for 40 when the jump was averaged in)."""
    from crawler.tilt import SweepWatch, TiltTrack

    watch, t = SweepWatch(), 0.13 * np.arange(60)
    turn = np.radians(24 + 2.7 * np.clip(t - 1.0, 0, 4.0))
    moving = [watch.add(ti, yi) for ti, yi in zip(t, turn)]
    after = [ti for ti, m in zip(t, moving) if ti > 5.0 and not m]
    assert any(moving) and after and after[0] < 5.75
    track = TiltTrack(math.radians(40.0), sigma=math.radians(0.05), checked=True)
    jumped = math.radians(50.0)
    assert track.add(1.0, 0.0, jumped, 6.0, 0.001) is None and math.degrees(track.value) == pytest.approx(40.0)
    assert track.add(1.0, 0.0, jumped, 6.1, 0.001) is not None          # two in a row: a step


def test_lost_frames_end_a_sweep_and_a_far_remount_keeps_a_turn_s_keyframe_tilt():
    """A gap may hide anything (a step is found afresh after it), so the sweep watch starts over;
    and a step measured again at a tilt far off drops its pitch and height as the old tilt's
    error, but not the keyframe tilt a sweep gave it (dropped, each such remount added 4-5 mm)."""
    from crawler.autotilt import AutoTilt
    from crawler.tiltport import Hop
    from crawler.geometry import make_projection
    from crawler.measurement import recording_camera, thesis_roi

    cam = recording_camera(S.CameraSettings())
    roi = thesis_roi(cam.width, cam.height)
    proj = make_projection("cylinder", S.MountSettings(tilt_deg=24.0).mount())
    tilt = AutoTilt(cam, proj, roi)
    for i in range(6):
        tilt.sweep.add(0.13 * i, math.radians(24 + 0.3 * i))
    assert tilt.sweep.readings
    tilt.closed(False, 1.0)
    assert not tilt.sweep.readings and not tilt.turning
    rng = np.random.default_rng(5)
    px = np.column_stack([roi[0] + rng.uniform(0, roi[2], 20), roi[1] + rng.uniform(0, roi[3] / 2, 20)])
    xy = cam.normalise(px)
    hop = Hop(1.0, proj, xy, xy, np.zeros(20), (0.001, 0.0005, 0.004, 0.0), 0.0, 0.0, turn=0.003)
    far = make_projection("cylinder", S.MountSettings(tilt_deg=27.0).mount())
    tilt._measure_again(hop, far)
    assert hop.pose == (0.0, 0.0, 0.003, 0.0)


def test_the_status_says_while_the_camera_is_being_turned():
    from crawler.geometry import make_projection
    from crawler.measurement import recording_camera, thesis_roi
    from crawler.pose import PoseEstimator, PoseParams

    cam = recording_camera(S.CameraSettings())
    pose = PoseEstimator(cam, make_projection("cylinder", S.MountSettings(tilt_deg=24.0).mount()),
                         thesis_roi(cam.width, cam.height), PoseParams(auto_tilt=True))
    assert pose.status()["tilt_turning"] is False
    t = 0.13 * np.arange(8)
    for ti in t:                                           # a clean turn at 2.7 deg/s
        pose.tilt.sweep.add(ti, math.radians(24 + 2.7 * ti))
    assert pose.status()["tilt_turning"] is True
