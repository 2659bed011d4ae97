"""Frame cost of the odometry loop at the live path's window sizes: ARM instructions per frame, stages, fps.

    python benchmarks/throughput.py [--arm] [--arm-replay] [--callgrind] [--speed 0.1,0.3,0.6]
                                    [--features N] [--win PX] [--levels N] [--no-fb] [--cases 240x240]

Renders a hw_sim run per window size (240x240 and the thesis's 360x360 crop), encodes it to H.264,
then measures per frame: decode, the odometry's stages (coarse guess, LK tracking, keyframe
detection, projection and estimation) and a Zenoh publish, in wall time on this machine.

--arm counts the odometry's ARM instructions per frame on the Pi's own instruction set (the armhf
yardstick, benchmarks/arm_yardstick.py: bookworm armhf python3.11, numpy 1.24, OpenCV 4.6 under
qemu-arm): the slope between a short and a long run over preloaded frames, so start-up cancels and
decoding is excluded, then the same runs with stage marks for a per-stage, per-library split.
--arm-replay counts `python -m crawler --replay` (decode, odometry, summary) and bare decoding the
same way. --callgrind counts x86 instructions under valgrind (AVX2 code paths: the second figure).
A Raspberry Pi 2 estimate is 900 MHz x IPC 0.5 / ARM instructions per frame.
Not a test: it prints figures (docs/performance.md).
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

PI2_HZ = 900e6
PI2_IPC = 0.5
ARM_FRAMES = (90, 270)   # short and long run of the slope
CASES = {  # name: sensor crop of the thesis camera (960x720, 37.16 x 53.5 deg) read at full scale
    "240x240": (360, 360, 240, 240),
    "360x360": (300, 360, 360, 360),
}


def make_run(out: Path, name: str, window, speed: float, fps: float, frames: int):
    from hw_sim import SimConfig, write_run

    cfg = SimConfig(window=window, tilt_deg=0.0, speed_m_s=speed, fps=fps, duration_s=(frames - 1) / fps,
                    seed=1)
    meta = out / f"{name}.json"
    if not meta.exists() or json.loads(meta.read_text())["config"] != json.loads(json.dumps(cfg.to_dict())):
        write_run(cfg, out, name)
    return out / f"{name}.h264", json.loads(meta.read_text())


def build(window, params, pose: str = "off"):
    """The odometer on the rendered window; pose "on": crawler/pose.py's pitch and height per frame
    ([odometry] estimate_pose), "auto": and the tilt ([mount] tilt_deg = "auto")."""
    from crawler import settings
    from crawler.geometry import Camera, Mount, make_projection
    from crawler.measurement import pose_params
    from crawler.odometry import Odometer
    from crawler.pose import PoseEstimator

    x, y, w, h = window
    cam = Camera.from_fov(960, 720, 37.16, 53.50).window(x, y, w, h, w, h)
    proj = make_projection("cylinder", Mount.from_car(0.30, 0.151, 0.054, 0.0))
    roi = (0, 0, w, h)
    # as crawler/measurement.py builds it from the settings at 0 deg: "on" with pitch, height, sway
    # and the ride height; tilt auto alone with none of them
    overrides = {"on": [], "auto": ['mount.tilt_deg="auto"']}.get(pose)
    estimator = None if overrides is None else PoseEstimator(
        cam, proj, roi, pose_params(settings.load(None, overrides)))
    return Odometer(cam, proj, roi, params, pose=estimator)


def params_from(args):
    from crawler.flow import FlowParams
    from crawler.odometry import OdometryParams

    fp = FlowParams()
    kw = {}
    if args.features:
        kw["max_features"] = args.features
    if args.win:
        kw["win_px"] = args.win
    if args.levels is not None:
        kw["levels"] = args.levels
    if args.iterations:
        kw["iterations"] = args.iterations
    if args.no_fb:
        kw["check_backward"] = False
    if getattr(args, "eps", None):
        kw["epsilon_px"] = args.eps
    fp = FlowParams(**{**fp.__dict__, **kw})
    return OdometryParams(flow=fp)


class Stages:
    """Wraps the odometry's building blocks with timers (benchmark only; the product is untouched)."""

    def __init__(self):
        self.ns = {}

    def wrap(self, module, name, stage):
        fn = getattr(module, name)

        def timed(*a, **kw):
            t = time.perf_counter_ns()
            try:
                return fn(*a, **kw)
            finally:
                self.ns[stage] = self.ns.get(stage, 0) + time.perf_counter_ns() - t

        setattr(module, name, timed)


