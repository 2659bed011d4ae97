"""Render cost of hw_sim per frame: 960x720 thesis frames, the live path's 240x240, and the fake.

    python benchmarks/render_speed.py [--frames N] [--repeat R]

For each case: ms per frame with the texture tiles already cached (the renderer alone), and ms per
frame over a run at the case's speed (new tiles included). The fake line is the Picamera2 fake on
the live path's plan (IMX219 VGA mode, ScalerCrop 1400,1232,480,480 scaled to 240x240, 60 fps),
timed as one capture + make_array on a ManualClock. Not a test: it prints figures
(docs/simulator.md, Speed).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

LIVE_CROP = (1400, 1232, 480, 480)
CASES = {   # name: SimConfig fields
    "960x720 tilt 0": dict(tilt_deg=0.0),
    "960x720 tilt 24": dict(tilt_deg=24.0),
    "960x720 tilt 40": dict(tilt_deg=40.0),
    "240x240 window tilt 0": dict(tilt_deg=0.0, window=(360, 360, 240, 240)),
    "240x240 window tilt 40": dict(tilt_deg=40.0, window=(360, 360, 240, 240)),
}


def best_ms(fn, frames: int, repeat: int) -> float:
    """Fastest of `repeat` passes of `frames` calls fn(i), in ms per call (a shared machine)."""
    best = float("inf")
    for _ in range(repeat):
        t0 = time.perf_counter()
        for i in range(frames):
            fn(i)
        best = min(best, (time.perf_counter() - t0) / frames)
    return 1000 * best


def simulator_case(fields: dict, frames: int, repeat: int) -> tuple[float, float]:
    from hw_sim import SimConfig, Simulator

    cfg = SimConfig(speed_m_s=0.2, duration_s=60.0, seed=1, **fields)
    sim = Simulator(cfg)
    sim.render(0.0)
    cached = best_ms(lambda i: sim.render(0.0 + 1e-4 * (i % 2)), frames, repeat)
    fresh = Simulator(cfg)
    run = best_ms(lambda i: fresh.render(i / cfg.fps), frames, 1)
    return cached, run


def fake_case(frames: int, repeat: int) -> float:
    from hw_sim.picamera2_fake import ManualClock, SimWorld, make_picamera2

    clock = ManualClock()
    world = SimWorld("imx219", clock=clock.ns, sleep=clock.sleep, speed_m_s=0.2, seed=1)
    cam = make_picamera2(world)(0)
    cfg = cam.create_video_configuration(main={"size": (240, 240), "format": "YUV420"}, raw=None,
                                         controls={"FrameDurationLimits": (16667, 16667), "ExposureTime": 1500,
                                                   "AnalogueGain": 4.0, "ScalerCrop": LIVE_CROP})
    cam.configure(cfg)
    cam.start()

    def one(_):
        with cam.captured_request(wait=1.0) as r:
            r.make_array("main")
    try:
        one(0)
        return best_ms(one, frames, repeat)
    finally:
        cam.close()


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=60)
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args(argv)
    print(f"{'case':28s} {'cached ms':>10s} {'run ms':>8s}")
    for name, fields in CASES.items():
        cached, run = simulator_case(fields, args.frames, args.repeat)
        print(f"{name:28s} {cached:10.2f} {run:8.2f}")
    print(f"{'fake 240x240 capture':28s} {fake_case(args.frames, args.repeat):10.2f}")


if __name__ == "__main__":
    main()
