"""crawlerd --replay on hw_sim recordings: accuracy at the thesis tilts, disturbances, bad input."""

import json
import subprocess
import sys

import numpy as np
import pytest

from hw_sim import read_ground_truth

SHORT = dict(duration_s=2.0)


def err_pct(summary, truth):
    return 100 * abs(summary["distance_m"] - truth["true_distance_m"]) / truth["path_length_m"]


@pytest.mark.parametrize("tilt,speed", [(0, 0.2), (24, 0.3), (40, 0.4)])
def test_cylinder_is_exact_at_the_thesis_tilts(render_run, crawlerd, tilt, speed):
    run = render_run(f"tilt{tilt}", tilt_deg=tilt, speed_m_s=speed, **SHORT)
    rc, s, _ = crawlerd("--replay", run["h264"], "--tilt", tilt)
    assert rc == 0 and s["frames"] == run["truth"]["frames"] and s["tracking_share"] == 1.0
    assert err_pct(s, run["truth"]) < 0.3
    assert s["source"].endswith("(found beside the video))")


def test_thesis_method_1_fails_at_40_degrees_as_the_thesis_found(render_run, crawlerd):
    run = render_run("tilt40", tilt_deg=40, speed_m_s=0.4, **SHORT)
    rc, pixel, _ = crawlerd("--replay", run["h264"], "--tilt", 40, "--method", "pixel")
    rc2, plane, _ = crawlerd("--replay", run["h264"], "--tilt", 40, "--method", "plane")
    assert rc == rc2 == 0
    assert err_pct(pixel, run["truth"]) > 10         # thesis: ~20 %
    assert err_pct(plane, run["truth"]) < 5


def test_disturbances_at_24_degrees(render_run, crawlerd):
    run = render_run("shaky", tilt_deg=24, speed_m_s=0.3, bounce_mm=1.0, pitch_jitter_deg=0.3,
                     roll_deg=3.0, sway_mm=2.0, lighting=True, vignetting=True, noise_sigma=2.0,
                     flicker_amp=0.1, drop_prob=0.05, seed=3, **SHORT)
    rc, s, _ = crawlerd("--replay", run["h264"], "--tilt", 24)
    assert rc == 0 and s["tracking_share"] > 0.95
    assert err_pct(s, run["truth"]) < 1.0


def test_rolling_shutter_correction(render_run, crawlerd):
    run = render_run("rs", tilt_deg=0, speed_m_s=0.5, readout_ms=25.0, fps=30, **SHORT)
    rc, raw, _ = crawlerd("--replay", run["h264"])
    rc2, fixed, _ = crawlerd("--replay", run["h264"], "--set", "camera.readout_ms=25.0")
    assert rc == rc2 == 0
    assert err_pct(fixed, run["truth"]) < 0.3
    assert err_pct(raw, run["truth"]) > 3 * err_pct(fixed, run["truth"])


def test_reverse_and_stop_and_go(render_run, crawlerd, tmp_path):
    run = render_run("rev", profile="reverse", speed_m_s=0.2, duration_s=4.0)
    log = tmp_path / "rev.jsonl"
    rc, s, _ = crawlerd("--replay", run["h264"], "--log", log)
    assert rc == 0
    truth = read_ground_truth(run["csv"])
    rows = [json.loads(line) for line in log.read_text().splitlines()]
    est = np.array([r["distance_m"] for r in rows])
    true = np.asarray(truth["distance_m"])
    assert len(rows) == len(true)
    assert np.max(np.abs(est - true)) < 0.002 + 0.003 * np.max(np.abs(true))
    assert min(r["speed_m_s"] for r in rows if r["speed_m_s"] is not None) < -0.15

    run = render_run("stopgo", profile="stopgo", speed_m_s=0.3, duration_s=4.0)
    rc, s, _ = crawlerd("--replay", run["h264"])
    assert rc == 0 and err_pct(s, run["truth"]) < 0.3
    accel = run["truth"]["config"]["accel_m_s2"]
    seen = [r for r in s["drive"].values() if r is not None]           # the ramps the gap model would take
    assert seen and all(abs(r - accel) < 0.15 * accel for r in seen), s["drive"]