def timing(args, name, window, h264, meta):
    import cv2

    from crawler import flow
    from crawler.link import ZenohLink, make_zenoh_config
    from crawler.video import VideoReplay

    cv2.setNumThreads(1)
    frames = []
    t = time.perf_counter_ns()
    with VideoReplay(h264, build(window, None).camera) as src:
        for f in src.frames():
            frames.append((f.gray.copy(), f.t_s, f.intra))
    decode_ns = (time.perf_counter_ns() - t) / len(frames)
    st = Stages()
    st.wrap(flow, "track", "track (LK fwd+bwd)")
    st.wrap(flow, "detect", "keyframe detect")
    st.wrap(flow, "coarse_image", "coarse guess")
    st.wrap(flow, "coarse_shift", "coarse guess")
    odo = build(window, params_from(args), args.pose)
    t = time.perf_counter_ns()
    for gray, ts, intra in frames:
        est = odo.update(gray, ts, intra)
    total = (time.perf_counter_ns() - t) / len(frames)
    for fn in ("track", "detect", "coarse_image", "coarse_shift"):    # unwrap
        setattr(flow, fn, getattr(flow, fn).__closure__[0].cell_contents)
    link = ZenohLink("bench", make_zenoh_config("peer", multicast=False)).open()
    d = est.as_dict()
    t = time.perf_counter_ns()
    for _ in range(200):
        link.publish_estimate(d)
    pub_ns = (time.perf_counter_ns() - t) / 200
    link.close()
    stages = {k: v / len(frames) for k, v in st.ns.items()}
    stages["projection + estimation"] = total - sum(stages.values())
    path = meta["path_length_m"]
    err = 100 * (odo.distance - meta["true_distance_m"]) / path if path else 0.0
    return {"case": name, "frames": len(frames), "decode_ms": decode_ns / 1e6, "odometry_ms": total / 1e6,
            "stages_ms": {k: v / 1e6 for k, v in stages.items()}, "publish_ms": pub_ns / 1e6,
            "fps_odometry": 1e9 / total, "error_pct": err}


def count_instructions(args, window, h264, n_frames):
    """Odometry instructions per frame: callgrind totals for N and 2N frames, differenced."""
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        preload(h264, tmp, window)
        return _callgrind_runs(args, window, tmp, n_frames)


def save_frames(tmp: Path, frames):
    """(grey, time, I-frame) of each decoded frame, as the guest or valgrind's run loads them."""
    import numpy as np

    np.save(tmp / "frames.npy", np.stack([g for g, _, _ in frames]))
    np.save(tmp / "times.npy", np.array([t for _, t, _ in frames]))
    np.save(tmp / "intra.npy", np.array([k for _, _, k in frames], dtype=bool))


def load_frames(tmp) -> list:
    """save_frames' (grey, time, I-frame) of each frame, back."""
    import numpy as np

    frames, times, intra = (np.load(Path(tmp) / f"{name}.npy") for name in ("frames", "times", "intra"))
    return [(g, float(t), bool(k)) for g, t, k in zip(frames, times, intra)]


