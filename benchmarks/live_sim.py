"""Accuracy of the live path: crawler/camera.py on hw_sim's Picamera2 fake, no encoding in between.

    python benchmarks/live_sim.py [--frames 1200] [--sensor imx219]

Runs the planned sensor window (default 240x240 at 60 fps) through Picamera2Source and the Odometer
on a simulated clock (no wall time), for a constant-speed and a stop-and-go run, with and without
the rolling-shutter correction, and prints the distance error against the simulator's truth.
Not a test: it prints figures (docs/accuracy.md).
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def run(sensor: str, profile: str, speed: float, frames: int, rolling_shutter: bool):
    from crawler.camera import Picamera2Source
    from crawler.geometry import Mount, make_projection
    from crawler.odometry import Odometer
    from crawler.settings import CameraSettings
    from hw_sim.picamera2_fake import ManualClock, MappedArray, SimWorld, make_picamera2

    clock = ManualClock()
    world = SimWorld(sensor, clock=clock.ns, sleep=clock.sleep, speed_m_s=speed, profile=profile)
    source = Picamera2Source(CameraSettings(output_size=(240, 240), fps=60.0, exposure_us=1500),
                             make_picamera2(world), mapped_array=MappedArray)
    with source:
        cam = source.plan.camera
        if not rolling_shutter:
            cam = dataclasses.replace(cam, readout_s=0.0)
        odo = Odometer(cam, make_projection("cylinder", Mount.from_car(0.30, 0.151, 0.054, 0.0)),
                       (0, 0, 240, 240))
        lost = 0
        for frame in source.frames():
            lost += not odo.update(frame.gray, frame.t_s).tracking
            if frame.index + 1 >= frames:
                break
        true = world.true_distance_m(source.last_sensor_ns) - world.true_distance_m(source.first_sensor_ns)
        return source.plan, odo.distance, true, lost


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=1200)
    ap.add_argument("--sensor", default="imx219", choices=("imx219", "ov5647", "imx708"))
    ap.add_argument("--speed", type=float, default=0.4)
    args = ap.parse_args(argv)
    for profile in ("constant", "stopgo"):
        for rs in (True, False):
            plan, measured, true, lost = run(args.sensor, profile, args.speed, args.frames, rs)
            print(f"{args.sensor} {plan.fps:.0f} fps readout {plan.readout_s * 1e3:.2f} ms  {profile:8s} "
                  f"{'rolling-shutter correction' if rs else 'no correction':27s} true {true:8.4f} m  "
                  f"measured {measured:8.4f} m  error {100 * (measured - true) / true:+.4f} %  lost {lost}")


if __name__ == "__main__":
    main()
