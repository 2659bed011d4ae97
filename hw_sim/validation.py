"""SimConfig's checks: JSON-ish values coerced to the declared types, then every range, each
failure a ConfigError naming the field, its value and what would be right."""
from __future__ import annotations

import math
import os
from dataclasses import fields
from typing import TYPE_CHECKING, Any

import numpy as np

from .errors import ConfigError

if TYPE_CHECKING:
    from .config import SimConfig

PROFILES = ("constant", "accel", "stopgo", "reverse")
TEXTURES = ("concrete", "masonry", "image")
PRESETS = ("ultrafast", "superfast", "veryfast", "faster", "fast", "medium", "slow", "slower",
           "veryslow")
MAX_SPEED_M_S = 2.0       # the studied range is 0..1 m/s; a little headroom for stress runs
MAX_TILT_DEG = 60.0
MAX_VIEW_DEG = 85.0       # |tilt| + vfov/2 + jitter beyond this looks along the pipe, not at the wall


def _set(cfg: SimConfig, name: str, value: Any) -> None:
    object.__setattr__(cfg, name, value)


PAIRS = ("featureless", "wet_patches", "dropped_bursts", "led_blackouts", "tilt_schedule", "height_profile")


def normalise(c: SimConfig) -> None:
    """Coerce JSON-ish values (lists, ints for floats) to the declared types, naming what fails."""
    for name, n, typ in (("window", 4, int), ("output_size", 2, int), ("distortion", 5, float),
                         ("brick_mm", 2, float), ("wet_highlight_at", 2, float)):
        v = getattr(c, name)
        if v is None:
            continue
        try:
            t = tuple(v)
            if len(t) != n:
                raise ValueError
            if typ is int and any(float(x) != int(x) for x in t):
                raise ValueError
            _set(c, name, tuple(typ(x) for x in t))
        except (TypeError, ValueError):
            raise ConfigError(name, v, f"must be {n} {typ.__name__}s") from None
    for name in PAIRS:
        v = getattr(c, name)
        try:
            pairs = tuple((float(a), float(b)) for a, b in v)
        except (TypeError, ValueError):
            raise ConfigError(name, v, "must be a sequence of (a, b) pairs") from None
        if not all(math.isfinite(x) for p in pairs for x in p):
            raise ConfigError(name, v, "must hold finite numbers")
        _set(c, name, pairs)
    for f in fields(c):
        _coerce(c, f.name, f.type, getattr(c, f.name))
    if c.tilt_schedule:
        t0 = float(np.interp(0.0, *zip(*c.tilt_schedule)))
        if c.tilt_deg == 0.0:
            _set(c, "tilt_deg", t0)
        elif abs(c.tilt_deg - t0) > 1e-9:
            raise ConfigError("tilt_schedule", c.tilt_schedule, f"starts at {t0:g} deg but tilt_deg={c.tilt_deg:g}: "
                              "leave tilt_deg out (it becomes the tilt at t = 0) or make them agree")


def _coerce(c: SimConfig, name: str, typ: str, v: Any) -> None:
    if typ in ("float", "float | None") and v is not None:
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise ConfigError(name, v, "must be a finite number")
        _set(c, name, float(v))
    elif typ == "int":
        if isinstance(v, bool) or not isinstance(v, (int, float)) or float(v) != int(v):
            raise ConfigError(name, v, "must be an integer")
        _set(c, name, int(v))
    elif typ == "bool" and not isinstance(v, bool):
        raise ConfigError(name, v, "must be true or false")
    elif typ in ("str", "str | None") and not isinstance(v, str) and not (v is None and typ == "str | None"):
        raise ConfigError(name, v, "must be a string")


def _check(c: SimConfig, name: str, ok: bool, why: str) -> None:
    if not ok:
        raise ConfigError(name, getattr(c, name), why)


def _range(c: SimConfig, name: str, lo: float, hi: float, lo_open: bool = False) -> None:
    v = getattr(c, name)
    ok = (lo < v if lo_open else lo <= v) and v <= hi
    _check(c, name, ok, f"is outside {'(' if lo_open else '['}{lo:g}, {hi:g}]")