def _callgrind_runs(args, window, tmp: Path, n_frames: int) -> float:
    totals = []
    for n in (n_frames, 2 * n_frames):
        out = tmp / f"cg.{n}"
        cmd = ["valgrind", "--tool=callgrind", f"--callgrind-out-file={out}", sys.executable, __file__,
               "--_count", str(tmp), str(n), json.dumps(list(window)), json.dumps(vars(args))]
        env = dict(os.environ, OPENCV_FOR_THREADS_NUM="1", OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1")
        p = subprocess.run(cmd, capture_output=True, text=True, env=env)
        m = re.search(r"Collected : (\d+)", p.stderr)
        if not m:
            raise SystemExit(f"callgrind failed: {p.stderr[-2000:]}")
        totals.append(int(m.group(1)))
    return (totals[1] - totals[0]) / n_frames


def _count(tmp, n, window, argd):
    """Inside valgrind: run the odometry over n preloaded frames."""
    import cv2

    cv2.setNumThreads(1)
    frames = load_frames(tmp)
    opts = json.loads(argd)
    odo = build(json.loads(window), params_from(argparse.Namespace(**opts)), opts.get("pose", "off"))
    for i in range(int(n)):
        odo.update(*frames[i % len(frames)])


# -- ARM yardstick (benchmarks/arm_yardstick.py) ------------------------------------------------------

ARM_STAGES = {  # stage number: what the instructions counted there did
    0: "start-up, imports, loading frames",
    1: "update(): the odometer's own Python/numpy",
    2: "LK forward (calcOpticalFlowPyrLK)",
    3: "LK backward (calcOpticalFlowPyrLK)",
    4: "track(): numpy around the LK calls",
    5: "keyframe detection (flow.detect)",
    6: "keyframe setup (projection, guess model)",
    7: "coarse guess (phase correlation)",
    8: "projection to the wall (per frame)",
    9: "robust step (median/MAD)",
    10: "benchmark loop",
}


def preload(h264: Path, tmp: Path, window) -> int:
    """Decodes once on the host: the guest replays raw frames, so decoding is not counted."""
    from crawler.video import VideoReplay

    with VideoReplay(h264, build(window, None).camera) as src:
        frames = [(f.gray.copy(), f.t_s, f.intra) for f in src.frames()]
    save_frames(tmp, frames)
    return len(frames)


def arm_count(args, window, h264) -> dict:
    """Odometry ARM instructions per frame: slope of the totals, then the per-stage split."""
    with tempfile.TemporaryDirectory() as tmp:
        if preload(h264, Path(tmp), window) < ARM_FRAMES[1]:
            raise SystemExit(f"{h264} has fewer than {ARM_FRAMES[1]} frames; use --frames {ARM_FRAMES[1]}")
        return _arm_runs(args, window, h264, Path(tmp))


def _arm_runs(args, window, h264, tmp: Path) -> dict:
    import arm_yardstick as ay

    n1, n2 = ARM_FRAMES

    def one(n, marks):
        return ay.run(["benchmarks/throughput.py", "--_arm", str(tmp), str(n), json.dumps(list(window)),
                       json.dumps(vars(args)), str(int(marks))])

    short, long = one(n1, False), one(n2, False)
    guest = json.loads(long.stdout)
    true_m = float(h264.with_suffix(".csv").read_text().splitlines()[n2].split(",")[2])
    guest["error_mm"] = 1000 * (guest["distance_m"] - true_m)     # a standing crawler has no path to divide by
    guest["error_pct"] = 100 * (guest["distance_m"] - true_m) / true_m if true_m else None
    r = {"arm_per_frame": ay.slope(short, long, n2 - n1), "guest": guest}
    if args.arm_stages:
        ms, ml = one(n1, True), one(n2, True)
        r["marked_per_frame"] = ay.slope(ms, ml, n2 - n1)
        r["stages"] = {s: ((ml.stage(s) - ms.stage(s)) / (n2 - n1),
                           {g: (ml.grouped(s).get(g, 0) - ms.grouped(s).get(g, 0)) / (n2 - n1)
                            for g in set(ml.grouped(s)) | set(ms.grouped(s))})
                       for s in ARM_STAGES if s}
    return r


def replay_args(h264: Path, meta: dict) -> list[str]:
    """crawlerd --set options that describe the rendered window: its intrinsics and the whole-frame ROI."""
    cal = h264.with_suffix(".calibration.json")
    cal.write_text(json.dumps({"camera_matrix": [[meta["fx"], 0, meta["cx"]], [0, meta["fy"], meta["cy"]], [0, 0, 1]],
                               "dist_coeffs": [], "image_size": [meta["width"], meta["height"]]}))
    return ["--set", f"camera.calibration={cal}", "--set", f"camera.width={meta['width']}",
            "--set", f"camera.height={meta['height']}", "--set", f"odometry.roi=[0,0,{meta['width']},{meta['height']}]"]


def arm_replay(h264: Path, meta: dict, fps: float) -> dict:
    """The whole replay loop (`python -m crawler --replay`) and bare decoding, per frame on ARM."""
    import arm_yardstick as ay

    n1, n2 = ARM_FRAMES
    rep = [ay.run(["-m", "crawler", "--replay", str(h264), "--fps", f"{fps:g}", "--no-publish",
                   "--max-frames", str(n), *replay_args(h264, meta)]) for n in (n1, n2)]
    dec = [ay.run(["benchmarks/throughput.py", "--_decode", str(h264), str(n)]) for n in (n1, n2)]
    return {"replay_per_frame": ay.slope(*rep, n2 - n1), "decode_per_frame": ay.slope(*dec, n2 - n1)}


def print_arm(r: dict):
    import arm_yardstick as ay

    g = r["guest"]
    print(f"    ARM: odometry {r['arm_per_frame'] / 1e6:.2f} M instructions/frame (slope {ARM_FRAMES[0]}"
          f"->{ARM_FRAMES[1]} frames)  ->  Pi 2 estimate {ay.pi2_fps(r['arm_per_frame']):.0f} fps on one core"
          f"  [{g['keyframes']} keyframes, {g['lost']} lost in {g['frames']} frames, error "
          + (f"{g['error_pct']:+.4f} %]" if g["error_pct"] is not None else f"{g['error_mm']:+.3f} mm]"))
    if "stages" not in r:
        return
    groups = ("OpenCV", "numpy", "Python", "libc/libm", "other")
    print(f"    {'ARM stage (M/frame)':44s} {'total':>6s} " + " ".join(f"{k:>9s}" for k in groups))
    for s, (tot, split) in sorted(r["stages"].items(), key=lambda kv: -kv[1][0]):
        print(f"    {ARM_STAGES[s]:44s} {tot / 1e6:6.3f} "
              + " ".join(f"{split.get(k, 0) / 1e6:9.3f}" for k in groups))
    over = r["marked_per_frame"] - r["arm_per_frame"]
    print(f"    (stage marks add {over / 1e6:+.3f} M/frame to the marked runs)")


def _mark_stages():
    """Inside qemu: wrap the odometry's building blocks with stage marks (the product is untouched)."""
    import cv2

    import arm_yardstick

    from crawler import flow, odometry

    st = arm_yardstick.Stages()
    lk_calls = [0]

    def track_stage():
        lk_calls[0] = 0
        return 4

    def lk_stage():
        lk_calls[0] += 1
        return 2 if lk_calls[0] % 2 else 3

    odo = odometry.Odometer
    st.wrap(odo, "update", 1)
    st.wrap(flow, "track", track_stage)
    st.wrap(cv2, "calcOpticalFlowPyrLK", lk_stage)
    st.wrap(flow, "detect", 5)
    st.wrap(odo, "_new_keyframe", 6)
    st.wrap(odo, "_coarse_guess", 7)
    st.wrap(odo, "_wall", 8, keep=(6,))
    st.wrap(odometry, "robust_step", 9)
    return st


def _arm(tmp, n, window, argd, marks):
    """Inside qemu: the odometry over n preloaded frames; prints what it did as JSON."""
    import cv2

    cv2.setNumThreads(1)
    frames = load_frames(tmp)
    opts = json.loads(argd)
    odo = build(json.loads(window), params_from(argparse.Namespace(**opts)), opts.get("pose", "off"))
    st = _mark_stages() if marks == "1" else None
    if st:
        st.set(10)
    keyframes = lost = 0
    for i in range(int(n)):
        est = odo.update(*frames[i])
        keyframes += est.keyframe
        lost += not est.tracking
    if st:
        st.set(0)
    print(json.dumps({"frames": int(n), "keyframes": keyframes, "lost": lost, "distance_m": odo.distance}))


def _decode(h264, n):
    """Inside qemu: bare decoding of the first n frames, as the replay does it."""
    from crawler.video import VideoReplay

    from crawler.geometry import Camera

    meta = json.loads(Path(h264).with_suffix(".json").read_text())
    with VideoReplay(Path(h264), Camera.from_fov(meta["width"], meta["height"], 37.16, 53.50)) as src:
        for i, f in enumerate(src.frames()):
            if i + 1 >= int(n):
                break



def main(argv=None):
    argv = sys.argv[1:] if argv is None else argv
    if argv and argv[0] == "--_count":
        return _count(*argv[1:])
    if argv and argv[0] == "--_arm":
        return _arm(*argv[1:])
    if argv and argv[0] == "--_decode":
        return _decode(*argv[1:])
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=str(ROOT / "out" / "throughput"))
    ap.add_argument("--speed", default="0.3", help="crawler speeds of the rendered runs, comma-separated (m/s)")
    ap.add_argument("--fps", type=float, default=60.0)
    ap.add_argument("--frames", type=int, default=ARM_FRAMES[1], help="frames per rendered run")
    ap.add_argument("--arm", action="store_true", help="count ARM instructions on the armhf yardstick")
    ap.add_argument("--no-arm-stages", dest="arm_stages", action="store_false",
                    help="with --arm: only the total, not the per-stage split (two runs fewer)")
    ap.add_argument("--arm-replay", action="store_true",
                    help="count `python -m crawler --replay` and bare decoding on the yardstick")
    ap.add_argument("--callgrind", action="store_true", help="count x86 instructions under valgrind")
    ap.add_argument("--cg-frames", type=int, default=40, help="frames per callgrind run")
    ap.add_argument("--no-timing", dest="timing", action="store_false", help="skip the wall-clock stages")
    ap.add_argument("--features", type=int, help="max features per keyframe")
    ap.add_argument("--win", type=int, help="LK window (px)")
    ap.add_argument("--levels", type=int, help="pyramid levels")
    ap.add_argument("--iterations", type=int, help="LK iterations")
    ap.add_argument("--eps", type=float, help="LK convergence threshold (px)")
    ap.add_argument("--no-fb", action="store_true", help="skip the backward LK check")
    ap.add_argument("--cases", default=",".join(CASES))
    ap.add_argument("--pose", choices=("off", "on", "auto"), default="on",
                    help='pose estimation: on (the default config: pitch and height per frame), off '
                         '(estimate_pose = false), auto (tilt_deg = "auto")')
    args = ap.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    for speed in (float(v) for v in args.speed.split(",")):
        for name in args.cases.split(","):
            measure_case(args, out, name, speed)


