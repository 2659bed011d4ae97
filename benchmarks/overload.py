"""Overload: a loop slower than the camera measures the newest frames, drops the rest, keeps the distance.

    python benchmarks/overload.py [--speed 0.3,0.6] [--tilt 24] [--load 1,2,3] [--workers 1,3]

Renders a hw_sim run at 60 fps, then replays it in real time (`--realtime`, frames handed on at their
times, as a camera delivers them) through the daemon with an output that makes each loop iteration
take `load` frame intervals (a slow disk, a busy core), and prints per load and worker count the share
of frames dropped and the distance error at the last frame measured against the ground truth, beside
the same replay as fast as it goes (every frame measured). Not a test: it prints figures
(docs/performance.md, "Overload").
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from crawler.ports import Output  # noqa: E402

FPS = 60.0


class SlowLoop(Output):
    """An output that takes `seconds` per frame, remembering the last frame it saw."""

    def __init__(self, seconds: float):
        self.seconds, self.last = seconds, None

    def write(self, frame, estimate, run):
        self.last = frame.index
        if self.seconds:
            time.sleep(self.seconds)


def replay(run: dict, tilt: float, load: float | None, workers: int):
    """(frames measured, dropped, distance error % of the path at the last frame measured)."""
    from crawler import settings
    from crawler.daemon import Daemon
    from crawler.measurement import build_odometer, recording_camera, thesis_roi
    from crawler.video import VideoReplay
    from crawler.workers import measuring
    from hw_sim import read_ground_truth

    s = settings.load(None, [f"mount.tilt_deg={tilt}"], {})
    cam = recording_camera(s.camera)
    slow = SlowLoop(0.0 if load is None else load / FPS)
    source = VideoReplay(run["h264"], cam, realtime=load is not None, default_roi=thesis_roi(cam.width, cam.height))
    with source:
        odo = build_odometer(s, cam, source.default_roi)
        with measuring(odo, (cam.height, cam.width), workers) as measure:
            daemon = Daemon(source, odo, name="bench", outputs=[slow], measure=measure)
            stats = daemon.run()
    true = read_ground_truth(run["csv"])["distance_m"][slow.last]
    return stats.frames, stats.dropped, 100 * (daemon.distance_m - true) / run["truth"]["path_length_m"]


def main(argv=None):
    from hw_sim import SimConfig, write_run

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=str(ROOT / "out" / "overload"))
    ap.add_argument("--speed", default="0.3,0.6")
    ap.add_argument("--tilt", type=float, default=24.0)
    ap.add_argument("--duration", type=float, default=4.0)
    ap.add_argument("--load", default="2,3", help="loop iteration in frame intervals (2: twice too slow)")
    ap.add_argument("--workers", default="1,3")
    args = ap.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    for speed in (float(v) for v in args.speed.split(",")):
        cfg = SimConfig(tilt_deg=args.tilt, speed_m_s=speed, fps=FPS, duration_s=args.duration, seed=2)
        run = write_run(cfg, out, f"t{args.tilt:g}-v{speed:g}")
        run["truth"] = json.loads(Path(run["json"]).read_text())
        print(f"tilt {args.tilt:g} deg, {speed:g} m/s, {FPS:g} fps, {run['truth']['frames']} frames:")
        for w in (int(v) for v in args.workers.split(",")):
            n, _, err = replay(run, args.tilt, None, w)
            print(f"    workers {w}: every frame        {n:4d} measured, error {err:+.4f} %")
            for load in (float(v) for v in args.load.split(",")):
                n, dropped, err = replay(run, args.tilt, load, w)
                print(f"    workers {w}: loop {load:g}x too slow {n:4d} measured, {dropped:4d} dropped "
                      f"({100 * dropped / (n + dropped):.0f} %), error {err:+.4f} %")


if __name__ == "__main__":
    main()