def validate(c: SimConfig) -> None:
    for group in (_validate_camera, _validate_mount, _validate_surface, _validate_motion,
                  _validate_disturbances, _validate_light, _validate_run, _validate_pairs, _validate_view):
        group(c)


def _validate_camera(c: SimConfig) -> None:
    _range(c, "width", 2, 8192)
    _range(c, "height", 2, 8192)
    _range(c, "vfov_deg", 1.0, 150.0)
    _range(c, "hfov_deg", 1.0, 150.0)
    _range(c, "fps", 0.0, 1000.0, lo_open=True)
    if c.window is not None:
        x0, y0, w, h = c.window
        _check(c, "window", w > 0 and h > 0 and x0 >= 0 and y0 >= 0
               and x0 + w <= c.width and y0 + h <= c.height,
               f"must lie inside the {c.width}x{c.height} sensor with w, h > 0")
    W, Hh = c.out_size
    name = "output_size" if c.output_size is not None else ("window" if c.window is not None else "width")
    if not (W % 2 == 0 and Hh % 2 == 0 and 16 <= W <= 4096 and 16 <= Hh <= 4096):
        raise ConfigError(name, getattr(c, name),
                          f"gives a {W}x{Hh} output frame; H.264 yuv420p needs even sizes in 16..4096")


def _validate_mount(c: SimConfig) -> None:
    _range(c, "pipe_diameter_m", 0.02, 10.0)
    _range(c, "car_width_m", 0.0, 10.0, lo_open=True)
    _check(c, "car_width_m", c.car_width_m < c.pipe_diameter_m,
           f"must be smaller than pipe_diameter_m={c.pipe_diameter_m!r} (the car must fit in the pipe)")
    if c.camera_height_m is not None:
        _check(c, "camera_height_m", 0 < c.camera_height_m < c.pipe_diameter_m,
               f"must be in (0, pipe_diameter_m={c.pipe_diameter_m!r}) (camera inside the pipe)")
    else:
        _check(c, "offset_m", 0 < c.H_m < c.pipe_diameter_m,
               f"puts the camera outside the pipe (H = {c.H_m:.4f} m, diameter {c.pipe_diameter_m} m)")
    for t, deg in c.tilt_schedule:
        _check(c, "tilt_schedule", abs(deg) <= MAX_TILT_DEG, f"has tilt {deg:g} outside +-{MAX_TILT_DEG:g} deg")
    _range(c, "tilt_deg", -MAX_TILT_DEG, MAX_TILT_DEG)


def _validate_surface(c: SimConfig) -> None:
    _range(c, "mm_per_texel", 0.02, 5.0)
    _range(c, "brightness", 0.0, 255.0)
    _range(c, "contrast", 0.0, 4.0)
    _range(c, "featureless_contrast", 0.0, 1.0)
    _check(c, "texture", c.texture in TEXTURES, f"is not one of {', '.join(TEXTURES)}")
    for i in (0, 1):
        _check(c, "brick_mm", 5.0 <= c.brick_mm[i] <= 2000.0, "must be two sizes in [5, 2000] mm")
    _range(c, "mortar_mm", 0.0, 100.0)
    _range(c, "image_mm_per_px", 0.01, 50.0)
    if c.texture == "image":
        _check(c, "texture_image", c.texture_image is not None,
               "must name a grey image file (or skimage:brick|gravel|grass) when texture='image'")
        path = c.texture_image
        _check(c, "texture_image", path.startswith("skimage:") or os.path.isfile(path), "is not an existing file")
    _range(c, "wet_contrast", 0.0, 1.0)
    _range(c, "wet_albedo", 0.05, 1.5)
    _range(c, "wet_highlight", 0.0, 20.0)
    _range(c, "wet_highlight_deg", 0.1, 45.0)
    if c.wet_highlight_at is not None:
        u, v = c.wet_highlight_at
        _check(c, "wet_highlight_at", 0 <= u <= c.width - 1 and 0 <= v <= c.height - 1,
               f"must be a pixel u,v of the {c.width}x{c.height} sensor")


