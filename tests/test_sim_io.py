"""hw_sim files and CLI: the .h264/.pts/.csv/.json set, dropped frames, bad values."""
import dataclasses
import json
import math
import subprocess
import sys

import numpy as np
import pytest

from hw_sim import (ConfigError, SimConfig, Simulator, read_ground_truth, read_h264, read_pts,
                    write_run)
from hw_sim.cli import main

SMALL = dict(window=(400, 300, 160, 120), duration_s=1.0, tilt_deg=24.0, speed_m_s=0.3)


@pytest.fixture(scope="module")
def run_with_drops(tmp_path_factory):
    cfg = SimConfig(**SMALL, drop_prob=0.2, seed=7)
    out = tmp_path_factory.mktemp("run")
    return cfg, write_run(cfg, out, "drops")


def test_write_run_files_agree(run_with_drops):
    cfg, paths = run_with_drops
    assert set(paths) == {"h264", "pts", "csv", "json"} and all(p.exists() for p in paths.values())
    assert paths["pts"].read_text().splitlines()[:2] == ["# timecode format v2", "0.000"]
    gt, pts = read_ground_truth(paths["csv"]), read_pts(paths["pts"])
    assert paths["csv"].read_text().splitlines()[0] == ("frame,t_s,distance_m,speed_m_s,tilt_deg,camera_height_m,"
                                                        "led_light,wet,lost_before")
    np.testing.assert_array_equal(gt["frame"], np.arange(len(gt)))
    np.testing.assert_allclose(gt["t_s"], pts, atol=1.5e-6)
    np.testing.assert_allclose(gt["distance_m"], 0.3 * gt["t_s"], atol=1e-8)
    decoded = list(read_h264(paths["h264"]))
    assert len(decoded) == len(gt) and decoded[0].shape == (120, 160)


def test_dropped_frames_leave_gaps(run_with_drops):
    cfg, paths = run_with_drops
    pts = read_pts(paths["pts"])
    steps = np.round(np.diff(pts) * cfg.fps, 3)   # ms with 3 decimals
    assert set(steps) <= {1.0, 2.0, 3.0, 4.0, 5.0} and steps.max() > 1     # gaps of whole frames
    meta = json.loads(paths["json"].read_text())
    assert meta["sensor_frames"] == 31 and meta["frames"] == len(pts) == 31 - meta["dropped_frames"]
    sim = Simulator(cfg)
    frames = list(sim.frames())
    assert [f.index for f in frames] == list(range(len(pts)))
    np.testing.assert_allclose([f.t_s for f in frames], pts, atol=1e-6)
    assert all(f.t_s == f.sensor_index / cfg.fps for f in frames)


def test_h264_round_trip_is_close_to_the_render(run_with_drops):
    cfg, paths = run_with_drops
    rendered = [f.image for f in Simulator(cfg).frames()]
    decoded = list(read_h264(paths["h264"]))
    assert len(decoded) == len(rendered)
    err = np.mean([np.abs(a.astype(float) - b).mean() for a, b in zip(rendered, decoded)])
    assert err < 4.0                                   # crf 18 on a grainy wall: a few DN


def test_sidecar_has_parameters_and_derived_values(run_with_drops):
    cfg, paths = run_with_drops
    meta = json.loads(paths["json"].read_text())
    assert SimConfig.from_dict(meta["config"]) == cfg                     # every parameter
    assert meta["camera_height_m"] == pytest.approx(0.22562, abs=1e-5)
    assert (meta["width"], meta["height"], meta["window"]) == (160, 120, [400, 300, 160, 120])
    assert (meta["vfov_deg"], meta["hfov_deg"], meta["fps"]) == (37.16, 53.5, 30.0)
    assert meta["fy"] == pytest.approx(360 / math.tan(math.radians(37.16 / 2)))
    assert (meta["cx"], meta["cy"]) == (pytest.approx(79.5), pytest.approx(59.5))
    assert meta["distortion"] == [0.0] * 5 and meta["mm_per_texel"] == 0.2
    assert meta["mm_per_texel_circumferential"] == pytest.approx(0.2, rel=0.01)
    gt = read_ground_truth(paths["csv"])
    assert meta["true_distance_m"] == pytest.approx(gt["distance_m"][-1], abs=1e-8)
    assert meta["files"] == {k: p.name for k, p in paths.items()}


def test_cropped_scaled_window_run(tmp_path):
    cfg = SimConfig(window=(160, 120, 640, 480), output_size=(160, 120), duration_s=0.1)
    paths = write_run(cfg, tmp_path, "crop")
    frames = list(read_h264(paths["h264"]))
    assert len(frames) == 4 and frames[0].shape == (120, 160)
    meta = json.loads(paths["json"].read_text())
    assert meta["fx"] == pytest.approx(480 / math.tan(math.radians(53.5 / 2)) / 4)


