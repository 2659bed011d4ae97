"""SimConfig: every knob of a simulated run, validated once, with a help line per field.

The help, unit and CLI flag of each field live in its metadata, so the CLI, the sidecar JSON and the
parameter table in docs/simulator.md all come from this one place.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field, fields
from typing import Any

from .errors import BadValue, ConfigError, SimError
from .validation import (MAX_SPEED_M_S, MAX_TILT_DEG, MAX_VIEW_DEG, PRESETS, PROFILES, TEXTURES, normalise,
                         validate)


def _f(default: Any, help: str, flag: str, unit: str = "", metavar: str = "") -> Any:
    return field(default=default, metadata={"help": help, "flag": flag, "unit": unit, "metavar": metavar})


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
    tilt_schedule: tuple[tuple[float, float], ...] = _f(
        (), "tilt keyframes t:deg, linear between, held before/after (replaces tilt_deg, which "
        "then is the tilt at t = 0)", "--tilt-schedule", "s:deg", "T:DEG[,T:DEG...]")
    height_profile: tuple[tuple[float, float], ...] = _f(
        (), "extra ride height keyframes y:mm along the pipe (sediment: + lifts the camera toward the "
        "crown), linear between, held before/after", "--height-profile", "m:mm", "Y:MM[,Y:MM...]")
    # --- wall surface ---
    texture: str = _f("concrete", "wall pattern: " + ", ".join(TEXTURES), "--texture")
    brick_mm: tuple[float, float] = _f((215.0, 65.0), "masonry: block length along the pipe, height around it",
                                       "--brick", "mm")
    mortar_mm: float = _f(10.0, "masonry: mortar joint width", "--mortar", "mm")
    texture_image: str | None = _f(
        None, "image: a grey image file tiled over the wall, or skimage:brick|gravel|grass (needs "
        "scikit-image)", "--texture-image")
    image_mm_per_px: float = _f(0.5, "image: wall size of one image pixel", "--image-mm-per-px", "mm")
    mm_per_texel: float = _f(0.2, "axial texture scale (the circumferential one is rounded to wrap)",
                             "--mm-per-texel", "mm")
    brightness: float = _f(128.0, "mean grey level of the wall at the image centre", "--brightness", "DN")
    contrast: float = _f(1.0, "texture contrast multiplier (1: concrete-like, std ~24 DN)", "--contrast")
    featureless: tuple[tuple[float, float], ...] = _f(
        (), "wall stretches a:b (m along the pipe from y=0) where texture contrast drops to ~0",
        "--featureless", "m")
    featureless_contrast: float = _f(0.02, "contrast left inside a featureless stretch",
                                     "--featureless-contrast")
    wet_patches: tuple[tuple[float, float], ...] = _f(
        (), "wet smooth stretches a:b (m along the pipe): faint grain, shading, and the LED's specular "
        "highlight, fixed in the image", "--wet", "m")
    wet_contrast: float = _f(0.06, "texture contrast left on a wet patch", "--wet-contrast")
    wet_albedo: float = _f(0.8, "albedo factor of wet wall (wet concrete is darker)", "--wet-albedo")
    wet_highlight: float = _f(2.0, "peak of the highlight, x the lit wall's mean (above ~1 it saturates)",
                              "--wet-highlight")
    wet_highlight_deg: float = _f(5.0, "angular radius of the highlight (Gaussian sigma)", "--wet-highlight-deg",
                                  "deg")
    wet_highlight_at: tuple[float, float] | None = _f(
        None, "sensor pixel u,v of the highlight's centre (None: the LED's mirror point, where a ray meets "
        "the wall square on)", "--wet-highlight-at", "px")
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
    dropped_bursts: tuple[tuple[float, float], ...] = _f(
        (), "time intervals a:b (s) in which the camera delivers no frame (never the first)", "--drop-bursts", "s")
    led_blackouts: tuple[tuple[float, float], ...] = _f(
        (), "time intervals a:b (s) with the LEDs off: dark, noisy frames", "--blackouts", "s")
    blackout_ambient: float = _f(0.02, "light left with the LEDs off, x theirs", "--blackout-ambient")
    blackout_noise_sigma: float = _f(2.0, "extra sensor noise in the dark (adds to noise_sigma in quadrature)",
                                     "--blackout-noise", "DN")
    blackout_decay_ms: float = _f(0.3, "LED light decay time constant after switching off", "--blackout-decay-ms",
                                  "ms")
    # --- run ---
    seed: int = _f(0, "texture, jitter, noise and drop seed", "--seed")
    crf: int = _f(18, "libx264 constant quality (0 lossless .. 51)", "--crf")
    preset: str = _f("veryfast", "libx264 preset", "--preset")

    def __post_init__(self) -> None:
        normalise(self)
        validate(self)

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


__all__ = ["BadValue", "ConfigError", "MAX_SPEED_M_S", "MAX_TILT_DEG", "MAX_VIEW_DEG", "PRESETS", "PROFILES",
           "SimConfig", "SimError", "TEXTURES", "field_docs"]
