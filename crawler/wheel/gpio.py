"""gpiozero's RotaryEncoder: the wheel counted in Python, one callback per edge.

For slow wheels only: every edge runs gpiozero's state machine in Python (docs/wheel.md has the
cost per edge on the Pi 2 yardstick), and the count lives in this process, so a restart loses what
the wheel did while crawlerd was down. gpiozero counts one step per full quadrature period (four
edges): counts_per_m is in those steps. max_steps=0, else gpiozero clamps the count at ±16.
"""

from __future__ import annotations

import time
import uuid

from .port import WheelReading, WheelUnavailable


class GpioEncoder:
    def __init__(self, pins, counts_per_m: float, *, direction: int = 1, clock=time.monotonic,
                 pin_factory=None):
        self.pins = tuple(pins)
        self.clock = clock
        self._per_count = direction / float(counts_per_m)
        self._pin_factory = pin_factory
        self.encoder = None
        self.epoch = None
        self.description = f"gpiozero RotaryEncoder on GPIO{self.pins[0]}/GPIO{self.pins[1]}"

    @classmethod
    def from_settings(cls, s, *, clock=time.monotonic, pin_factory=None):
        return cls(s.pins, s.counts_per_m, direction=s.direction, clock=clock, pin_factory=pin_factory)

    def __enter__(self):
        return self.open()

    def __exit__(self, *exc):
        self.close()

    def open(self):
        from gpiozero import RotaryEncoder
        from gpiozero.exc import GPIOZeroError

        try:
            self.encoder = RotaryEncoder(self.pins[0], self.pins[1], max_steps=0,
                                         pin_factory=self._pin_factory)
        except GPIOZeroError as exc:
            raise WheelUnavailable(f"[wheel] pins = {list(self.pins)} cannot be read: {exc}; check the "
                                   "wiring, that the user is in the 'gpio' group and that no other "
                                   "device claims the pins") from None
        self.epoch = f"gpiozero:{uuid.uuid4().hex[:12]}"   # the count starts at 0 in each process
        return self

    def read(self) -> WheelReading | None:
        enc = self.encoder
        if enc is None:
            return None
        return WheelReading(self.clock(), enc.steps * self._per_count, None, self.epoch)

    def close(self):
        enc, self.encoder = self.encoder, None
        if enc is not None:
            enc.close()
