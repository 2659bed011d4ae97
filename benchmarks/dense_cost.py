"""What one dense shift costs on the Pi 2 (a wall too smooth for features), in ARM instructions.

    python benchmarks/dense_cost.py                # the figures (runs the yardstick 6 times)
    python benchmarks/dense_cost.py N MODE         # one run: N dense shifts; MODE full|image|plain|clipped

N frames of a faint wall (3 % contrast, 8 px a frame) through the odometer's DenseShift on a
240 x 240 window at 24 deg: `full` as crawlerd runs it (on the wall grid, refined), `image` refined
on the image itself (no wall grid), `plain` OpenCV's shift of the image as it was before, `clipped`
as `full` under the LED's highlight clipped at its middle, its light swinging by 10 %. The cost
is the slope between a short and a long run, so start-up cancels. It is paid only on frames
without features (docs/odometry.md, "Weak texture"); a tracked frame pays none of it. Not a test:
it prints figures (docs/performance.md).
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))


def shifts(n: int, mode: str):
    import cv2
    import numpy as np

    from crawler.dense import DenseParams
    from crawler.geometry import Camera, Mount, make_projection
    from crawler.odometry import Odometer
    from crawler.odometry_params import OdometryParams

    cam = Camera.from_fov(640, 480, 37.16, 53.50)
    params = OdometryParams(dense=DenseParams(refine=0 if mode == "plain" else 1))
    odo = Odometer(cam, make_projection("cylinder", Mount(0.15, 0.2256, math.radians(24))),
                   (200, 120, 240, 240), params=params)
    dense = odo._dense
    if mode != "full":
        dense.resample(None)
    rng = np.random.default_rng(1)
    wall = cv2.GaussianBlur(rng.normal(0, 1, (800, 240)).astype(np.float32), (0, 0), 6.0)
    wall = 120 + 0.03 * 64 * wall / wall.std()
    yy, xx = np.mgrid[0:240, 0:240]
    lobe = 200.0 * np.exp(-((yy - 120) ** 2 + (xx - 120) ** 2) / (2 * 40.0 ** 2)) if mode == "clipped" else 0.0
    frames = [np.clip((wall[8 * i:8 * i + 240] + lobe) * (1 + (0.1 * math.sin(i / 6) if mode == "clipped" else 0))
                      + rng.normal(0, 0.6, (240, 240)), 0, 255).astype(np.uint8) for i in range(60)]
    found = sum(dense.shift(frames[i % 60], i / 30) is not None for i in range(n))
    print("shifts", found, "of", n)


def report():
    from arm_yardstick import pi2_fps, run, slope

    script = "benchmarks/dense_cost.py"
    for mode in ("plain", "image", "full", "clipped"):
        per = slope(run([script, "30", mode]), run([script, "90", mode]), 60)
        print(f"{mode:7s}: {per / 1e6:.2f} M ARM instructions per dense shift ({1000 / pi2_fps(per):.1f} ms on a Pi 2)")


if __name__ == "__main__":
    if len(sys.argv) == 1:
        report()
    else:
        shifts(int(sys.argv[1]), sys.argv[2])
