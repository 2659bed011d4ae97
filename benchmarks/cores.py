"""Four cores: the odometry with [odometry] workers = N against one process, per frame and per process.

    python benchmarks/cores.py [--arm] [--fps 200] [--speed 0.3,0.6] [--workers 2,3,4] [--frames 450]

Renders the live path's 240x240 window (throughput.py's case) at the IMX219 VGA mode's frame rate,
then on this machine: the distances of workers = N against workers = 1 (lockstep, depth 1: bit for
bit; the pipeline: within a few micrometres) and the wall-clock frame rate here (x86, two cores:
not the Pi). With --arm, on the ARM yardstick (benchmarks/arm_yardstick.py, qemu-arm; every forked
worker is counted on its own): ARM instructions per frame of the main process, split into the
odometry's own work and the pipeline's (copying the frame in, requests, results), and of each
worker, as slopes between a short and a long run, and what they allow on a Pi 2 at 900 MHz x IPC 0.5:
the main process is the critical path, a worker has (N - 1) frame intervals per frame.
Not a test: it prints figures (docs/performance.md).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

WINDOW = (360, 360, 240, 240)       # throughput.py's 240x240 case
STAGES = {0: "start-up, loading frames", 1: "main: odometry (consensus, keyframes, ...)",
          2: "main: pipeline (frame copy, requests, results)", 3: "main: benchmark loop"}


def frames_of(h264: Path):
    from crawler.geometry import Camera
    from crawler.video import VideoReplay

    src = VideoReplay(h264, Camera.from_fov(WINDOW[2], WINDOW[3], 30.0, 30.0))
    with src:
        return [(f.gray.copy(), f.t_s, f.intra) for f in src.frames()]


def run(frames, workers: int, depth=None, stages=None):
    """Distances of every frame, the pool's counts and the wall time, for one configuration."""
    from throughput import build

    from crawler.daemon import measure_serially
    from crawler.ports import Frame

    odo = build(WINDOW, None, os.environ.get("CORES_POSE", "on"))   # the default config: pitch and height per frame
    src = (Frame(i, t, g, intra=k) for i, (g, t, k) in enumerate(frames))
    t0 = time.perf_counter()
    if workers == 1:
        d = [e.distance_m for _, e in measure_serially(odo, src)]
        return d, {}, time.perf_counter() - t0
    from crawler.workers import TrackerPool

    with TrackerPool(odo, frames[0][0].shape, workers, depth) as pool:
        t0 = time.perf_counter()
        if stages:
            stages.set(3)
        d = [e.distance_m for _, e in pool.measure(src)]
        if stages:
            stages.set(0)
        return d, dict(pool.counts), time.perf_counter() - t0


def host(frames, workers_list, truth_m):
    import numpy as np

    base, _, wall = run(frames, 1)
    print(f"    this PC, 1 process: {len(frames) / wall:.0f} fps, distance error "
          f"{100 * (base[-1] - truth_m) / truth_m:+.4f} %")
    for w in workers_list:
        lock, _, _ = run(frames, w, depth=1)
        piped, counts, wall = run(frames, w)
        diff = np.abs(np.array(piped) - base).max()
        print(f"    this PC, workers = {w}: {len(frames) / wall:.0f} fps; lockstep {'bit for bit' if lock == base else 'DIFFERS'}"
              f", pipeline max |distance difference| {diff * 1e6:.2f} um; {counts}")


def arm(frames, h264: Path, workers_list, n1: int, n2: int):
    import arm_yardstick as ay
    from throughput import save_frames

    with tempfile.TemporaryDirectory() as tmp:
        save_frames(Path(tmp), frames[:n2])
        for w in [1, *workers_list]:
            runs = [ay.run(["benchmarks/cores.py", "--_arm", tmp, str(n), str(w)]) for n in (n1, n2)]
            print_arm(w, runs, n2 - n1)


def print_arm(workers: int, runs, frames: int):
    import arm_yardstick as ay

    short, long = runs
    main = (long.total - short.total) / frames
    stage = {s: (long.stage(s) - short.stage(s)) / frames for s in STAGES}
    kids = sorted(long.children, key=lambda c: -c.total)[:max(0, workers - 1)]
    kids0 = sorted(short.children, key=lambda c: -c.total)[:max(0, workers - 1)]
    per_worker = [(a.total - b.total) / frames for a, b in zip(kids, kids0)]
    total = main + sum(per_worker)
    g = json.loads(long.stdout)
    line = f"    ARM, workers = {workers}: main process {main / 1e6:.2f} M/frame (-> {ay.pi2_fps(main):.0f} fps)"
    if per_worker:      # a worker's instructions over all the run's frames: its core's limit directly
        line += (f", each worker {', '.join(f'{v / 1e6:.2f}' for v in per_worker)} M per frame of the run "
                 f"(-> {ay.pi2_fps(max(per_worker)):.0f} fps), all processes {total / 1e6:.2f} M/frame\n"
                 f"        main process: odometry {stage[1] / 1e6:.2f}, pipeline {stage[2] / 1e6:.2f}, "
                 f"benchmark loop {stage[3] / 1e6:.2f} M/frame; {g['counts']}")
    print(line)