def measure_case(args, out: Path, name: str, speed: float):
    window = CASES[name]
    h264, meta = make_run(out, f"{name}-v{speed:g}-f{args.fps:g}", window, speed, args.fps, args.frames)
    print(f"{name} at {speed:g} m/s, {args.fps:g} fps:")
    if args.timing:
        r = timing(args, name, window, h264, meta)
        print(f"    this PC: decode {r['decode_ms']:.2f} ms, odometry {r['odometry_ms']:.2f} ms "
              f"({r['fps_odometry']:.0f} fps), publish {r['publish_ms'] * 1000:.0f} us, "
              f"distance error {r['error_pct']:+.4f} %")
        for k, v in r["stages_ms"].items():
            print(f"        {k:26s} {v:7.3f} ms")
    if args.arm:
        print_arm(arm_count(args, window, h264))
    if args.arm_replay:
        r = arm_replay(h264, meta, args.fps)
        print(f"    ARM: python -m crawler --replay {r['replay_per_frame'] / 1e6:.2f} M instructions/frame "
              f"(Pi 2 estimate {PI2_HZ * PI2_IPC / r['replay_per_frame']:.0f} fps), of which bare decoding "
              f"{r['decode_per_frame'] / 1e6:.2f} M; the rest (odometry, summary, loop) "
              f"{(r['replay_per_frame'] - r['decode_per_frame']) / 1e6:.2f} M")
    if args.callgrind:
        ipf = count_instructions(args, window, h264, args.cg_frames)
        print(f"    x86 callgrind: odometry {ipf / 1e6:.2f} M instructions/frame (AVX2 code paths)")


if __name__ == "__main__":
    main()
