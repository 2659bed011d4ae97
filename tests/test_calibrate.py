"""crawlerd calibrate: intrinsics from rendered board recordings, drives of known length, bad input."""

import json
import math
import re

import numpy as np
import pytest

from crawler.calibrate_board import parse_board
from crawler.calibrate_drive import secant
from crawler.calibrate_intrinsics import View, coverage, select_views
from crawler.calibration import load_calibration, write_calibration
from crawler.errors import BadConfig
from crawler.geometry import Camera
from hw_sim.target import Board, TargetCamera, board_poses, write_board_video

# a Pi-like lens with strong barrel distortion: what the recordings are rendered with
LENS = TargetCamera(640, 480, fx=520.0, fy=518.0, cx=322.5, cy=236.0, distortion=(-0.28, 0.10, 0.001, -0.0005, 0.0))
F_TOL = 0.003               # recovered focal lengths within 0.3 %
C_TOL_PX = 1.0              # principal point within a pixel


@pytest.fixture(scope="session")
def board_video(tmp_path_factory):
    """board_video(kind) -> the path of a rendered recording of that board waved in front of LENS."""
    root = tmp_path_factory.mktemp("boards")
    boards = {"checkerboard": Board("checkerboard", 10, 7, 0.025),
              "charuco": Board("charuco", 8, 6, 0.030, 0.022, "DICT_5X5_100")}
    cache = {}

    def render(kind):
        if kind not in cache:
            board = boards[kind]
            poses = board_poses(board, LENS, keyposes=12, frames_between=3, seed=1)
            cache[kind] = write_board_video(root / f"{kind}.h264", board, LENS, poses)
        return cache[kind]

    return render


def calibrate(crawlerd, *argv):
    return crawlerd("calibrate", *argv, "--json")


def assert_recovers_the_lens(s, out):
    assert abs(s["fx"] / LENS.fx - 1) < F_TOL and abs(s["fy"] / LENS.fy - 1) < F_TOL
    assert abs(s["cx"] - LENS.cx) < C_TOL_PX and abs(s["cy"] - LENS.cy) < C_TOL_PX
    assert abs(s["dist_coeffs"][0] - LENS.distortion[0]) < 0.01
    cam = load_calibration(out)              # the file the config reads, read as the config reads it
    assert (cam.width, cam.height) == (640, 480)
    assert cam.fx == pytest.approx(s["fx"], abs=1e-3) and cam.distortion[0] == pytest.approx(s["dist_coeffs"][0], abs=1e-6)


def test_intrinsics_from_a_checkerboard_recover_the_rendered_lens(board_video, crawlerd, tmp_path):
    out = tmp_path / "calib.json"
    rc, s, err = calibrate(crawlerd, "intrinsics", board_video("checkerboard"), "--board", "checkerboard:9x6:25mm",
                           "-o", out)
    assert rc == 0, err
    assert_recovers_the_lens(s, out)
    assert s["rms_px"] < 0.2 and s["found"] == s["examined"] == 34
    assert s["coverage"] > 0.5


def test_intrinsics_from_a_charuco_board_recover_the_rendered_lens(board_video, crawlerd, tmp_path):
    out = tmp_path / "charuco.json"
    rc, s, err = calibrate(crawlerd, "intrinsics", board_video("charuco"),
                           "--board", "charuco:8x6:30mm:22mm:DICT_5X5_100", "-o", out)
    assert rc == 0, err
    assert_recovers_the_lens(s, out)
    assert s["rms_px"] < 0.2


def test_scale_to_writes_the_same_view_at_the_sensor_resolution(board_video, crawlerd, tmp_path):
    out = tmp_path / "full.json"
    rc, s, _ = calibrate(crawlerd, "intrinsics", board_video("checkerboard"), "-o", out, "--scale-to", "1280x960")
    assert rc == 0 and s["image_size"] == [1280, 960] and s["recorded_size"] == [640, 480]
    cam = load_calibration(out)
    assert cam.fx == pytest.approx(2 * LENS.fx, rel=F_TOL)
    assert cam.cx == pytest.approx((LENS.cx + 0.5) * 2 - 0.5, abs=2 * C_TOL_PX)     # pixel centres kept

    rc, _, err = calibrate(crawlerd, "intrinsics", board_video("checkerboard"), "-o", out, "--scale-to", "1920x1080")
    assert rc == 2 and "another shape" in err