def arm_replay(h264: Path, meta: dict, fps: float, workers_list, n1: int, n2: int):
    """`python -m crawler --replay` with --workers N (the daemon's whole loop), minus bare decoding."""
    import arm_yardstick as ay
    from throughput import replay_args

    dec = [ay.run(["benchmarks/cores.py", "--_decode", str(h264), str(n)]) for n in (n1, n2)]
    decode = ay.slope(*dec, n2 - n1)
    # OpenCV's armhf build (TBB) ignores OPENCV_FOR_THREADS_NUM: one process runs it on the guest's
    # threads unless told otherwise; the pool sets one thread itself
    one_thread = ["-c", "import sys, cv2; cv2.setNumThreads(1); from crawler.cli import main; sys.exit(main())"]
    for w, how in [(1, ["-m", "crawler"]), (1, one_thread)] + [(w, ["-m", "crawler"]) for w in workers_list]:
        rep = [ay.run([*how, "--replay", str(h264), "--fps", f"{fps:g}", "--no-publish", "--max-frames",
                       str(n), "--workers", str(w), *replay_args(h264, meta)]) for n in (n1, n2)]
        main = ay.slope(*rep, n2 - n1)
        kids = [(a.total - b.total) / (n2 - n1) for a, b in
                zip(*(sorted(r.children, key=lambda c: -c.total)[:w - 1] for r in (rep[1], rep[0])))]
        label = f"--workers {w}" + (", OpenCV on one thread" if how is one_thread else "")
        print(f"    ARM, crawlerd --replay {label}: main process {main / 1e6:.2f} M/frame, of which decoding "
              f"{decode / 1e6:.2f}: the daemon's loop without decoding {(main - decode) / 1e6:.2f} M/frame (-> "
              f"{ay.pi2_fps(main - decode):.0f} fps)" + (f"; workers {', '.join(f'{k / 1e6:.2f}' for k in kids)}"
                                                          if kids else ""))


def _decode(h264, n):
    """Inside qemu: bare decoding of the first n frames, as the replay does it."""
    from crawler.geometry import Camera
    from crawler.video import VideoReplay

    with VideoReplay(Path(h264), Camera.from_fov(WINDOW[2], WINDOW[3], 30.0, 30.0)) as src:
        for i, _ in enumerate(src.frames()):
            if i + 1 >= int(n):
                break


def _arm(tmp, n, workers):
    """Inside qemu: n preloaded frames through workers = N, the main process's stages marked."""
    import cv2

    import arm_yardstick
    from throughput import load_frames

    from crawler import workers as W
    from crawler.odometry import Odometer

    cv2.setNumThreads(1)
    st = arm_yardstick.Stages()
    st.wrap(Odometer, "update", 1)
    for name in ("_admit", "_sync", "_collect"):
        st.wrap(W.TrackerPool, name, 2)
    data = load_frames(tmp)[:int(n)]
    d, counts, _ = run(data, int(workers), stages=st)
    print(json.dumps({"distance_m": d[-1], "counts": counts}))


def main(argv=None):
    argv = sys.argv[1:] if argv is None else argv
    if argv and argv[0] == "--_arm":
        return _arm(*argv[1:])
    if argv and argv[0] == "--_decode":
        return _decode(*argv[1:])
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=str(ROOT / "out" / "cores"))
    ap.add_argument("--fps", type=float, default=200.0)
    ap.add_argument("--speed", default="0.3")
    ap.add_argument("--workers", default="2,3,4")
    ap.add_argument("--frames", type=int, default=450, help="frames per rendered run (the long ARM run)")
    ap.add_argument("--arm", action="store_true", help="count ARM instructions per process on the yardstick")
    ap.add_argument("--arm-replay", action="store_true",
                    help="count `python -m crawler --replay --workers N` (the daemon's loop) and bare decoding")
    ap.add_argument("--no-host", dest="host", action="store_false", help="skip the checks and timing on this PC")
    args = ap.parse_args(argv)
    from throughput import make_run

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    workers = [int(w) for w in args.workers.split(",")]
    for speed in (float(v) for v in args.speed.split(",")):
        h264, meta = make_run(out, f"240x240-v{speed:g}-f{args.fps:g}", WINDOW, speed, args.fps, args.frames)
        frames = frames_of(h264)
        truth = float(h264.with_suffix(".csv").read_text().splitlines()[len(frames)].split(",")[2])
        print(f"240x240 at {speed:g} m/s, {args.fps:g} fps, {len(frames)} frames:")
        if args.host:
            host(frames, workers, truth)
        if args.arm:
            arm(frames, h264, workers, args.frames // 3, args.frames)
        if args.arm_replay:
            arm_replay(h264, meta, args.fps, workers, args.frames // 3, args.frames)


if __name__ == "__main__":
    main()
