"""The `[wheel]` section: which encoder backend, its wiring, and the fusion's tuning, validated once.

Every value is checked here, so a typo in the TOML fails at start with one line that names the key,
the value and the fix, not 80 m down a pipe.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

from ..errors import BadConfig
from .fusion import FusionParams

BACKENDS = ("none", "evdev", "gpiozero", "zenoh")
_NUM = (int, float)


@dataclass(frozen=True)
class WheelSettings:
    backend: str = "none"               # none | evdev (kernel rotary-encoder) | gpiozero | zenoh
    counts_per_m: float | None = None   # nominal counts per metre of travel, in the backend's counts
    direction: int = 1                  # -1 when the counts fall while the crawler moves forward
    device: str | None = None           # evdev: /dev/input/eventN, or the input device's name
    axis: int = 0                       # evdev: the overlay's linux_axis (0 = ABS_X / REL_X)
    pins: tuple[int, int] | None = None  # gpiozero: BCM numbers of channels A and B
    key: str | None = None              # zenoh: key of the controller's wheel messages
    resolution_m: float | None = None   # zenoh {"distance_m": x} messages: the controller's step
    timeout_s: float = 0.5              # zenoh: a message older than this is no reading
    noise: float = 0.02                 # wheel noise per frame, share of the frame's travel
    scale: float = 1.0                  # prior wheel scale: true metres per nominal metre
    scale_sigma: float = 0.05           # its uncertainty (a fresh wheel: a few percent)
    slip_ratio: float = 0.05            # slip: the wheel ahead by at least this share of its travel
    slip_window_s: float = 0.3          # ...over this much time

    @property
    def enabled(self) -> bool:
        return self.backend != "none"

    @classmethod
    def keys(cls) -> tuple[str, ...]:
        """The keys a user may write in [wheel] (for the config schema)."""
        return tuple(f.name for f in fields(cls))

    @classmethod
    def from_dict(cls, d: dict, *, name: str = "crawler1") -> "WheelSettings":
        """Validate a parsed [wheel] table; `name` is the crawler's, for the default Zenoh key."""
        if not isinstance(d, dict):
            raise BadConfig(f"[wheel] must be a table of keys, got {d!r}")
        unknown = sorted(set(d) - set(cls.keys()))
        if unknown:
            raise BadConfig(f"[wheel] unknown key {unknown[0]!r}; known keys: {', '.join(cls.keys())}")
        kw = dict(d)
        backend = kw.get("backend", "none")
        if backend not in BACKENDS:
            raise BadConfig(f"[wheel] backend = {backend!r} must be one of {', '.join(BACKENDS)}")
        _check_numbers(kw)
        _check_backend(kw, backend, name)
        if "pins" in kw:
            kw["pins"] = tuple(kw["pins"])
        return cls(**kw)

    def fusion_params(self) -> FusionParams:
        """The filter's tuning; the quantum is one count (or the controller's resolution)."""
        quantum = 1.0 / self.counts_per_m if self.counts_per_m else (self.resolution_m or 1e-3)
        return FusionParams(quantum_m=quantum, noise=self.noise, scale=self.scale,
                            scale_sigma=self.scale_sigma, slip_ratio=self.slip_ratio,
                            slip_window_s=self.slip_window_s)


def _number(kw, key, test, rule, fix=""):
    if key not in kw:
        return
    v = kw[key]
    if isinstance(v, bool) or not isinstance(v, _NUM):
        raise BadConfig(f"[wheel] {key} = {v!r} must be a number{fix}")
    if not (math.isfinite(v) and test(v)):
        raise BadConfig(f"[wheel] {key} = {v!r} must be {rule}{fix}")


def _check_numbers(kw):
    _number(kw, "counts_per_m", lambda v: v > 0, "> 0",
            "; set the encoder's counts per metre of travel (counts per wheel turn / wheel "
            "circumference in metres)")
    _number(kw, "resolution_m", lambda v: v > 0, "> 0", "; the controller's distance step in metres")
    _number(kw, "timeout_s", lambda v: 0 < v <= 60, "between 0 and 60 seconds")
    _number(kw, "noise", lambda v: 0 < v < 1, "between 0 and 1 (a share of each frame's travel)")
    _number(kw, "scale", lambda v: 0.2 <= v <= 5, "between 0.2 and 5; check counts_per_m instead")
    _number(kw, "scale_sigma", lambda v: 0 < v <= 1, "between 0 and 1")
    _number(kw, "slip_ratio", lambda v: 0 < v < 1, "between 0 and 1 (0.05 = 5 % ahead)")
    _number(kw, "slip_window_s", lambda v: 0.05 <= v <= 5, "between 0.05 and 5 seconds")
    if "direction" in kw and (isinstance(kw["direction"], bool) or kw["direction"] not in (1, -1)):
        raise BadConfig(f"[wheel] direction = {kw['direction']!r} must be 1 or -1 "
                        "(-1 when the counts fall while the crawler moves forward)")
    axis = kw.get("axis", 0)
    if isinstance(axis, bool) or not isinstance(axis, int) or not 0 <= axis <= 0x3F:
        raise BadConfig(f"[wheel] axis = {axis!r} must be the overlay's linux_axis, an integer "
                        "0..63 (0 = ABS_X / REL_X)")


def _check_backend(kw, backend, name):
    if backend in ("evdev", "gpiozero") and "counts_per_m" not in kw:
        raise BadConfig(f"[wheel] counts_per_m is missing; backend = {backend!r} needs the encoder's "
                        "counts per metre of travel (docs/wheel.md)")
    if backend == "evdev":
        dev = kw.get("device")
        if not isinstance(dev, str) or not dev.strip():
            raise BadConfig(f"[wheel] device = {dev!r} must name the encoder: a path like "
                            "'/dev/input/event0' or the input device's name, e.g. 'rotary@11' "
                            "(see /proc/bus/input/devices)")
    if backend == "gpiozero":
        pins = kw.get("pins")
        if (not isinstance(pins, (list, tuple)) or len(pins) != 2 or pins[0] == pins[1]
                or not all(isinstance(p, int) and not isinstance(p, bool) and 0 <= p <= 27 for p in pins)):
            raise BadConfig(f"[wheel] pins = {pins!r} must be two different BCM GPIO numbers 0..27 "
                            "for channels A and B, e.g. [17, 27]")
    key = kw.get("key", f"crawler/{name}/wheel")
    if not isinstance(key, str) or not key or any(c in key for c in " ?#$*") or key.startswith("/") \
            or key.endswith("/"):
        raise BadConfig(f"[wheel] key = {key!r} must be a plain Zenoh key like 'crawler/{name}/wheel' "
                        "(no spaces, wildcards, '?', '#' or leading/trailing '/')")
    kw["key"] = key
