"""Accuracy of the vision/wheel fusion on the issue-12 run, over seeds, encoders and frame rates.

    python benchmarks/wheel_fusion.py [--seeds 20]

The run: 0.2 m/s for 15 s, vision blind 1.0-1.3 s, the wheel 20 % fast 8-9 s, true counts per metre
1.03 x nominal; vision estimates from hw_sim's VisionModel, the wheel from hw_sim's SimEncoder read
through the kernel backend on the fake input device. Prints the final error, when slip was flagged
(relative to 8 s and 9 s), the learned scale's error, and the distance a restart loses (killed at
5 s, last checkpoint 4.5 s, back at 8 s). Not a test: it prints figures (docs/wheel.md).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from crawler.wheel import WheelFusion, WheelSettings, open_wheel  # noqa: E402
from hw_sim.encoder import FakeInputDevice, SimEncoder, VisionModel  # noqa: E402
from hw_sim.motion import Motion  # noqa: E402


class Clock:
    t = 0.0

    def __call__(self):
        return self.t


def one_run(seed: int, cpm: float, fps: float, restart: bool = False):
    clock, motion = Clock(), Motion("constant", 0.2, 15.0)
    enc = SimEncoder(motion.distance, counts_per_m=cpm, scale=1.03, slip=[(8.0, 9.0)], clock=clock,
                     t_boot=0.0, seed=seed)
    settings = WheelSettings.from_dict({"backend": "evdev", "device": "rotary@11", "counts_per_m": cpm})
    params = settings.fusion_params()

    def port():
        return open_wheel(settings, clock=clock, opener=lambda n: FakeInputDevice(enc), boot_id=lambda: "b")

    def frames(fusion, vision, wheel, t0, t1):
        out = []
        for i in range(round(t0 * fps), round(t1 * fps) + 1):
            est = vision.estimate(i / fps)
            clock.t = i / fps + 0.012
            out.append((i / fps, fusion.update(est, wheel.read())))
        return out

    fusion = WheelFusion(params)
    vision = VisionModel(motion.distance, featureless=[(1.0, 1.3)], seed=seed)
    with port() as wheel:
        if not restart:
            return frames(fusion, vision, wheel, 0.0, 15.0)
        frames(fusion, vision, wheel, 0.0, 4.5)
        saved = json.dumps(fusion.to_dict())
        frames(fusion, vision, wheel, 4.5 + 1 / fps, 5.0)
    with port() as wheel:
        resumed = WheelFusion.from_dict(json.loads(saved), params)
        return frames(resumed, VisionModel(motion.distance, seed=seed + 100), wheel, 8.0, 15.0)


def summary(seeds: int, cpm: float, fps: float) -> str:
    errs, onsets, releases, scales, restarts = [], [], [], [], []
    for seed in range(1, seeds + 1):
        run = one_run(seed, cpm, fps)
        t, last = run[-1]
        errs.append(abs(last.distance_m - 0.2 * t) / (0.2 * t) * 100)
        slip = [t for t, f in run if f.slip]
        onsets.append(min(slip) - 8.0)
        releases.append(max(slip) - 9.0)
        scales.append(abs(last.wheel_scale * 1.03 - 1) * 100)
        t, last = one_run(seed, cpm, fps, restart=True)[-1]
        restarts.append(abs(last.distance_m - 0.2 * t) * 1000)
    return (f"| {cpm:.0f} | {fps:.0f} | {max(errs):.4f} | {sum(errs) / len(errs):.4f} | "
            f"+{min(onsets):.3f}..+{max(onsets):.3f} | +{min(releases):.3f}..+{max(releases):.3f} | "
            f"{max(scales):.3f} | {max(restarts):.2f} |")


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=20)
    args = ap.parse_args()
    print(f"{args.seeds} seeds each (VisionModel noise and keyframe walk, encoder phase)\n")
    print("| counts/m | fps | max error % of path | mean error % | slip on after 8 s | "
          "slip off after 9 s | max scale error % | max restart error mm |")
    print("|---|---|---|---|---|---|---|---|")
    for cpm in (1250.0, 5000.0, 20000.0):
        for fps in (30.0, 60.0):
            print(summary(args.seeds, cpm, fps))


if __name__ == "__main__":
    main()
