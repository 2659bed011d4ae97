"""Frame cost of the odometry loop at the live path's window sizes: stages, fps, instructions per frame.

    python benchmarks/throughput.py [--callgrind] [--features N] [--win PX] [--levels N] [--no-fb]

Renders a hw_sim run per window size (240x240 and the thesis's 360x360 crop), encodes it to H.264,
then measures per frame: decode, the odometry's stages (coarse guess, LK tracking, keyframe
detection, projection and estimation) and a Zenoh publish. With --callgrind it also counts the
odometry's instructions per frame under valgrind (stable on a shared machine, unlike seconds) and
turns them into a Raspberry Pi 2 estimate: 900 MHz x IPC 0.5 / instructions per frame.
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


def build(window, params):
    from crawler.geometry import Camera, Mount, make_projection
    from crawler.odometry import Odometer

    x, y, w, h = window
    cam = Camera.from_fov(960, 720, 37.16, 53.50).window(x, y, w, h, w, h)
    proj = make_projection("cylinder", Mount.from_car(0.30, 0.151, 0.054, 0.0))
    return Odometer(cam, proj, (0, 0, w, h), params)


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
    with VideoReplay(h264) as src:
        for f in src.frames():
            frames.append((f.gray.copy(), f.t_s))
    decode_ns = (time.perf_counter_ns() - t) / len(frames)
    st = Stages()
    st.wrap(flow, "track", "track (LK fwd+bwd)")
    st.wrap(flow, "detect", "keyframe detect")
    st.wrap(flow, "coarse_image", "coarse guess")
    st.wrap(flow, "coarse_shift", "coarse guess")
    odo = build(window, params_from(args))
    t = time.perf_counter_ns()
    for gray, ts in frames:
        est = odo.update(gray, ts)
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
    err = 100 * (odo.distance - meta["true_distance_m"]) / meta["path_length_m"]
    return {"case": name, "frames": len(frames), "decode_ms": decode_ns / 1e6, "odometry_ms": total / 1e6,
            "stages_ms": {k: v / 1e6 for k, v in stages.items()}, "publish_ms": pub_ns / 1e6,
            "fps_odometry": 1e9 / total, "error_pct": err}


def count_instructions(args, window, h264, n_frames):
    """Odometry instructions per frame: callgrind totals for N and 2N frames, differenced."""
    import numpy as np

    from crawler.video import VideoReplay

    with VideoReplay(h264) as src:
        frames = [(f.gray.copy(), f.t_s) for f in src.frames()]
    tmp = Path(tempfile.mkdtemp())
    np.save(tmp / "frames.npy", np.stack([g for g, _ in frames]))
    np.save(tmp / "times.npy", np.array([t for _, t in frames]))
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
    import numpy as np

    cv2.setNumThreads(1)
    frames = np.load(Path(tmp) / "frames.npy")
    times = np.load(Path(tmp) / "times.npy")
    odo = build(json.loads(window), params_from(argparse.Namespace(**json.loads(argd))))
    for i in range(int(n)):
        odo.update(frames[i % len(frames)], float(times[i % len(frames)]))


def main(argv=None):
    argv = sys.argv[1:] if argv is None else argv
    if argv and argv[0] == "--_count":
        return _count(*argv[1:])
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=str(ROOT / "out" / "throughput"))
    ap.add_argument("--speed", type=float, default=0.3, help="crawler speed of the rendered runs (m/s)")
    ap.add_argument("--fps", type=float, default=60.0)
    ap.add_argument("--frames", type=int, default=240)
    ap.add_argument("--callgrind", action="store_true", help="count instructions under valgrind")
    ap.add_argument("--cg-frames", type=int, default=40, help="frames per callgrind run")
    ap.add_argument("--features", type=int, help="max features per keyframe")
    ap.add_argument("--win", type=int, help="LK window (px)")
    ap.add_argument("--levels", type=int, help="pyramid levels")
    ap.add_argument("--iterations", type=int, help="LK iterations")
    ap.add_argument("--eps", type=float, help="LK convergence threshold (px)")
    ap.add_argument("--no-fb", action="store_true", help="skip the backward LK check")
    ap.add_argument("--cases", default=",".join(CASES))
    args = ap.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    for name in args.cases.split(","):
        window = CASES[name]
        h264, meta = make_run(out, name, window, args.speed, args.fps, args.frames)
        r = timing(args, name, window, h264, meta)
        line = (f"{name}: decode {r['decode_ms']:.2f} ms, odometry {r['odometry_ms']:.2f} ms "
                f"({r['fps_odometry']:.0f} fps on this PC), publish {r['publish_ms'] * 1000:.0f} us, "
                f"distance error {r['error_pct']:+.4f} %")
        print(line)
        for k, v in r["stages_ms"].items():
            print(f"    {k:26s} {v:7.3f} ms")
        if args.callgrind:
            ipf = count_instructions(args, window, h264, args.cg_frames)
            print(f"    instructions/frame {ipf / 1e6:.2f} M  ->  Pi 2 estimate "
                  f"{PI2_HZ * PI2_IPC / ipf:.0f} fps on one core (900 MHz, IPC {PI2_IPC})")


if __name__ == "__main__":
    main()
