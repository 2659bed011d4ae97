"""The LED drivers: PWM-dimmable, on gpiozero, with an optional loop that holds the wall's brightness.

The pin factory is injected (gpiozero's `pin_factory=`): lgpio on the Pi, MockFactory in tests and
`--sim`. gpiozero is imported only when LEDs are built.

lgpio's PWM is timed in software. A camera exposure that is not a whole number of PWM periods
catches a varying number of "on" slices from row to row and frame to frame: at 1 kHz and 80 %, a
1.5 ms exposure sees the light vary by about +-8 % in bands that move every frame, texture the
odometry would track. `pwm_exposure_us` makes the exposure a whole number of periods; at full level
(brightness 1.0) the pin is steadily on and any exposure is fine. After close, lgpio leaves the pins
as floating inputs: the drivers' PWM inputs need a pull-down (docs/deploy.md) to stay dark then.
"""

from __future__ import annotations

import logging
import threading
from dataclasses import dataclass

import numpy as np

from .errors import CrawlerError
from .ports import Output

_log = logging.getLogger(__name__)


class Leds:
    """All LED drivers at one brightness level in [0, 1]."""

    def __init__(self, pins, *, brightness: float = 1.0, frequency_hz: float = 1000.0,
                 active_high: bool = True, pin_factory=None):
        from gpiozero import PWMLED
        from gpiozero.exc import GPIOZeroError

        self.brightness = float(brightness)
        self._lock = threading.Lock()
        self._leds = []
        for pin in pins:
            try:
                self._leds.append(PWMLED(pin, active_high=active_high, initial_value=0,
                                         frequency=frequency_hz, pin_factory=pin_factory))
            except Exception as exc:        # gpiozero's own errors, and lgpio's (pin busy, frequency)
                self.close()
                kind = "gpiozero" if isinstance(exc, GPIOZeroError) else type(exc).__name__
                raise CrawlerError(
                    f"LED pin {pin!r} cannot be driven ({kind}: {exc}); check [leds] pins (BCM numbers), "
                    "that no other program holds the pin, that the user is in the 'gpio' group and "
                    "[leds] frequency_hz (use --sim off the Pi)") from None
        self.level = 0.0

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def on(self, level: float | None = None):
        """Light at `level` (default: the configured brightness)."""
        self.set(self.brightness if level is None else level)

    def set(self, level: float):
        level = min(1.0, max(0.0, float(level)))
        with self._lock:
            for led in self._leds:
                led.value = level
            self.level = level

    def off(self):
        self.set(0.0)

    def close(self):
        """Switch off and free the pins; safe to call twice."""
        with self._lock:
            for led in self._leds:
                try:
                    led.value = 0           # driven low before the pin is released
                    led.close()
                except Exception:   # closing must never mask the error that got us here
                    _log.debug("closing LED failed", exc_info=True)
            self._leds = []
            self.level = 0.0


def pwm_exposure_us(exposure_us: int, frequency_hz: float) -> int:
    """The exposure nearest `exposure_us` that is a whole number (>= 1) of PWM periods, so every
    row integrates the same light whatever the phase (ties round down: less motion blur)."""
    period = 1e6 / frequency_hz
    periods = max(1, int(exposure_us / period + 0.5 - 1e-9))
    return int(round(periods * period))


class NoLeds:
    """Stand-in when no pins are configured (replay on a PC)."""

    brightness = 0.0
    level = 0.0

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        pass

    def on(self, level=None):
        pass

    def set(self, level):
        pass

    def off(self):
        pass

    def close(self):
        pass


@dataclass
class BrightnessLoop:
    """Integral control of LED level toward a target mean grey of the ROI.

    Pure: feed it the ROI mean each frame, apply what it returns. The gain is per frame and small, so
    a textured wall passing by does not make the lights pump.
    """

    target: float = 110.0        # mean grey value of the ROI to hold
    gain: float = 0.002          # level change per grey level of error per frame
    min_level: float = 0.05
    max_level: float = 1.0

    def update(self, level: float, mean_grey: float) -> float:
        new = level + self.gain * (self.target - mean_grey)
        return min(self.max_level, max(self.min_level, new))


class AutoBrightness(Output):
    """Each frame, nudge the LEDs toward the target mean grey of the region being measured."""

    def __init__(self, leds, roi, loop: BrightnessLoop):
        self.leds, self.roi, self.loop = leds, roi, loop

    def write(self, frame, estimate, run):
        x, y, w, h = self.roi
        mean = float(np.mean(frame.gray[y:y + h:4, x:x + w:4]))     # every 4th pixel is plenty
        self.leds.set(self.loop.update(self.leds.level, mean))
