"""What the wheel costs on the Pi 2, counted in ARM instructions on the armhf yardstick.

    python benchmarks/wheel_cost.py                 # both figures (runs the yardstick 8 times)
    python benchmarks/wheel_cost.py edges N [--bare]    # one run: N quadrature edges
    python benchmarks/wheel_cost.py frames N [--bare]   # one run: N frames of poll + fusion

edges: N edges through gpiozero MockFactory pins into a RotaryEncoder(max_steps=0); --bare drives
the same pins with no encoder attached (the mock's own cost, which lgpio's callback thread
replaces on a Pi). frames: per camera frame the kernel backend's poll (one absinfo on a device
whose ioctl returns at once) and WheelFusion.update on the issue-12 run (blind 1.0-1.3 s, slip
8-9 s, 0.2 m/s, 30 fps); --bare builds the same inputs and skips both. Costs are slopes between a
short and a long run, so start-up cancels. Not a test: it prints figures (docs/wheel.md).
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
COUNT = os.environ.get("ARM_COUNT", "/work/shared/tools/armhf/count")
PI2_HZ, PI2_IPC = 900e6, 0.5


def edges(n: int, bare: bool):
    from gpiozero import InputDevice, RotaryEncoder
    from gpiozero.pins.mock import MockFactory

    factory = MockFactory()
    if bare:
        devs = [InputDevice(17, pull_up=True, pin_factory=factory),
                InputDevice(27, pull_up=True, pin_factory=factory)]
    else:
        enc = RotaryEncoder(17, 27, max_steps=0, pin_factory=factory)
    a, b = factory.pin(17), factory.pin(27)
    cycle = (a.drive_low, b.drive_low, a.drive_high, b.drive_high)   # one period forward
    for _ in range(n // 4):
        for edge in cycle:
            edge()
    if not bare:
        assert enc.steps == n // 4, enc.steps
        print("steps", enc.steps)
    else:
        print("edges", n, devs[0].pin.state)


class _Device:
    """An input device whose EVIOCGABS answers at once: what is left is evdev's Python side."""

    name, path = "rotary@11", "/dev/input/event0"

    def __init__(self, counts):
        from hw_sim.encoder import AbsInfo

        self._info = [(c % (1 << 30), 0, 1 << 30, 0, 0, 0) for c in counts]
        self._absinfo = AbsInfo
        self.i = 0
        self.fd = -1

    def capabilities(self, absinfo=True):
        return {3: [(0, self._absinfo(0, 0, 1 << 30, 0, 0, 0))]}

    def absinfo(self, axis):
        info = self._info[self.i]
        self.i += 1
        return self._absinfo(*info)       # python-evdev: AbsInfo(*_input.ioctl_EVIOCGABS(fd, axis))

    def close(self):
        pass


def frames(n: int, bare: bool):
    import numpy as np

    from crawler.wheel import FusionParams, VisionFix, WheelFusion
    from crawler.wheel.kernel import KernelEncoder

    cpm, fps = 5000.0, 30.0
    t = np.arange(n) / fps
    truth = 0.2 * t
    rim = 0.2 * (t + 0.2 * (np.clip(t, 8.0, 9.0) - 8.0))
    counts = np.floor(1.03 * cpm * 0.2 * (t + 0.012) + 1.03 * cpm * (rim - truth)).astype(int).tolist()
    blind = ((t >= 1.0) & (t < 1.3)).tolist()
    vision = (truth + np.random.default_rng(1).normal(0, 3e-5, n)).tolist()
    times = (t + 0.012).tolist()
    clock = iter(times).__next__
    port = KernelEncoder("rotary@11", cpm, clock=clock, opener=lambda name: _Device(counts),
                         boot_id=lambda: "boot").open()
    fusion = WheelFusion(FusionParams(quantum_m=1 / cpm))
    held = 0.0
    out = None
    for i, ts in enumerate(t.tolist()):
        if blind[i]:
            fix = VisionFix(ts, held, None, False, False)
        else:
            held = vision[i]
            fix = VisionFix(ts, held, 3e-5, True, False)
        if not bare:
            out = fusion.update(fix, port.read())
    print("distance", out.distance_m if out else None, "slips", fusion.slip_count)


def _count(*args) -> int:
    r = subprocess.run([COUNT, *args], cwd=ROOT, capture_output=True, text=True)
    m = re.search(r"arm instructions: (\d+)", r.stderr)
    if r.returncode or not m:
        raise SystemExit(f"wheel_cost: {' '.join(args)} failed: {r.stderr.strip()[-400:]}")
    return int(m.group(1))


def _slope(kind: str, n1: int, n2: int, bare: bool) -> float:
    extra = ["--bare"] if bare else []
    script = "benchmarks/wheel_cost.py"
    return (_count(script, kind, str(n2), *extra) - _count(script, kind, str(n1), *extra)) / (n2 - n1)


def report():
    edge = _slope("edges", 4000, 40000, False)
    edge_bare = _slope("edges", 4000, 40000, True)
    frame = _slope("frames", 150, 450, False)
    frame_bare = _slope("frames", 150, 450, True)
    us = 1e6 / (PI2_HZ * PI2_IPC)
    print(f"gpiozero RotaryEncoder: {edge:,.0f} ARM instructions per edge with MockFactory pins "
          f"({edge * us:.1f} us on a Pi 2), of which the mock pin {edge_bare:,.0f}; encoder "
          f"{edge - edge_bare:,.0f} ({(edge - edge_bare) * us:.1f} us)")
    print(f"kernel backend poll + fusion: {frame - frame_bare:,.0f} ARM instructions per frame "
          f"({(frame - frame_bare) * us:.0f} us on a Pi 2); inputs alone {frame_bare:,.0f}")


if __name__ == "__main__":
    if len(sys.argv) == 1:
        report()
    else:
        kind, n, bare = sys.argv[1], int(sys.argv[2]), "--bare" in sys.argv
        {"edges": edges, "frames": frames}[kind](n, bare)
