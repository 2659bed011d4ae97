"""Typed settings: one frozen dataclass per TOML section, loaded once, validated in exactly one place.

Every key a user may write is a field below, with its type, default and check; unknown keys are
errors (a typo must not silently fall back to a default on a robot 80 m down a pipe), and a key
that was renamed is refused with its new name. Command-line flags set fields directly
(`Settings.with_values`); `--set section.key=value` parses the value as TOML first.
"""

from __future__ import annotations

import tomllib
from dataclasses import asdict, dataclass, field, fields, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from .errors import BadConfig
from .fields import (_check_field, _check_fields, _coerce, _distortion, _f, _lgpio_frequency, _name,
                     _odd_window, _output_size, _pins, _roi, _tilt, _window, between, one_of, positive)
from .geometry import METHODS, Mount

if TYPE_CHECKING:
    from .wheel.settings import WheelSettings

# (section, key) of a key that no longer exists -> what to write instead
RENAMED = {
    ("camera", "line_time_us"): "[camera] readout_ms (the readout of the frames the odometry sees, top "
                                "row to bottom row, in ms; on the live camera it is computed from the "
                                "sensor mode unless you set it)",
}


# -- the sections -------------------------------------------------------------------------------------

@dataclass(frozen=True)
class CameraSettings:
    """The frames' camera: the recording's geometry, and how the live CSI camera is driven."""

    width: int = _f(960, between(16, 8192))
    height: int = _f(720, between(16, 8192))
    vfov_deg: float = _f(37.16, between(0, 170, lo_open=True, hi_open=True))
    hfov_deg: float = _f(53.50, between(0, 170, lo_open=True, hi_open=True))
    calibration: str | None = _f(None)
    distortion: tuple[float, ...] | None = _f(None, _distortion)
    readout_ms: float | None = _f(None, between(0, 1000, hi_open=True))
    hflip: bool = _f(False)
    vflip: bool = _f(False)
    # live camera (crawlerd without --replay): see docs/deploy.md
    camera_num: int = _f(0, between(0, 16))
    sensor_window: tuple[int, ...] | None = _f(None, _window)
    output_size: tuple[int, ...] = _f((240, 240), _output_size)
    fps: float = _f(60.0, between(0, 1000, lo_open=True))
    exposure_us: int = _f(1500, between(1, 1_000_000))
    analogue_gain: float = _f(4.0, between(1, 64))
    sensor_hfov_deg: float | None = _f(None, between(0, 170, lo_open=True, hi_open=True))
    sensor_vfov_deg: float | None = _f(None, between(0, 170, lo_open=True, hi_open=True))
    capture_timeout_s: float = _f(2.0, between(0.05, 60))
    fallback_video: str | None = _f(None)
    fallback_pts: str | None = _f(None)
    fallback_fps: float | None = _f(None, between(0.1, 1000))

    def __post_init__(self):
        _check_fields(self, "camera")
        if self.exposure_us > 1e6 / self.fps:
            raise BadConfig(f"[camera] exposure_us = {self.exposure_us} is longer than a frame at "
                            f"fps = {self.fps:g}; shorten it (motion blur) or lower fps")
        if (self.sensor_hfov_deg is None) != (self.sensor_vfov_deg is None):
            raise BadConfig("[camera] sensor_hfov_deg and sensor_vfov_deg go together; set both or neither")

    @property
    def readout_s(self) -> float | None:
        return None if self.readout_ms is None else self.readout_ms / 1000.0


@dataclass(frozen=True)
class MountSettings:
    """Where the camera sits in the pipe (thesis Eq. 3.4, or the height directly)."""

    pipe_diameter_m: float = _f(0.30)
    car_width_m: float = _f(0.151)
    camera_offset_m: float = _f(0.054)
    height_m: float | None = _f(None)
    tilt_deg: float | str = _f(0.0, _tilt)    # "auto": estimated online (crawler/autotilt.py), from 0

    def __post_init__(self):
        _check_fields(self, "mount")
        self.mount()   # impossible geometry (car wider than the pipe, camera outside it) is refused here

    @property
    def tilt_auto(self) -> bool:
        return self.tilt_deg == "auto"

    def mount(self) -> Mount:
        """The mount to measure with; with tilt "auto", the start of the estimate (0 degrees)."""
        tilt = 0.0 if self.tilt_auto else self.tilt_deg
        if self.height_m is not None:
            return Mount.from_height(self.pipe_diameter_m, self.height_m, tilt)
        return Mount.from_car(self.pipe_diameter_m, self.car_width_m, self.camera_offset_m, tilt)