def test_a_fit_above_max_rms_is_refused_and_nothing_written(board_video, crawlerd, tmp_path):
    out = tmp_path / "calib.json"
    rc, s, err = crawlerd("calibrate", "intrinsics", board_video("checkerboard"), "-o", out, "--max-rms", "0.01")
    assert rc == 1 and s is None and not out.exists()
    assert "RMS reprojection error" in err and "--max-rms 0.01" in err and err.count("\n") == 1


def test_the_wrong_board_is_named_with_the_fix(board_video, crawlerd, tmp_path):
    rc, _, err = crawlerd("calibrate", "intrinsics", board_video("checkerboard"), "--board", "checkerboard:10x7",
                          "-o", tmp_path / "c.json")
    assert rc == 1 and "found in 0 of 34 frames" in err and "9x6 inner corners" in err
    assert "Traceback" not in err and err.count("\n") == 1


@pytest.mark.parametrize("argv,words", [
    (["--board", "chess:9x6"], "must be checkerboard:COLSxROWS"),
    (["--board", "checkerboard:9x6:25"], "'25' must be a length with its unit"),
    (["--board", "charuco:8x6:30mm:40mm"], "must be smaller than the square"),
    (["--board", "charuco:8x6:30mm:22mm:DICT_7X7"], "not an OpenCV ArUco dictionary"),
    (["--max-rms", "-1"], "'-1' must be pixels between"),
    (["--max-views", "3"], "'3' must be a whole number >= 8"),
    (["-o", "/nonexistent/c.json"], "does not exist or is not writable"),
])
def test_bad_intrinsics_input_is_one_line_and_exit_2(board_video, crawlerd, tmp_path, argv, words):
    argv = ["-o", tmp_path / "c.json", *argv] if "-o" not in argv else argv
    rc, _, err = crawlerd("calibrate", "intrinsics", board_video("checkerboard"), *argv)
    assert rc == 2 and words in err and err.count("\n") == 1 and err.startswith("crawlerd calibrate: error:")


def test_a_missing_video_is_exit_2(crawlerd, tmp_path):
    rc, _, err = crawlerd("calibrate", "intrinsics", tmp_path / "none.h264", "-o", tmp_path / "c.json")
    assert rc == 2 and "not found" in err and err.count("\n") == 1
    rc, _, err = crawlerd("calibrate")
    assert rc == 2 and "required" in err


# -- the drive ---------------------------------------------------------------------------------------

@pytest.fixture(scope="session")
def drive_run(render_run):
    """A 0.600 m drive at 24 deg tilt (H = 0.22561 m from the mount formula)."""
    run = render_run("drive24", tilt_deg=24, speed_m_s=0.3, duration_s=2.0)
    assert run["truth"]["true_distance_m"] == pytest.approx(0.6)
    return run


def test_a_wrong_height_fails_with_the_height_that_fixes_it(drive_run, crawlerd):
    truth = drive_run["truth"]
    rc, s, _ = crawlerd("calibrate", "drive", drive_run["h264"], "--length", "0.600", "--tilt", "24",
                        "--set", "mount.height_m=0.2300", "--json")
    assert rc == 1 and not s["pass"]
    assert s["error_pct"] == pytest.approx(100 * (0.2300 / truth["camera_height_m"] - 1), abs=0.1)   # ~ +1.9 %
    h = s["height"]
    assert h["exact"] == pytest.approx(truth["camera_height_m"], rel=0.0005)
    assert h["check_m"] == pytest.approx(0.6, rel=1e-4) and h["set"] == f"--set mount.height_m={h['exact']:.5f}"
    f = s["fov"]                        # the other way to the same metres: a wider view
    assert f["check_m"] == pytest.approx(0.6, rel=1e-4) and f["exact"][0] < 53.5 and f["exact"][1] < 37.16

    rc, s, _ = crawlerd("calibrate", "drive", drive_run["h264"], "--length", "0.600", "--tilt", "24",
                        *h["set"].split(), "--json")
    assert rc == 0 and s["pass"] and abs(s["error_pct"]) < 0.02

    rc, s, _ = crawlerd("calibrate", "drive", drive_run["h264"], "--length", "0.600", "--tilt", "24",
                        "--set", "mount.height_m=0.2300", *f["set"].split(), "--json")
    assert rc == 0 and s["pass"] and abs(s["error_pct"]) < 0.02