def test_failed_run_leaves_no_files(tmp_path):
    def stop_after_two(done, total):
        if done == 2:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        write_run(SimConfig(**SMALL), tmp_path, "cut", progress=stop_after_two)
    assert list(tmp_path.iterdir()) == []


# --- bad values ---------------------------------------------------------------------------------

@pytest.mark.parametrize("field,value", [
    ("car_width_m", 0.35), ("speed_m_s", -0.1), ("tilt_deg", 61.0), ("tilt_deg", -75.0),
    ("fps", 0.0), ("duration_s", -1.0), ("window", (0, 0, 961, 720)), ("output_size", (321, 240)),
    ("distortion", (0.1, 0.2)), ("profile", "zigzag"), ("drop_prob", 1.0), ("exposure_ms", 40.0),
    ("featureless", ((2.0, 1.0),)), ("camera_height_m", 0.5), ("crf", 60), ("stopgo_dwell_s", 3.0),
    ("seed", -1), ("noise_sigma", float("nan")), ("lighting", "yes"),
])
def test_bad_values_raise_naming_the_value(field, value):
    with pytest.raises(ConfigError) as e:
        SimConfig(**{field: value})
    assert e.value.field == field and str(e.value).startswith(f"{field}=")
    assert isinstance(e.value, ValueError)


def test_config_is_frozen_and_round_trips():
    cfg = SimConfig(featureless=[[1, 2]], window=[0, 0, 480, 360], distortion=[0.1, 0, 0, 0, 0])
    assert cfg.featureless == ((1.0, 2.0),) and cfg.window == (0, 0, 480, 360)
    with pytest.raises(dataclasses.FrozenInstanceError):
        cfg.tilt_deg = 3.0
    assert SimConfig.from_dict(json.loads(json.dumps(cfg.to_dict()))) == cfg
    with pytest.raises(ConfigError, match="not a SimConfig field"):
        SimConfig.from_dict({"tilt": 3})


# --- CLI ----------------------------------------------------------------------------------------

@pytest.mark.parametrize("argv,needle", [
    (["--car-width", "0.4"], "car_width_m=0.4"),
    (["--speed", "-1"], "speed_m_s=-1.0"),
    (["--tilt", "70"], "tilt_deg=70.0"),
    (["--tilt", "steep"], "'steep'"),
    (["--window", "1,2,3"], "'1,2,3'"),
    (["--featureless", "1-2"], "'1-2'"),
    (["--bogus"], "--bogus"),
])
def test_cli_bad_values_exit_2_with_one_line(tmp_path, capsys, argv, needle):
    rc = main(["render", "--out", str(tmp_path), "--name", "x", *argv])
    err = capsys.readouterr().err
    assert rc == 2
    assert err.count("\n") == 1 and err.startswith("hw_sim: error: ") and needle in err
    assert not any(tmp_path.iterdir())


def test_cli_renders_and_prints_a_json_summary(tmp_path):
    cmd = [sys.executable, "-m", "hw_sim", "render", "--out", str(tmp_path), "--name", "cli",
           "--tilt", "24", "--speed", "0.2", "--duration", "0.5", "--window", "400,300,160,120",
           "--featureless", "0.01:0.02", "--lighting"]
    res = subprocess.run(cmd, capture_output=True, text=True, timeout=60)
    assert res.returncode == 0, res.stderr
    assert res.stderr == ""                                 # no progress when not a terminal
    summary = json.loads(res.stdout)
    assert summary["frames"] == 16 and summary["true_distance_m"] == pytest.approx(0.1)
    assert {k for k in summary} >= {"h264", "pts", "csv", "json"}
    meta = json.loads((tmp_path / "cli.json").read_text())
    assert meta["config"]["featureless"] == [[0.01, 0.02]] and meta["config"]["lighting"] is True


def test_cli_bad_value_in_a_subprocess_has_no_traceback(tmp_path):
    res = subprocess.run([sys.executable, "-m", "hw_sim", "render", "--out", str(tmp_path), "--name", "x",
                          "--car-width", "0.5"], capture_output=True, text=True, timeout=60)
    assert res.returncode == 2 and res.stdout == ""
    assert res.stderr.splitlines() == [
        "hw_sim: error: car_width_m=0.5 must be smaller than pipe_diameter_m=0.3 "
        "(the car must fit in the pipe) (--car-width)"]


def test_cli_params_table_lists_every_field(capsys):
    assert main(["params"]) == 0
    table = capsys.readouterr().out
    for f in dataclasses.fields(SimConfig):
        assert f"`{f.name}`" in table


def test_cli_bad_name_exits_2(tmp_path, capsys):
    assert main(["render", "--out", str(tmp_path), "--name", "a/b", "--duration", "0.1"]) == 2
    assert capsys.readouterr().err == "hw_sim: error: name='a/b' must be a plain file name\n"