@dataclass(frozen=True)
class OdometrySettings:
    method: str = _f("cylinder", one_of(*METHODS))
    roi: tuple[int, ...] | None = _f(None, _roi)
    max_features: int = _f(30, between(8, 2000))
    win_px: int = _f(9, _odd_window)
    levels: int = _f(1, between(0, 6))
    max_roundtrip_px: float = _f(0.5, positive)
    min_tracks: int = _f(8, between(3, 2000))
    max_baseline_px: float = _f(120.0, positive)
    speed_window_s: float = _f(0.25, positive)
    max_incidence_deg: float = _f(70.0, between(0, 90, lo_open=True, hi_open=True))
    pitch_jitter_deg: float = _f(0.25, between(0, 10))    # the car's pitching: part of sigma_m; the pose prior
    bounce_mm: float = _f(1.0, between(0, 50))            # the suspension's bounce: the pose prior
    sway_mm: float = _f(2.0, between(0, 50))              # the car's weave across the pipe: the pose prior
    estimate_pose: bool | None = _f(None)   # per-frame pitch, height, sway (crawler/pose.py); unset: with a
                                            # configured tilt, not with tilt "auto" (docs/odometry.md, "Pose")
    ride_height: bool | None = _f(None)     # the ride height's level over sediment (crawler/ride.py); unset: with
                                            # a configured tilt up to ride.MAX_TILT_DEG (docs/odometry.md, "Ride height")
    workers: int = _f(1, between(1, 16))    # processes that share a frame's work (crawler/workers.py)

    def __post_init__(self):
        _check_fields(self, "odometry")
        if self.min_tracks >= self.max_features:
            raise BadConfig(f"[odometry] min_tracks = {self.min_tracks} must be >= 3 and below "
                            f"max_features = {self.max_features}")


@dataclass(frozen=True)
class LedSettings:
    pins: tuple[int, ...] = _f((), _pins)
    brightness: float = _f(0.8, between(0, 1))
    frequency_hz: float = _f(2000.0, _lgpio_frequency)    # 1500 us exposure = 3 whole PWM periods
    active_high: bool = _f(True)
    auto_brightness: bool = _f(False)
    target_grey: float = _f(110.0, between(0, 255))

    def __post_init__(self):
        _check_fields(self, "leds")


@dataclass(frozen=True)
class ZenohSettings:
    mode: str | None = _f(None, one_of("peer", "client", "router"))
    listen: tuple[str, ...] = _f(())
    connect: tuple[str, ...] = _f(())
    config: str | None = _f(None)
    multicast: bool = _f(True)
    publish_hz: float = _f(30.0, between(0, 1000, lo_open=True))
    status_hz: float = _f(1.0, between(0, 1000, lo_open=True))

    def __post_init__(self):
        _check_fields(self, "zenoh")
        self.zenoh_config()     # zenoh parses the endpoints and the config file: errors now, not mid-run

    def zenoh_config(self):
        from .zenoh_config import make_zenoh_config

        return make_zenoh_config(self.mode, self.listen, self.connect, self.config, self.multicast)


@dataclass(frozen=True)
class StateSettings:
    directory: str = _f("/var/lib/crawlerd")
    checkpoint_s: float = _f(0.1, positive)           # 10 Hz: a kill -9 loses at most this much motion

    def __post_init__(self):
        _check_fields(self, "state")


@dataclass(frozen=True)
class InspectionSettings:
    """What the inspection overlay and report say of the pipe, and the footage counter's start."""

    pipe_id: str = _f("")                       # e.g. "MH12-MH13", burned into the annotated video
    unit: str = _f("m", one_of("m", "ft"))      # of a new run; the operator can change it (cmd/units)
    direction: str = _f("downstream", one_of("downstream", "upstream"))

    def __post_init__(self):
        _check_fields(self, "inspection")
        if len(self.pipe_id) > 40 or any(ord(ch) < 32 for ch in self.pipe_id):
            raise BadConfig(f"[inspection] pipe_id = {self.pipe_id!r} must be at most 40 characters of text")


@dataclass(frozen=True)
class Ros2Settings:
    """Publish nav_msgs/msg/Odometry the way rmw_zenoh does, for ROS 2 machines on the network."""

    enabled: bool = _f(False)
    domain_id: int = _f(0, between(0, 232))     # ROS_DOMAIN_ID
    topic: str = _f("")                         # default /<name>/odom
    distro: str = _f("jazzy", one_of("jazzy", "humble"))

    def __post_init__(self):
        _check_fields(self, "ros2")
        if self.topic:
            from .ros2 import fully_qualified

            fully_qualified(self.topic, "/crawler")        # ROS 2's own name rules, in one place


SECTIONS = {"camera": CameraSettings, "mount": MountSettings, "odometry": OdometrySettings,
            "leds": LedSettings, "zenoh": ZenohSettings, "state": StateSettings,
            "inspection": InspectionSettings, "ros2": Ros2Settings}