def test_a_crawler_that_reverses_inside_a_blackout_is_tracked_again_when_the_light_returns(
        render_run, crawlerd, tmp_path):
    """It brakes from 0.7 m/s and backs off at 0.7 m/s, all at 1.5 m/s^2, in the dark. Light back,
    the phase correlation's shift wraps every 74 mm of wall: the wrap the speed before (+0.63 m/s)
    predicts was 74 mm ahead of the truth, and nothing was tracked again: +1.00 m where it was at
    -0.56 m. A speed that may have changed by half a wrap since it was measured chooses no wrap."""
    run = render_run("rev-dark", profile="reverse", speed_m_s=0.7, accel_m_s2=1.5, duration_s=4.0, tilt_deg=15,
                     led_blackouts=((1.2, 2.0),), seed=3)
    log = tmp_path / "rev-dark.jsonl"
    rc, s, _ = crawlerd("--replay", run["h264"], "--tilt", 15, "--log", log)
    assert rc == 0
    rows = [json.loads(line) for line in log.read_text().splitlines()]
    assert all(r["tracking"] for r in rows if r["t_s"] >= 2.2)
    assert abs(s["distance_m"] - run["truth"]["true_distance_m"]) < 0.05
    assert abs(s["distance_m"] - run["truth"]["true_distance_m"]) < 2 * rows[-1]["sigma_m"]


def test_a_featureless_patch_is_bridged_and_said_so(render_run, crawlerd, tmp_path):
    run = render_run("wet", speed_m_s=0.2, featureless=((0.15, 0.35),), duration_s=3.0)
    log = tmp_path / "wet.jsonl"
    rc, s, _ = crawlerd("--replay", run["h264"], "--log", log)
    assert rc == 0 and s["lost_frames"] > 10
    rows = [json.loads(line) for line in log.read_text().splitlines()]
    lost = [r for r in rows if not r["tracking"]]
    assert all(r["quality"] == 0 and r["speed_m_s"] is None for r in lost)
    assert all(r["bridged"] and r["source"] == "model" for r in lost)       # carried, and said so
    truth = read_ground_truth(run["csv"])
    err = [abs(r["distance_m"] - truth["distance_m"][r["frame"]]) for r in rows]
    assert max(err) < 0.01 and err[-1] < 0.005                            # the gap's distance is not lost
    for a, b in zip(rows, rows[1:]):       # sigma grows with bridged time (a measurement may settle it)
        if a["bridged"] and b["bridged"]:
            assert b["sigma_m"] > a["sigma_m"]
    assert max(r["sigma_m"] for r in lost) > 5 * rows[0]["sigma_m"]
    assert all(e <= 2 * r["sigma_m"] for e, r in zip(err, rows) if r["bridged"])
    assert rows[-1]["tracking"] and not rows[-1]["bridged"]


def test_log_and_annotated_video(render_run, crawlerd, tmp_path):
    import av

    run = render_run("tilt0", tilt_deg=0, speed_m_s=0.2, **SHORT)
    out = tmp_path / "ann.mp4"
    rc, s, _ = crawlerd("--replay", run["h264"], "--annotate", out, "--max-frames", 20)
    assert rc == 0 and s["frames"] == 20
    with av.open(str(out)) as c:
        frames = list(c.decode(video=0))
    assert len(frames) == 20 and frames[0].width == 960
    img = frames[-1].to_ndarray(format="rgb24")
    assert (img[:, :, 1].astype(int) - img[:, :, 0]).max() > 100    # the green ROI box is drawn


