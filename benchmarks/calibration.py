"""How well `crawlerd calibrate` recovers a known camera, on hw_sim renders (figures for docs/calibration.md).

    python benchmarks/calibration.py intrinsics     # boards x lenses x noise: recovered fx, fy, cx, cy
    python benchmarks/calibration.py drive          # wrong heights and FOVs at 0, 24, 40 deg tilt
    python benchmarks/calibration.py                # both

intrinsics: a checkerboard (9x6 inner corners, 25 mm) and a ChArUco board (8x6 squares, 30/22 mm,
DICT_5X5_100) waved through 16 key poses (61 frames, 640x480) in front of a narrow and a wide
distorted lens, at sensor noise 1.5 and 4 DN, through H.264; prints the errors of the recovered
intrinsics and the RMS. drive: a 0.9 m drive at 0.3 m/s replayed with the camera height or the
FOV 2 % and 5 % off; prints the error found, the corrections' own replays and their distance from
the truth. Not a test: it prints figures.
"""

from __future__ import annotations

import io
import json
import math
import sys
import tempfile
import time
from contextlib import redirect_stdout
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from crawler.cli import main  # noqa: E402
from hw_sim import SimConfig, write_run  # noqa: E402
from hw_sim.target import Board, TargetCamera, board_poses, write_board_video  # noqa: E402

LENSES = {
    "narrow": TargetCamera(640, 480, 620.0, 618.0, 322.5, 236.0, (-0.12, 0.05, 0.0005, -0.0003, 0.0)),
    "wide": TargetCamera(640, 480, 420.0, 421.0, 316.0, 244.5, (-0.32, 0.12, -0.001, 0.0008, -0.02)),
}
BOARDS = {
    "checkerboard:9x6:25mm": Board("checkerboard", 10, 7, 0.025),
    "charuco:8x6:30mm:22mm:DICT_5X5_100": Board("charuco", 8, 6, 0.030, 0.022, "DICT_5X5_100"),
}


def crawlerd(*argv) -> tuple[int, dict | None]:
    out = io.StringIO()
    with redirect_stdout(out):
        rc = main([str(a) for a in argv])
    lines = [ln for ln in out.getvalue().splitlines() if ln.startswith("{")]
    return rc, json.loads(lines[-1]) if lines else None


def intrinsics(folder: Path):
    print("board                               lens    noise  views  RMS px   dfx %    dfy %   dcx px  dcy px   dk1      s")
    for spec, board in BOARDS.items():
        for name, lens in LENSES.items():
            for noise in (1.5, 4.0):
                video = folder / f"{board.kind}-{name}-{noise}.h264"
                write_board_video(video, board, lens, board_poses(board, lens, keyposes=16, frames_between=4, seed=2),
                                  noise_sigma=noise)
                t = time.perf_counter()
                k3 = ("--k3",) if lens.distortion[4] else ()
                rc, s = crawlerd("calibrate", "intrinsics", video, "--board", spec, "-o", folder / "c.json", "--json", *k3)
                dt = time.perf_counter() - t
                if rc:
                    print(f"{spec:35s} {name:7s} {noise:5.1f}  failed (exit {rc})")
                    continue
                print(f"{spec:35s} {name:7s} {noise:5.1f}  {s['views']:5d}  {s['rms_px']:6.3f}  "
                      f"{100 * (s['fx'] / lens.fx - 1):+7.3f}  {100 * (s['fy'] / lens.fy - 1):+7.3f}  "
                      f"{s['cx'] - lens.cx:+6.2f}  {s['cy'] - lens.cy:+6.2f}  "
                      f"{s['dist_coeffs'][0] - lens.distortion[0]:+7.4f}  {dt:5.1f}")


def _fov(deg: float, k: float) -> float:
    return math.degrees(2 * math.atan(math.tan(math.radians(deg) / 2) * k))


def drive(folder: Path):
    print("tilt  wrong        error %   replay m   height -> (truth)    off %   replay m   hfov -> (truth)   off %   replay m")
    for tilt in (0, 24, 40):
        run = write_run(SimConfig(tilt_deg=tilt, speed_m_s=0.3, duration_s=3.0), folder, f"drive{tilt}")
        truth = json.loads(run["json"].read_text())
        length, h = truth["true_distance_m"], truth["camera_height_m"]
        for what, k in (("height", 1.02), ("height", 0.95), ("fov", 1.02), ("fov", 0.95)):
            wrong = (["--set", f"mount.height_m={h * k:.6f}"] if what == "height" else
                     ["--set", f"camera.hfov_deg={_fov(53.5, k):.4f}", "--set", f"camera.vfov_deg={_fov(37.16, k):.4f}"])
            rc, s = crawlerd("calibrate", "drive", run["h264"], "--length", f"{length:.6f}", "--tilt", tilt, *wrong,
                             "--json")
            hc, fc = s["height"], s["fov"]
            # only the parameter that was made wrong has a true value to come back to
            h_off = f"{100 * (hc['exact'] / h - 1):+6.3f}" if what == "height" else "     -"
            f_off = f"{100 * (fc['exact'][0] / 53.5 - 1):+6.3f}" if what == "fov" else "     -"
            print(f"{tilt:4d}  {what:6s} x{k:<4g} {s['error_pct']:+8.3f}   {s['measured_m']:.4f}   "
                  f"{hc['exact']:.5f} ({h:.5f})  {h_off}   {hc['check_m']:.4f}   "
                  f"{fc['exact'][0]:6.3f} (53.500)  {f_off}   {fc['check_m']:.4f}   [{hc['replays']}+{fc['replays']} replays]")
    print(f"(each drive {length:.4f} m; 'off' is the found value against the one the render used)")


if __name__ == "__main__":
    which = sys.argv[1:] or ["intrinsics", "drive"]
    with tempfile.TemporaryDirectory() as tmp:
        for name in which:
            {"intrinsics": intrinsics, "drive": drive}[name](Path(tmp))