def test_the_drive_text_says_fail_and_both_corrections(drive_run, crawlerd, capsys):
    from crawler.cli import main

    rc = main(["calibrate", "drive", str(drive_run["h264"]), "--length", "0.6", "--tilt", "24",
               "--set", "mount.height_m=0.2300"])
    out = capsys.readouterr().out
    assert rc == 1 and "FAIL (limit +-0.5 %)" in out
    height = float(re.search(r"--set mount.height_m=([0-9.]+)", out).group(1))
    assert height == pytest.approx(0.22561, abs=2e-4) and "--set camera.hfov_deg=" in out   # the mount formula's H
    assert "suggested: the field of view" in out


def test_a_length_no_height_could_explain_is_refused(drive_run, crawlerd):
    rc, s, err = crawlerd("calibrate", "drive", drive_run["h264"], "--length", "2.0", "--tilt", "24", "--json")
    assert rc == 1 and s is None and "against --length 2 m (-70.0 %)" in err and err.count("\n") == 1


def test_marks_by_frame_and_by_time_measure_between_them(drive_run, crawlerd):
    from hw_sim import read_ground_truth

    gt = read_ground_truth(drive_run["csv"])
    length = gt["distance_m"][50] - gt["distance_m"][10]
    rc, s, _ = crawlerd("calibrate", "drive", drive_run["h264"], "--length", f"{length:.4f}", "--tilt", "24",
                        "--start-frame", "10", "--end-frame", "50", "--json")
    assert rc == 0 and s["pass"] and (s["start"]["frame"], s["end"]["frame"]) == (10, 50)
    assert abs(s["error_pct"]) < 0.2
    rc, s, _ = crawlerd("calibrate", "drive", drive_run["h264"], "--length", f"{length:.4f}", "--tilt", "24",
                        "--start-time", f"{gt['t_s'][10]:.4f}", "--end-time", f"{gt['t_s'][50]:.4f}", "--json")
    assert rc == 0 and (s["start"]["frame"], s["end"]["frame"]) == (10, 50)


@pytest.mark.parametrize("argv,words", [
    (["--end-frame", "500"], "--end-frame 500 is after the recording's last frame (60)"),
    (["--start-frame", "40", "--end-frame", "20"], "--end-frame 20 is not after --start-frame 40; swap them"),
    (["--start-time", "1.5", "--end-frame", "20"], "the end mark (frame 20, 0.667 s) is not after the start mark (--start-time 1.5)"),
    (["--end-time", "9"], "--end-time 9 is after the recording's last frame (2.000 s)"),
    (["--length", "0"], "'0' must be a length in metres"),
    (["--set", "mount.height_m=0.5"], "[mount] height_m = 0.5 puts the camera outside the pipe"),
])
def test_bad_drive_input_is_one_line_and_exit_2(drive_run, crawlerd, argv, words):
    argv = ["--length", "0.6", *argv] if "--length" not in argv else argv
    rc, s, err = crawlerd("calibrate", "drive", drive_run["h264"], "--tilt", "24", *argv, "--json")
    assert rc == 2 and s is None and words in err and err.count("\n") == 1, err


# -- the parts -----------------------------------------------------------------------------------------

def test_board_texts():
    b = parse_board("checkerboard:9x6:25mm")
    assert (b.kind, b.corners, b.square_m) == ("checkerboard", (9, 6), 0.025)
    assert parse_board("checkerboard:7x5").square_m == 0.025
    c = parse_board("charuco:8x11:2cm:1.5cm:dict_4x4_50")
    assert (c.corners, c.square_m, c.marker_m, c.dictionary) == ((7, 10), 0.02, 0.015, "DICT_4X4_50")
    assert parse_board(c.text()) == c
    with pytest.raises(BadConfig, match="different count across than down"):
        parse_board("checkerboard:6x6")


def test_secant_finds_a_nonlinear_root_in_few_evaluations():
    calls = []

    def measure(x):                     # distance ~ x^0.85, like the FOV at 24 deg tilt
        calls.append(x)
        return 0.6 * x ** 0.85

    x, m, n = secant(measure, 1.0, 0.6, 0.6 / 0.612 * 1.0, target=0.612, tol=1e-4, max_evals=3)
    assert m == pytest.approx(0.612, rel=1e-4) and x == pytest.approx((0.612 / 0.6) ** (1 / 0.85), rel=1e-4)
    assert n == len(calls) <= 3

    def refuses(x):
        raise BadConfig("outside the pipe")

    assert secant(refuses, 0.2, 0.5, 0.3, 0.6, 1e-4, 3) == (0.2, 0.5, 0)


