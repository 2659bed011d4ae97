"""The speed limit of tracking: highest crawler speed with distance error under 1 % per frame rate.

    python benchmarks/speed_limit.py [--fps 30,60,90,200] [--configs default,levels2,levels3,win21]

For each frame rate and LK configuration, renders short hw_sim runs of the live path's 240x240 window
(thesis camera crop, tilt 0) at rising speeds and replays them; prints, per configuration, the
highest speed whose distance error stays under 1 % and the image
motion in px/frame it corresponds to (frames reported lost are allowed; the distance must hold). Not a test: it prints figures (docs/performance.md).
"""

from __future__ import annotations

import argparse
import json
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

WINDOW = (360, 360, 240, 240)
SPEEDS = (0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.8, 1.0, 1.25, 1.5, 1.75, 2.0)
CONFIGS = {
    "default": {},
    "levels2": {"levels": 2},
    "levels3": {"levels": 3},
    "win21": {"win_px": 21},
    "levels3-win21": {"levels": 3, "win_px": 21},
}


def error_at(args):
    out, fps, speed, config = args
    from hw_sim import SimConfig, write_run

    from crawler.flow import FlowParams
    from crawler.geometry import Camera, Mount, make_projection
    from crawler.odometry import Odometer, OdometryParams
    from crawler.video import VideoReplay

    frames = 45
    name = f"v{speed:g}_f{fps:g}"
    if not (out / f"{name}.json").exists():
        write_run(SimConfig(window=WINDOW, speed_m_s=speed, fps=fps, duration_s=(frames - 1) / fps, seed=2),
                  out, name)
    meta = json.loads((out / f"{name}.json").read_text())
    x, y, w, h = WINDOW
    cam = Camera.from_fov(960, 720, 37.16, 53.50).window(x, y, w, h, w, h)
    fp = FlowParams(**{**FlowParams().__dict__, **CONFIGS[config]})
    odo = Odometer(cam, make_projection("cylinder", Mount.from_car(0.30, 0.151, 0.054, 0.0)), (0, 0, w, h),
                   OdometryParams(flow=fp))
    lost = 0
    with VideoReplay(out / f"{name}.h264", cam) as src:
        for f in src.frames():
            lost += not odo.update(f.gray, f.t_s, f.intra).tracking
    err = 100 * abs(odo.distance - meta["true_distance_m"]) / meta["true_distance_m"]
    px_per_frame = speed / fps / (0.2256 / cam.fy)
    return fps, speed, config, err, lost, px_per_frame


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=str(ROOT / "out" / "speed_limit"))
    ap.add_argument("--fps", default="30,60,90,200")
    ap.add_argument("--configs", default=",".join(CONFIGS))
    ap.add_argument("--jobs", type=int, default=2)
    args = ap.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    fpss = [float(f) for f in args.fps.split(",")]
    configs = args.configs.split(",")
    jobs = [(out, fps, v, c) for fps in fpss for v in SPEEDS for c in configs]
    # render each video once before the configurations share it
    with ProcessPoolExecutor(args.jobs) as pool:
        list(pool.map(error_at, [(out, fps, v, configs[0]) for fps in fpss for v in SPEEDS]))
        results = list(pool.map(error_at, jobs))
    print(f"{'config':16s} " + " ".join(f"{f:>16g}fps" for f in fpss))
    for c in configs:
        cells = []
        for fps in fpss:
            ok = [r for r in results if r[0] == fps and r[2] == c and r[3] < 1.0]
            # the limit is the last speed before the first failure
            limit = None
            for v in SPEEDS:
                if any(r[1] == v for r in ok):
                    limit = v
                else:
                    break
            if limit is None:
                cells.append(f"{'< ' + str(SPEEDS[0]):>19s}")
            else:
                px = [r[5] for r in ok if r[1] == limit][0]
                more = ">=" if limit == SPEEDS[-1] else ""
                cells.append(f"{more}{limit:g} m/s ({px:.0f} px)".rjust(19))
        print(f"{c:16s} " + " ".join(cells))
    (out / "results.json").write_text(json.dumps(results))


if __name__ == "__main__":
    main()
