"""SimConfig: every knob of a simulated run, validated once, with a help line per field.

The help, unit and CLI flag of each field live in its metadata, so the CLI, the sidecar JSON and the
parameter table in docs/simulator.md all come from this one place.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field, fields
from typing import Any

PROFILES = ("constant", "accel", "stopgo", "reverse")
PRESETS = ("ultrafast", "superfast", "veryfast", "faster", "fast", "medium", "slow", "slower",
           "veryslow")
MAX_SPEED_M_S = 2.0       # the studied range is 0..1 m/s; a little headroom for stress runs
MAX_TILT_DEG = 60.0
MAX_VIEW_DEG = 85.0       # |tilt| + vfov/2 + jitter beyond this looks along the pipe, not at the wall


class SimError(Exception):
    """Root of every error hw_sim raises on purpose."""


class BadValue(SimError, ValueError):
    """A value given to hw_sim is unusable (the CLI exits 2)."""


class ConfigError(BadValue):
    """A SimConfig value is out of range; `.field` names the field."""

    def __init__(self, name: str, value: Any, why: str):
        self.field = name
        self.value = value
        super().__init__(f"{name}={value!r} {why}")


def _f(default: Any, help: str, flag: str, unit: str = "") -> Any:
    return field(default=default, metadata={"help": help, "flag": flag, "unit": unit})


@dataclass(frozen=True)
class SimConfig:
    """A simulated crawler run. Defaults: the thesis camera and car in a 0.30 m pipe."""

    # --- camera (the full sensor) ---
    width: int = _f(960, "sensor width (the FOV spans it)", "--width", "px")
    height: int = _f(720, "sensor height (the FOV spans it)", "--height", "px")
    vfov_deg: float = _f(37.16, "vertical field of view of the full sensor", "--vfov", "deg")
    hfov_deg: float = _f(53.50, "horizontal field of view of the full sensor", "--hfov", "deg")
    fps: float = _f(30.0, "frame rate", "--fps", "Hz")
    window: tuple[int, int, int, int] | None = _f(
        None, "sensor crop x0,y0,w,h read out (None: the full sensor)", "--window", "px")
    output_size: tuple[int, int] | None = _f(
        None, "output frame W,H the window is scaled to (None: the window's size); even", "--output-size", "px")
    distortion: tuple[float, float, float, float, float] | None = _f(
        None, "OpenCV radial/tangential k1,k2,p1,p2,k3 of the sensor (None: a pinhole)", "--distortion")
    # --- pipe and car ---
    pipe_diameter_m: float = _f(0.30, "pipe inner diameter", "--diameter", "m")
    car_width_m: float = _f(0.151, "wheel track: wheels touch the wall at x = +-w/2", "--car-width", "m")
    offset_m: float = _f(0.054, "camera height above the wheel contact line", "--offset", "m")
    camera_height_m: float | None = _f(
        None, "camera-to-crown distance H; None: Eq. 3.4 from diameter, car width, offset",
        "--camera-height", "m")
    tilt_deg: float = _f(0.0, "camera pitch toward travel (0: looks straight up)", "--tilt", "deg")
    # --- wall surface ---
    mm_per_texel: float = _f(0.2, "axial texture scale (the circumferential one is rounded to wrap)",
                             "--mm-per-texel", "mm")
    brightness: float = _f(128.0, "mean grey level of the wall at the image centre", "--brightness", "DN")
    contrast: float = _f(1.0, "texture contrast multiplier (1: concrete-like, std ~24 DN)", "--contrast")
    featureless: tuple[tuple[float, float], ...] = _f(
        (), "wall stretches a:b (m along the pipe from y=0) where texture contrast drops to ~0",
        "--featureless", "m")
    featureless_contrast: float = _f(0.02, "contrast left inside a featureless stretch",
                                     "--featureless-contrast")
    # --- motion ---
    profile: str = _f("constant", "distance-vs-time profile: " + ", ".join(PROFILES), "--profile")
    speed_m_s: float = _f(0.2, "cruise speed (reverse: both ways)", "--speed", "m/s")
    duration_s: float = _f(5.0, "run length; frames at k/fps for 0 <= k/fps <= duration", "--duration", "s")
    accel_m_s2: float = _f(0.5, "acceleration and braking of accel/stopgo/reverse", "--accel", "m/s^2")
    stopgo_period_s: float = _f(2.0, "stopgo: one go-and-stop cycle", "--stopgo-period", "s")
    stopgo_dwell_s: float = _f(0.5, "stopgo: standstill at the end of each cycle", "--stopgo-dwell", "s")
    start_m: float = _f(0.0, "camera's axial position y at t = 0", "--start", "m")
    # --- disturbances (all off by default) ---
    bounce_mm: float = _f(0.0, "suspension bounce: H + A sin(2 pi f t)", "--bounce", "mm")
    bounce_hz: float = _f(4.0, "suspension bounce frequency", "--bounce-hz", "Hz")
    pitch_jitter_deg: float = _f(0.0, "pitch jitter peak (smooth, quasi-random)", "--pitch-jitter", "deg")
    pitch_jitter_hz: float = _f(3.0, "pitch jitter main frequency", "--pitch-jitter-hz", "Hz")
    roll_deg: float = _f(0.0, "roll about the pipe axis A sin(2 pi f t) (+: image content moves right)",
                         "--roll", "deg")
    roll_hz: float = _f(0.2, "roll oscillation frequency", "--roll-hz", "Hz")
    sway_mm: float = _f(0.0, "lateral camera offset A sin(2 pi f t + 1 rad) (+: car's right)", "--sway", "mm")
    sway_hz: float = _f(0.5, "lateral sway frequency", "--sway-hz", "Hz")
    lighting: bool = _f(False, "LED at the camera: 1/range^2 * cos(incidence), 1 at the principal ray",
                        "--lighting")
    vignetting: bool = _f(False, "lens vignetting cos^4 of the field angle", "--vignetting")
    noise_sigma: float = _f(0.0, "Gaussian sensor noise", "--noise", "DN")
    exposure_ms: float = _f(0.0, "exposure time; > 0 blurs the frame over it (motion blur)",
                            "--exposure-ms", "ms")
    blur_samples: int = _f(0, "sub-frames averaged for camera wobble during the exposure "
                           "(0: ~1 per px of wobble, max 16; travel is blurred exactly)", "--blur-samples")
    readout_ms: float = _f(0.0, "rolling shutter: top-to-bottom row readout time (0: global)",
                           "--readout-ms", "ms")
    flicker_amp: float = _f(0.0, "brightness flicker: gain 1 + A sin(2 pi f t)", "--flicker")
    flicker_hz: float = _f(2.0, "brightness flicker frequency", "--flicker-hz", "Hz")
    drop_prob: float = _f(0.0, "probability that a frame is dropped (never the first)", "--drop")
    # --- run ---
    seed: int = _f(0, "texture, jitter, noise and drop seed", "--seed")
    crf: int = _f(18, "libx264 constant quality (0 lossless .. 51)", "--crf")
    preset: str = _f("veryfast", "libx264 preset", "--preset")

    def __post_init__(self) -> None:
        _normalise(self)
        _validate(self)

    # --- derived values used by the renderer, the sidecar and the CLI ---
    @property
    def radius_m(self) -> float:
        return self.pipe_diameter_m / 2.0

    @property
    def H_m(self) -> float:
        """Camera-to-crown distance: given, or thesis Eq. 3.4."""
        if self.camera_height_m is not None:
            return float(self.camera_height_m)
        r, w = self.radius_m, self.car_width_m
        return r + math.sqrt(4 * r * r - w * w) / 2 - self.offset_m

    @property
    def window_px(self) -> tuple[int, int, int, int]:
        return self.window if self.window is not None else (0, 0, self.width, self.height)

    @property
    def out_size(self) -> tuple[int, int]:
        if self.output_size is not None:
            return self.output_size
        return self.window_px[2], self.window_px[3]

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "SimConfig":
        """Inverse of to_dict (tolerates JSON lists for tuples); unknown keys are an error."""
        known = {f.name for f in fields(cls)}
        extra = sorted(set(d) - known)
        if extra:
            raise ConfigError(extra[0], d[extra[0]], "is not a SimConfig field")
        return cls(**d)


def field_docs() -> list[dict[str, Any]]:
    """(name, flag, default, unit, help) of every field, for the CLI and the docs table."""
    return [dict(name=f.name, default=f.default, type=f.type, **f.metadata) for f in fields(SimConfig)]


# ---------------------------------------------------------------------------------------------------

def _set(cfg: SimConfig, name: str, value: Any) -> None:
    object.__setattr__(cfg, name, value)


def _normalise(c: SimConfig) -> None:
    """Coerce JSON-ish values (lists, ints for floats) to the declared types, naming what fails."""
    for name, n, typ in (("window", 4, int), ("output_size", 2, int), ("distortion", 5, float)):
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
    try:
        fl = tuple((float(a), float(b)) for a, b in c.featureless)
    except (TypeError, ValueError):
        raise ConfigError("featureless", c.featureless, "must be a sequence of (start_m, end_m) pairs") from None
    _set(c, "featureless", fl)
    for f in fields(SimConfig):
        v = getattr(c, f.name)
        if f.type in ("float", "float | None") and v is not None:
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise ConfigError(f.name, v, "must be a finite number")
            _set(c, f.name, float(v))
        elif f.type == "int":
            if isinstance(v, bool) or not isinstance(v, (int, float)) or float(v) != int(v):
                raise ConfigError(f.name, v, "must be an integer")
            _set(c, f.name, int(v))
        elif f.type == "bool" and not isinstance(v, bool):
            raise ConfigError(f.name, v, "must be true or false")
        elif f.type == "str" and not isinstance(v, str):
            raise ConfigError(f.name, v, "must be a string")


def _check(c: SimConfig, name: str, ok: bool, why: str) -> None:
    if not ok:
        raise ConfigError(name, getattr(c, name), why)


def _range(c: SimConfig, name: str, lo: float, hi: float, lo_open: bool = False) -> None:
    v = getattr(c, name)
    ok = (lo < v if lo_open else lo <= v) and v <= hi
    _check(c, name, ok, f"is outside {'(' if lo_open else '['}{lo:g}, {hi:g}]")


def _validate(c: SimConfig) -> None:
    for group in (_validate_camera, _validate_mount, _validate_surface, _validate_motion,
                  _validate_disturbances, _validate_run, _validate_view):
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
    _range(c, "tilt_deg", -MAX_TILT_DEG, MAX_TILT_DEG)


def _validate_surface(c: SimConfig) -> None:
    _range(c, "mm_per_texel", 0.02, 5.0)
    _range(c, "brightness", 0.0, 255.0)
    _range(c, "contrast", 0.0, 4.0)
    for a, b in c.featureless:
        _check(c, "featureless", a < b, f"has an interval ({a}, {b}) whose start is not before its end")
    _range(c, "featureless_contrast", 0.0, 1.0)


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
    view = abs(c.tilt_deg) + c.vfov_deg / 2 + c.pitch_jitter_deg
    _check(c, "tilt_deg", view < MAX_VIEW_DEG,
           f"with vfov_deg={c.vfov_deg:g} puts the frame edge {view:.1f} deg from vertical; "
           f"keep |tilt| + vfov/2 + pitch jitter below {MAX_VIEW_DEG:g}")