@dataclass(frozen=True)
class Settings:
    """The whole configuration: `name` and one object per section."""

    name: str = _f("crawler1", _name)
    camera: CameraSettings = field(default_factory=CameraSettings)
    mount: MountSettings = field(default_factory=MountSettings)
    odometry: OdometrySettings = field(default_factory=OdometrySettings)
    leds: LedSettings = field(default_factory=LedSettings)
    zenoh: ZenohSettings = field(default_factory=ZenohSettings)
    state: StateSettings = field(default_factory=StateSettings)
    inspection: InspectionSettings = field(default_factory=InspectionSettings)
    ros2: Ros2Settings = field(default_factory=Ros2Settings)
    wheel: WheelSettings = field(default_factory=lambda: _wheel_settings({}, "crawler1"))

    def __post_init__(self):
        _check_field(self, "", "name", self.name, "str")

    @classmethod
    def from_dict(cls, data: dict, origin: str = "the configuration") -> "Settings":
        """A parsed TOML mapping -> Settings; unknown or renamed keys and wrong types are refused."""
        top = {}
        sections = {}
        name = data.get("name", "crawler1") if isinstance(data.get("name"), str) else "crawler1"
        for key, value in data.items():
            if key == "wheel":
                sections["wheel"] = _wheel_settings(value, name)
            elif key in SECTIONS and isinstance(value, dict):
                sections[key] = SECTIONS[key](**_section_values(SECTIONS[key], key, value, origin))
            elif key == "name":
                top["name"] = _coerce("", key, value, "str")
            else:
                raise BadConfig(f"{origin}: unknown key or section {key!r}; known sections: "
                                f"{', '.join('[' + s + ']' for s in SECTIONS)}")
        return cls(**top, **sections)

    def with_values(self, values: dict[str, Any], origin: str = "the command line") -> "Settings":
        """These settings with `{"section.key": value}` replaced (a key without a section is top-level).

        The keys of one section are applied together, so checks across keys see them all.
        """
        out = self
        grouped: dict[str, dict] = {}
        for dotted, value in values.items():
            section, _, key = dotted.rpartition(".")
            if not section:
                if key != "name":
                    raise BadConfig(f"{origin}: unknown key {key!r}; keys outside a section: name")
                out = replace(out, name=_coerce("", key, value, "str"))
            elif section not in SECTIONS and section != "wheel":
                raise BadConfig(f"{origin}: unknown section [{section}]; known sections: "
                                f"{', '.join('[' + s + ']' for s in SECTIONS)}, [wheel]")
            else:
                grouped.setdefault(section, {})[key] = value
        for section, new in grouped.items():
            if section == "wheel":
                current = {k: v for k, v in asdict(out.wheel).items() if v is not None}
                out = replace(out, wheel=_wheel_settings(dict(current, **new), out.name))
            else:
                new = _section_values(SECTIONS[section], section, new, origin)
                out = replace(out, **{section: replace(getattr(out, section), **new)})
        return out


def _wheel_settings(data, name: str):
    """[wheel]: its own frozen dataclass, validated by its own from_dict (crawler/wheel/settings.py)."""
    from .wheel.settings import WheelSettings

    return WheelSettings.from_dict(data, name=name)


def load(path: str | Path | None = None, sets: list[str] = (), values: dict[str, Any] | None = None) -> Settings:
    """Defaults, then the TOML file, then `--set section.key=value` items, then typed flag values."""
    settings = Settings()
    if path is not None:
        settings = Settings.from_dict(_read_toml(Path(path)), str(path))
    if sets:
        merged = {}
        for item in sets:
            merged.update(parse_set(item))
        settings = settings.with_values(merged, "--set")
    if values:
        settings = settings.with_values(values)
    return settings


def parse_set(item: str) -> dict[str, Any]:
    """'mount.tilt_deg=24' -> {'mount.tilt_deg': 24}; the value is read as TOML, bare words as text."""
    key, sep, value = item.partition("=")
    if not sep or not key.strip():
        raise BadConfig(f"--set {item!r} must look like section.key=value, e.g. mount.tilt_deg=24")
    try:
        parsed = tomllib.loads(f"v = {value.strip()}")["v"]
    except tomllib.TOMLDecodeError:
        parsed = value.strip()   # bare words are strings: method=plane
    return {key.strip(): parsed}


def _read_toml(path: Path) -> dict:
    try:
        text = path.read_text()
    except FileNotFoundError:
        raise BadConfig(f"config file {str(path)!r} not found; pass --config PATH") from None
    except IsADirectoryError:
        raise BadConfig(f"config file {str(path)!r} is a folder; pass the .toml file") from None
    except OSError as exc:
        raise BadConfig(f"config file {str(path)!r} cannot be read: {exc.strerror}") from None
    except UnicodeDecodeError:
        raise BadConfig(f"config file {str(path)!r} is not UTF-8 text (a TOML file is)") from None
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise BadConfig(f"config file {str(path)!r} is not valid TOML: {exc}") from None


def _section_values(cls, section: str, data: dict, origin: str) -> dict:
    known = {f.name: f for f in fields(cls)}
    out = {}
    for key, value in data.items():
        if (section, key) in RENAMED:
            raise BadConfig(f"{origin}: [{section}] {key} was renamed; use {RENAMED[section, key]}")
        if key not in known:
            raise BadConfig(f"{origin}: unknown key [{section}] {key}; known keys: {', '.join(known)}")
        out[key] = _coerce(section, key, value, known[key].type)
    return out
