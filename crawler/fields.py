"""How a settings field is declared and checked: `_f(default, check)`, the checks, and the one
validator that turns a TOML value into the field's type or a BadConfig naming the key, the value
and what it must be. crawler/settings.py declares the fields with these."""

from __future__ import annotations

import math
from dataclasses import field, fields
from typing import Any, Callable

from .errors import BadConfig


def _f(default: Any, check: Callable[[Any], str | None] | None = None) -> Any:
    return field(default=default, metadata={"check": check})


# -- checks: each returns None when the value is fine, else what it must be ---------------------------

def between(lo: float, hi: float, *, lo_open: bool = False, hi_open: bool = False):
    def check(v):
        ok = (lo < v if lo_open else lo <= v) and (v < hi if hi_open else v <= hi)
        return None if ok else f"must be between {lo:g} and {hi:g}"
    return check


def positive(v) -> str | None:
    return None if v > 0 else "must be > 0"


def one_of(*choices: str):
    return lambda v: None if v in choices else f"must be one of {', '.join(choices)}"


def _odd_window(v) -> str | None:
    return None if v >= 5 and v % 2 == 1 else "must be an odd number >= 5"


def _name(v) -> str | None:
    if v and all(ch.isalnum() or ch in "-_" for ch in v):
        return None
    return "must be letters, digits, '-' or '_' (it becomes a Zenoh key segment)"


def _distortion(v) -> str | None:
    return None if len(v) in (4, 5, 8) else "must be 4, 5 or 8 numbers in OpenCV order [k1, k2, p1, p2, k3]"


def _output_size(v) -> str | None:
    ok = len(v) == 2 and all(32 <= x <= 2048 and x % 2 == 0 for x in v)
    return None if ok else "must be [width, height], even, 32..2048"


def _window(v) -> str | None:
    ok = len(v) == 4 and all(x >= 0 for x in v)
    return None if ok else "must be [x, y, w, h] in native pixels of the sensor's active area"


def _roi(v) -> str | None:
    return None if len(v) == 4 else "must be four integers [x, y, w, h] in frame pixels"


def _pins(v) -> str | None:
    return None if all(0 <= p <= 27 for p in v) else "must be BCM GPIO numbers 0..27, e.g. [12, 13]"


def _tilt(v) -> str | None:
    if v == "auto" or not isinstance(v, str) and -80 <= v <= 80:
        return None
    return 'must be between -80 and 80 (degrees), or "auto" (estimated from the flow, docs/calibration.md)'


def _lgpio_frequency(v) -> str | None:
    # lgpio's software PWM takes 0.1..10000 Hz; beyond that it raises from inside gpiozero
    return None if 0.1 <= v <= 10000 else "must be between 0.1 and 10000 Hz (lgpio's PWM range)"


# -- the one validator ----------------------------------------------------------------------------------

_TYPES = {"int": (int,), "float": (int, float), "bool": (bool,), "str": (str,), "float | str": (int, float, str)}
_TYPE_NAMES = {"int": "an integer", "float": "a number", "bool": "true or false", "str": "a string",
               "float | str": 'a number or "auto"'}


def _where(section: str, key: str) -> str:
    return f"[{section}] {key}" if section else key


def _coerce(section: str, key: str, value, annotation: str):
    """A TOML value to the field's type (lists become tuples, ints become floats), or BadConfig."""
    base, optional = annotation.removesuffix(" | None"), annotation.endswith(" | None")
    if value is None and optional:
        return None
    if base.startswith("tuple["):
        item = base[len("tuple["):].split(",")[0].strip()
        if not isinstance(value, (list, tuple)):
            raise BadConfig(f"{_where(section, key)} = {value!r} must be a list of "
                            f"{_TYPE_NAMES[item].removeprefix('a ').removeprefix('an ')}s")
        return tuple(_coerce(section, key, v, item) for v in value)
    ok = isinstance(value, _TYPES[base]) and not (isinstance(value, bool) and base != "bool")
    if not ok:
        raise BadConfig(f"{_where(section, key)} = {value!r} must be {_TYPE_NAMES[base]}")
    if base == "float | str":
        base = "str" if isinstance(value, str) else "float"
    if base == "float":
        if not math.isfinite(value):
            raise BadConfig(f"{_where(section, key)} = {value!r} must be a finite number")
        return float(value)
    return value


def _check_field(obj, section: str, name: str, value, annotation: str) -> None:
    _coerce(section, name, value, annotation)         # the type, also for values set in Python
    check = next(f for f in fields(obj) if f.name == name).metadata.get("check")
    if check is None or value is None:
        return
    problem = check(value)
    if problem:
        raise BadConfig(f"{_where(section, name)} = {_show(value)} {problem}")


def _check_fields(obj, section: str) -> None:
    for f in fields(obj):
        _check_field(obj, section, f.name, getattr(obj, f.name), f.type)


def _show(value) -> str:
    return repr(list(value)) if isinstance(value, tuple) else repr(value)
