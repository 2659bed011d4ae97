"""The wheel port: one reading per camera frame, whatever counts the wheel.

A port is a context manager with `read() -> WheelReading | None`. Backends are imported only when
chosen (python-evdev, gpiozero and zenoh load only then), from the table in BACKENDS.
"""

from __future__ import annotations

import importlib
import time
from typing import NamedTuple, Protocol

from ..errors import CrawlerError


class WheelUnavailable(CrawlerError, RuntimeError):
    """The encoder (or the library that reads it) cannot be opened."""


class WheelReading(NamedTuple):
    """Where the wheel was at t_s, in nominal metres (counts / counts_per_m, sign by direction).

    period_m: positions wrap modulo this (the kernel's absolute axis with rollover), else None.
    epoch: the counter's identity; a reading with another epoch comes from a counter that started
    again from zero (a reboot, another process), so no distance can be bridged across it.
    """

    t_s: float
    position_m: float
    period_m: float | None
    epoch: str


class WheelPort(Protocol):
    description: str

    def __enter__(self) -> "WheelPort": ...
    def __exit__(self, *exc) -> None: ...
    def read(self) -> WheelReading | None: ...


class NoWheel:
    """Stand-in when [wheel] backend = "none": never a reading."""

    description = "no wheel"

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        pass

    def open(self):
        return self

    def read(self):
        return None

    def close(self):
        pass


BACKENDS = {
    "evdev": "crawler.wheel.kernel:KernelEncoder",
    "gpiozero": "crawler.wheel.gpio:GpioEncoder",
    "zenoh": "crawler.wheel.remote:ZenohWheel",
}


def open_wheel(settings, *, clock=time.monotonic, **hardware):
    """Build (not yet open) the port that [wheel] names; enter it with `with`.

    clock: the frame clock (readings are stamped with it so the fusion can line them up with
    frames). hardware: what a backend needs injected: `opener` (evdev device factory),
    `boot_id` (evdev), `pin_factory` (gpiozero), `session` or `zenoh_config` (zenoh).
    """
    if not settings.enabled:
        return NoWheel()
    module, _, cls = BACKENDS[settings.backend].partition(":")
    return getattr(importlib.import_module(module), cls).from_settings(settings, clock=clock, **hardware)