def test_bad_input_is_one_line_and_nonzero(render_run, crawlerd, tmp_path):
    run = render_run("tilt0", tilt_deg=0, speed_m_s=0.2, **SHORT)
    rc, s, err = crawlerd("--replay", tmp_path / "missing.h264")
    assert rc == 2 and "not found" in err and "Traceback" not in err and err.count("\n") == 1

    junk = tmp_path / "junk.h264"
    junk.write_bytes(bytes(range(256)) * 64)
    rc, s, err = crawlerd("--replay", junk, "--fps", 30)
    assert rc == 2 and "crawlerd: error:" in err and "Traceback" not in err

    empty = tmp_path / "empty.h264"
    empty.write_bytes(b"")
    rc, s, err = crawlerd("--replay", empty, "--fps", 30)
    assert rc == 2 and ("no decodable frames" in err or "cannot be opened" in err)

    rc, s, err = crawlerd("--replay", tmp_path)
    assert rc == 2 and "is a folder" in err

    rc, s, err = crawlerd("--replay", run["h264"], "--set", "camera.width=640", "--set", "camera.height=480")
    assert rc == 2 and "960x720 but [camera] width/height say 640x480" in err and err.count("\n") == 1

    short_pts = tmp_path / "short.pts"
    short_pts.write_text("# timecode format v2\n" + "".join(f"{i * 33.333:.3f}\n" for i in range(30)))
    rc, s, err = crawlerd("--replay", run["h264"], "--pts", short_pts)
    assert rc == 2 and "has 61 frames but short.pts only 30 timestamps" in err

    back = tmp_path / "back.pts"
    back.write_text("0\n33\n20\n")
    rc, s, err = crawlerd("--replay", run["h264"], "--pts", back)
    assert rc == 2 and "does not increase" in err

    raw = tmp_path / "copy.h264"
    raw.write_bytes(run["h264"].read_bytes())
    rc, s, err = crawlerd("--replay", raw)
    assert rc == 2 and "--pts FILE" in err and "--fps N" in err


def test_frames_lost_inside_a_stream_are_not_passed_over_in_silence(render_run, crawlerd, tmp_path):
    run = render_run("tilt0", tilt_deg=0, speed_m_s=0.2, **SHORT)
    data = bytearray(run["h264"].read_bytes())
    mid = len(data) // 2
    data[mid:mid + 60000] = bytes(60000)          # a hole in the middle of the recording
    holed = tmp_path / "holed.h264"
    holed.write_bytes(data)
    rc, s, err = crawlerd("--replay", holed, "--pts", run["pts"])
    assert s["frames"] < run["truth"]["frames"]
    assert "warning" in err and "speeds) after the gap are wrong" in err
    assert any("after the gap" in w for w in s["warnings"])