def _validate_pairs(c: SimConfig) -> None:
    """Intervals start before they end; keyframes are in increasing order."""
    for name in ("featureless", "wet_patches", "dropped_bursts", "led_blackouts"):
        for a, b in getattr(c, name):
            _check(c, name, a < b, f"has an interval ({a:g}, {b:g}) whose start is not before its end")
    for name, what in (("tilt_schedule", "times"), ("height_profile", "positions")):
        keys = [k for k, _ in getattr(c, name)]
        _check(c, name, all(a < b for a, b in zip(keys, keys[1:])),
               f"needs keyframes in strictly increasing {what} (a step is two close keyframes)")
    lift = max((mm for _, mm in c.height_profile), default=0.0) + c.bounce_mm
    drop = -min((mm for _, mm in c.height_profile), default=0.0) + c.bounce_mm
    _check(c, "height_profile", lift < 800.0 * c.H_m and drop < 500 * c.H_m,
           f"moves the camera outside 0.2..1.5 x H = {c.H_m:.4f} m (with bounce_mm={c.bounce_mm:g})")


def _validate_light(c: SimConfig) -> None:
    _range(c, "blackout_ambient", 0.0, 1.0)
    _range(c, "blackout_noise_sigma", 0.0, 100.0)
    _range(c, "blackout_decay_ms", 0.0, 1000.0)


def _validate_motion(c: SimConfig) -> None:
    _check(c, "profile", c.profile in PROFILES, f"is not one of {', '.join(PROFILES)}")
    _range(c, "speed_m_s", 0.0, MAX_SPEED_M_S)
    _range(c, "duration_s", 0.0, 24 * 3600.0, lo_open=True)
    _range(c, "accel_m_s2", 0.0, 100.0, lo_open=True)
    _range(c, "stopgo_period_s", 0.0, 3600.0, lo_open=True)
    _range(c, "stopgo_dwell_s", 0.0, 3600.0)
    _check(c, "stopgo_dwell_s", c.stopgo_dwell_s < c.stopgo_period_s,
           f"must be shorter than stopgo_period_s={c.stopgo_period_s!r}")
    _range(c, "start_m", -1e5, 1e5)


def _validate_disturbances(c: SimConfig) -> None:
    _range(c, "bounce_mm", 0.0, 500.0 * c.H_m)    # at most half of H
    _range(c, "pitch_jitter_deg", 0.0, 10.0)
    _range(c, "roll_deg", 0.0, 90.0)
    _range(c, "sway_mm", 0.0, 250.0 * c.pipe_diameter_m)  # within the middle half of the pipe
    for hz in ("bounce_hz", "pitch_jitter_hz", "roll_hz", "sway_hz", "flicker_hz"):
        _range(c, hz, 0.0, 1000.0)
    _range(c, "noise_sigma", 0.0, 100.0)
    frame_ms = 1000.0 / c.fps
    _range(c, "exposure_ms", 0.0, frame_ms)
    _range(c, "blur_samples", 0, 64)
    _range(c, "readout_ms", 0.0, frame_ms)
    _range(c, "flicker_amp", 0.0, 0.9)
    _range(c, "drop_prob", 0.0, 0.9)


def _validate_run(c: SimConfig) -> None:
    _range(c, "seed", 0, 2**32 - 1)
    _range(c, "crf", 0, 51)
    _check(c, "preset", c.preset in PRESETS, f"is not an x264 preset ({', '.join(PRESETS)})")


def _validate_view(c: SimConfig) -> None:
    """The steepest ray must still meet the wall at a usable angle (after each field's own range)."""
    tilt = max([abs(c.tilt_deg)] + [abs(d) for _, d in c.tilt_schedule])
    view = tilt + c.vfov_deg / 2 + c.pitch_jitter_deg
    _check(c, "tilt_deg", view < MAX_VIEW_DEG,
           f"with vfov_deg={c.vfov_deg:g} puts the frame edge {view:.1f} deg from vertical; "
           f"keep |tilt| + vfov/2 + pitch jitter below {MAX_VIEW_DEG:g}")