def test_views_are_chosen_all_over_the_frame():
    rng = np.random.default_rng(0)
    obj = np.zeros((4, 3), np.float32)
    obj[:, :2] = [[0, 0], [1, 0], [0, 1], [1, 1]]

    def view(frame, x, y):
        return View(frame, obj, (obj[:, :2] * 40 + [x, y]).astype(np.float32))

    # 90 views lingering in the centre, 10 out at the corners and edges
    views = [view(k, 300 + rng.normal(0, 5), 220 + rng.normal(0, 5)) for k in range(90)]
    views += [view(90 + k, x, y) for k, (x, y) in enumerate(
        [(5, 5), (590, 5), (5, 430), (590, 430), (300, 5), (300, 430), (5, 220), (590, 220), (150, 100), (450, 330)])]
    chosen = select_views(views, (640, 480), max_views=12)
    assert len(chosen) == 12 and set(range(90, 100)) <= set(chosen)
    assert coverage([views[k] for k in chosen], (640, 480)) > 2 * coverage(views[:90], (640, 480))


def test_write_calibration_is_atomic_and_reads_back(tmp_path):
    path = tmp_path / "calib.json"
    cam = Camera(640, 480, 520.0, 518.0, 322.5, 236.0, distortion=(-0.28, 0.1, 0.001, -0.0005, 0.0))
    write_calibration(path, cam, rms_px=0.05)
    assert load_calibration(path) == cam and json.loads(path.read_text())["rms_px"] == 0.05
    assert [p.name for p in tmp_path.iterdir()] == ["calib.json"] and (path.stat().st_mode & 0o777) == 0o644
    bad = Camera(640, 480, math.nan, 518.0, 322.5, 236.0)
    with pytest.raises(ValueError):
        write_calibration(path, bad)                # NaN is refused before anything is replaced
    assert load_calibration(path) == cam and [p.name for p in tmp_path.iterdir()] == ["calib.json"]


@pytest.mark.parametrize("spec", ["checkerboard:9x6:25mm", "charuco:8x11:20mm:15mm:DICT_5X5_100"])
def test_the_printed_page_holds_the_board_at_its_true_size(crawlerd, tmp_path, spec):
    import cv2

    from crawler.calibrate_board import make_finder

    png = tmp_path / "board.png"
    rc, _, err = crawlerd("calibrate", "board", "--board", spec, "-o", png, "--dpi", "150")
    assert rc == 0, err
    page = cv2.imread(str(png), cv2.IMREAD_GRAYSCALE)
    board = parse_board(spec)
    a4 = np.array([210, 297]) / 25.4 * 150
    turned = a4[::-1] if board.kind == "checkerboard" else a4                   # landscape for a wide board
    assert np.abs(np.array(page.shape[::-1]) - turned).max() <= 1
    obj, img = make_finder(board).find(page)
    assert len(obj) == board.corners[0] * board.corners[1]                      # every corner, numbered
    a, b = np.argmin(obj[:, 0] + obj[:, 1]), np.argmax(obj[:, 0] + obj[:, 1])   # opposite corners of the grid
    px_per_m = np.linalg.norm(img[b] - img[a]) / np.linalg.norm(obj[b] - obj[a])
    assert px_per_m == pytest.approx(150 / 0.0254, rel=0.003)                    # squares of the stated size

    rc, _, err = crawlerd("calibrate", "board", "--board", "charuco:8x11:30mm:22mm", "-o", tmp_path / "b.pdf")
    assert rc == 2 and "more than fits on A4" in err and "--paper" in err and err.count("\n") == 1


def test_check_without_a_drive_says_what_it_needs(crawlerd):
    rc, _, err = crawlerd("calibrate", "check")
    assert rc == 2 and "VIDEO --live is required" in err and err.count("\n") == 1


def test_the_drive_calibrates_the_camera_alone(drive_run, crawlerd, tmp_path):
    config = tmp_path / "crawlerd.toml"      # the crawler's own config: a wheel that is not on this machine
    config.write_text('[mount]\nheight_m = 0.2300\ntilt_deg = 24.0\n\n'
                      '[wheel]\nbackend = "evdev"\ndevice = "/dev/input/by-path/no-such-wheel"\ncounts_per_m = 5000\n')
    rc, s, err = crawlerd("calibrate", "drive", drive_run["h264"], "--length", "0.6", "--config", config, "--json")
    assert rc == 1 and s["height"]["from"] == "[mount] height_m" and s["height"]["now"] == 0.23, err
    assert s["error_pct"] == pytest.approx(1.92, abs=0.1)