def test_truncated_stream_reports_distance_up_to_the_break(render_run, crawlerd, tmp_path):
    run = render_run("tilt0", tilt_deg=0, speed_m_s=0.2, **SHORT)
    cut = tmp_path / "cut.h264"
    data = run["h264"].read_bytes()
    cut.write_bytes(data[: len(data) // 2])
    log = tmp_path / "cut.jsonl"
    rc, s, err = crawlerd("--replay", cut, "--pts", run["pts"], "--log", log)
    assert 10 < s["frames"] < run["truth"]["frames"]
    truth = read_ground_truth(run["csv"])
    # the last, half-decoded frame may be refused as corrupt: measured up to the last good one, the
    # rest bridged by the motion model, and said so
    rows = [json.loads(line) for line in log.read_text().splitlines()]
    last = [r for r in rows if r["tracking"]][-1]
    assert last["frame"] >= s["frames"] - 2
    assert last["distance_m"] == pytest.approx(truth["distance_m"][last["frame"]], abs=2e-4)
    assert all(r["bridged"] for r in rows[last["frame"] + 1:])
    assert s["distance_m"] == pytest.approx(truth["distance_m"][s["frames"] - 1], abs=1e-3)
    assert "warning" in err and "extra timestamps" in err


def test_picamera2_pts_lines_and_fps_flag(render_run, crawlerd, tmp_path):
    run = render_run("tilt0", tilt_deg=0, speed_m_s=0.2, **SHORT)
    pts = tmp_path / "picam.txt"          # picamera2's pts= output: bare millisecond lines
    lines = [ln for ln in run["pts"].read_text().splitlines() if not ln.startswith("#")]
    pts.write_text("\n".join(lines) + "\n")
    rc, a, _ = crawlerd("--replay", run["h264"], "--pts", pts)
    rc2, b, _ = crawlerd("--replay", run["h264"], "--fps", 30)
    assert rc == rc2 == 0
    # the same frame times to the microsecond the lines keep (the pose filter's decay reads them)
    assert a["distance_m"] == pytest.approx(b["distance_m"], abs=5e-6) and "times from --fps 30" in b["source"]


def test_console_script_runs_as_a_subprocess(render_run):
    run = render_run("tilt0", tilt_deg=0, speed_m_s=0.2, **SHORT)
    p = subprocess.run([sys.executable, "-m", "crawler", "--replay", str(run["h264"])],
                       capture_output=True, text=True, timeout=120)
    assert p.returncode == 0, p.stderr
    s = json.loads(p.stdout.strip().splitlines()[-1])
    assert {"frames", "duration_s", "distance_m", "fps_processed"} <= set(s)


def test_roll_about_the_pipe_axis_is_measured(tmp_path):
    from crawler import settings
    from crawler.measurement import build_odometer, recording_camera, thesis_roi
    from hw_sim import SimConfig, Simulator

    sim = Simulator(SimConfig(tilt_deg=10, speed_m_s=0.2, roll_deg=4.0, roll_hz=0.25, duration_s=1.0))
    st = settings.load(None, ["mount.tilt_deg=10"])
    cam = recording_camera(st.camera)
    odo = build_odometer(st, cam, thesis_roi(cam.width, cam.height))
    worst = 0.0
    for f in sim.frames():
        est = odo.update(f.image, f.t_s)
        true_roll = np.degrees(sim.pose(f.t_s)["roll"] - sim.pose(0.0)["roll"])
        worst = max(worst, abs(est.roll_deg - true_roll))
    assert abs(true_roll) > 3.0 and worst < 0.05          # degrees, over a 4 deg swing


def test_lens_distortion_is_removed_from_the_points(render_run, crawlerd):
    k = (-0.25, 0.08, 0.0, 0.0, 0.0)
    run = render_run("barrel", tilt_deg=24, speed_m_s=0.3, distortion=k, **SHORT)
    rc, plain, _ = crawlerd("--replay", run["h264"], "--tilt", 24)
    rc2, fixed, _ = crawlerd("--replay", run["h264"], "--tilt", 24, "--set", f"camera.distortion={list(k)}")
    assert rc == rc2 == 0
    assert err_pct(fixed, run["truth"]) < 0.3
    assert err_pct(plain, run["truth"]) > 3 * err_pct(fixed, run["truth"])


def test_mp4_times_from_the_container(render_run, crawlerd, tmp_path):
    from fractions import Fraction

    import av

    run = render_run("tilt0", tilt_deg=0, speed_m_s=0.2, **SHORT)
    mp4 = tmp_path / "run.mp4"
    with av.open(str(run["h264"])) as src, av.open(str(mp4), "w") as dst:
        stream = dst.add_stream("libx264", rate=Fraction(30))
        stream.width, stream.height, stream.pix_fmt = 960, 720, "yuv420p"
        for i, frame in enumerate(src.decode(video=0)):
            frame.pts, frame.time_base = i, Fraction(1, 30)
            for packet in stream.encode(frame):
                dst.mux(packet)
        for packet in stream.encode():
            dst.mux(packet)
    rc, s, _ = crawlerd("--replay", mp4)
    assert rc == 0 and s["source"].endswith("(times from the container)")
    assert s["duration_s"] == pytest.approx(2.0, abs=1e-3) and err_pct(s, run["truth"]) < 0.3


def test_realtime_replay_paces_frames_to_their_times_on_a_manual_clock(render_run):
    from crawler.measurement import recording_camera
    from crawler.settings import CameraSettings
    from crawler.video import Pacer, VideoReplay

    run = render_run("tilt0", tilt_deg=0, speed_m_s=0.2, **SHORT)
    now = [100.0]
    handed = []

    def sleep(s):
        now[0] += s

    with VideoReplay(run["h264"], recording_camera(CameraSettings()), realtime=True) as src:
        src.pacer = Pacer(clock=lambda: now[0], sleep=sleep)
        for frame in src.frames():
            handed.append((now[0] - 100.0, frame.t_s))
            now[0] += 0.004                      # the loop's own work per frame
    assert len(handed) == 61
    assert all(abs(wall - t) < 0.0045 for wall, t in handed)      # never early, at most one step late
    assert handed[-1][0] == pytest.approx(2.0, abs=0.005)


def test_a_wheel_in_the_config_is_left_out_of_a_replay_and_said_so(render_run, crawlerd, tmp_path, caplog):
    run = render_run("tilt0", tilt_deg=0, speed_m_s=0.2, **SHORT)
    cfg = tmp_path / "wheel.toml"
    cfg.write_text('[wheel]\nbackend = "evdev"\ndevice = "rotary@11"\ncounts_per_m = 1000\n')
    rc, s, err = crawlerd("--replay", run["h264"], "--config", cfg, "--max-frames", 10)
    assert rc == 0 and s["frames"] == 10
    assert "[wheel] is not used in --replay" in caplog.text
