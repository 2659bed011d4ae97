"""The TOML configuration: defaults, validation with messages that name the key, and derived geometry.

Every key a user may write is declared in SCHEMA below, with its type and default; unknown keys are
errors (a typo must not silently fall back to a default on a robot 80 m down a pipe).
"""

from __future__ import annotations

import copy
import math
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from .errors import BadConfig
from .flow import FlowParams
from .geometry import METHODS, Camera, Mount, check_distortion, check_view, make_projection
from .odometry import OdometryParams

_NUM = (int, float)

# section -> key -> (types, default). None default = optional / derived.
SCHEMA: dict[str, dict[str, tuple[Any, Any]]] = {
    "": {"name": (str, "crawler1")},
    "camera": {
        "width": (int, 960), "height": (int, 720),
        "vfov_deg": (_NUM, 37.16), "hfov_deg": (_NUM, 53.50),
        "calibration": (str, None), "distortion": (list, None),
        "readout_ms": (_NUM, 0.0), "hflip": (bool, False), "vflip": (bool, False),
        # live camera (crawlerd without --replay): see docs/deploy.md
        "camera_num": (int, 0), "sensor_window": (list, None), "output_size": (list, [240, 240]),
        "fps": (_NUM, 60.0), "exposure_us": (int, 1500), "analogue_gain": (_NUM, 4.0),
        "sensor_hfov_deg": (_NUM, None), "sensor_vfov_deg": (_NUM, None), "line_time_us": (_NUM, None),
        "capture_timeout_s": (_NUM, 2.0),
        "fallback_video": (str, None), "fallback_pts": (str, None), "fallback_fps": (_NUM, None),
    },
    "mount": {
        "pipe_diameter_m": (_NUM, 0.30), "car_width_m": (_NUM, 0.151),
        "camera_offset_m": (_NUM, 0.054), "height_m": (_NUM, None), "tilt_deg": (_NUM, 0.0),
    },
    "odometry": {
        "method": (str, "cylinder"), "roi": (list, None),
        "max_features": (int, 30), "win_px": (int, 9), "levels": (int, 1),
        "max_roundtrip_px": (_NUM, 0.5), "min_tracks": (int, 8),
        "max_baseline_px": (_NUM, 120.0), "speed_window_s": (_NUM, 0.25),
        "max_incidence_deg": (_NUM, 70.0),
    },
    "leds": {
        "pins": (list, []), "brightness": (_NUM, 0.8), "frequency_hz": (_NUM, 1000.0),
        "active_high": (bool, True), "auto_brightness": (bool, False), "target_grey": (_NUM, 110.0),
    },
    "zenoh": {
        "mode": (str, None), "listen": (list, []), "connect": (list, []), "config": (str, None),
        "multicast": (bool, True), "publish_hz": (_NUM, 30.0), "status_hz": (_NUM, 1.0),
    },
    "state": {"directory": (str, "/var/lib/crawlerd"), "checkpoint_s": (_NUM, 1.0)},
}


def _endpoint_ok(endpoint: str) -> bool:
    """protocol/address[:port][#config]; IP endpoints need a port in range."""
    proto, sep, rest = endpoint.partition("/")
    if not sep or not proto.isalnum() and proto not in ("unixsock-stream", "unixpipe") or not rest:
        return False
    if proto in ("tcp", "udp", "tls", "quic", "ws"):
        host, colon, port = rest.split("#")[0].rpartition(":")
        if not colon or not host or not port.isdigit() or not 0 < int(port) < 65536:
            return False
        parts = host.split(".")
        if len(parts) == 4 and all(p.isdigit() for p in parts):
            return all(int(p) < 256 for p in parts)
    return True


def _type_name(types) -> str:
    if types is _NUM:
        return "a number"
    return {int: "an integer", str: "a string", list: "a list", bool: "true or false"}.get(types, str(types))


def defaults() -> dict:
    return {sec: {k: d for k, (_, d) in keys.items()} for sec, keys in SCHEMA.items()}


def _check_type(where: str, value, types):
    ok = isinstance(value, types) and not (isinstance(value, bool) and types in (_NUM, int))
    if not ok:
        raise BadConfig(f"{where} = {value!r} must be {_type_name(types)}")


def merge(base: dict, data: dict, origin: str) -> dict:
    """Overlay a parsed TOML mapping on base, refusing unknown sections, keys and wrong types."""
    out = copy.deepcopy(base)
    for key, value in data.items():
        if key in SCHEMA and key and isinstance(value, dict):
            for k, v in value.items():
                if k not in SCHEMA[key]:
                    raise BadConfig(f"{origin}: unknown key [{key}] {k}; known keys: "
                                    f"{', '.join(SCHEMA[key])}")
                _check_type(f"[{key}] {k}", v, SCHEMA[key][k][0])
                out[key][k] = v
        elif key in SCHEMA[""]:
            _check_type(key, value, SCHEMA[""][key][0])
            out[""][key] = value
        else:
            raise BadConfig(f"{origin}: unknown key or section {key!r}; known sections: "
                            f"{', '.join('[' + s + ']' for s in SCHEMA if s)}")
    return out


def load(path: str | Path | None = None, overrides: list[str] = ()) -> "Config":
    """Defaults, then the TOML file, then `section.key=value` overrides (TOML values)."""
    raw = defaults()
    if path is not None:
        path = Path(path)
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
            data = tomllib.loads(text)
        except tomllib.TOMLDecodeError as exc:
            raise BadConfig(f"config file {str(path)!r} is not valid TOML: {exc}") from None
        raw = merge(raw, data, str(path))
    for item in overrides:
        raw = merge(raw, parse_override(item), f"--set {item}")
    return Config(raw)


def parse_override(item: str) -> dict:
    """'mount.tilt_deg=24' -> {'mount': {'tilt_deg': 24}}; the value is read as TOML."""
    key, sep, value = item.partition("=")
    if not sep or not key.strip():
        raise BadConfig(f"--set {item!r} must look like section.key=value, e.g. mount.tilt_deg=24")
    try:
        parsed = tomllib.loads(f"v = {value.strip()}")["v"]
    except tomllib.TOMLDecodeError:
        parsed = value.strip()   # bare words are strings: method=plane
    section, _, k = key.strip().rpartition(".")
    return {section: {k: parsed}} if section else {k: parsed}


@dataclass
class Geometry:
    """Everything derived from the config that the odometry needs, validated together."""

    camera: Camera
    mount: Mount
    projection: Any
    roi: tuple[int, int, int, int]
    worst_incidence_deg: float
    m_per_px_eq31: float   # thesis Eq. 3.1 at the crown, tilt ignored


class Config:
    """Validated configuration. Sections are plain dicts: cfg.camera['width']."""

    def __init__(self, raw: dict):
        self.raw = raw
        self.name = raw[""]["name"]
        self.camera = raw["camera"]
        self.mount = raw["mount"]
        self.odometry = raw["odometry"]
        self.leds = raw["leds"]
        self.zenoh = raw["zenoh"]
        self.state = raw["state"]
        self._validate()

    def _validate(self):
        c, m, o = self.camera, self.mount, self.odometry
        if not self.name or not all(ch.isalnum() or ch in "-_" for ch in self.name):
            raise BadConfig(f"name = {self.name!r} must be letters, digits, '-' or '_' "
                            "(it becomes a Zenoh key segment)")
        for k in ("width", "height"):
            if not 16 <= c[k] <= 8192:
                raise BadConfig(f"[camera] {k} = {c[k]} must be between 16 and 8192 pixels")
        if c["distortion"] is not None and (
                len(c["distortion"]) not in (4, 5, 8) or not all(isinstance(v, _NUM) for v in c["distortion"])):
            raise BadConfig(f"[camera] distortion = {c['distortion']!r} must be 4, 5 or 8 numbers "
                            "in OpenCV order [k1, k2, p1, p2, k3]")
        if not 0 <= c["readout_ms"] < 1000:
            raise BadConfig(f"[camera] readout_ms = {c['readout_ms']} must be between 0 and 1000")
        for k in ("pipe_diameter_m", "car_width_m", "camera_offset_m"):
            if m[k] is not None and not math.isfinite(m[k]):
                raise BadConfig(f"[mount] {k} = {m[k]} must be a finite number")
        if not -80 <= m["tilt_deg"] <= 80:
            raise BadConfig(f"[mount] tilt_deg = {m['tilt_deg']} must be between -80 and 80 degrees")
        if o["method"] not in METHODS:
            raise BadConfig(f"[odometry] method = {o['method']!r} must be one of {', '.join(METHODS)}")
        if o["win_px"] < 5 or o["win_px"] % 2 == 0:
            raise BadConfig(f"[odometry] win_px = {o['win_px']} must be an odd number >= 5")
        if not 0 <= o["levels"] <= 6:
            raise BadConfig(f"[odometry] levels = {o['levels']} must be between 0 and 6")
        if not 8 <= o["max_features"] <= 2000:
            raise BadConfig(f"[odometry] max_features = {o['max_features']} must be between 8 and 2000")
        if not 3 <= o["min_tracks"] < o["max_features"]:
            raise BadConfig(f"[odometry] min_tracks = {o['min_tracks']} must be >= 3 and below "
                            f"max_features = {o['max_features']}")
        for k in ("max_roundtrip_px", "max_baseline_px", "speed_window_s"):
            if not o[k] > 0:
                raise BadConfig(f"[odometry] {k} = {o[k]} must be > 0")
        if not 0 < o["max_incidence_deg"] < 90:
            raise BadConfig(f"[odometry] max_incidence_deg = {o['max_incidence_deg']} must be between 0 and 90")
        self._validate_live()
        self.geometry()   # impossible geometry is refused at load time

    def _validate_live(self):
        c, l, z, st = self.camera, self.leds, self.zenoh, self.state
        size = c["output_size"]
        if len(size) != 2 or not all(isinstance(v, int) and 32 <= v <= 2048 and v % 2 == 0 for v in size):
            raise BadConfig(f"[camera] output_size = {size!r} must be [width, height], even, 32..2048")
        win = c["sensor_window"]
        if win is not None and (len(win) != 4 or not all(isinstance(v, int) and v >= 0 for v in win)):
            raise BadConfig(f"[camera] sensor_window = {win!r} must be [x, y, w, h] in native pixels "
                            "of the sensor's active area")
        if not 0 < c["fps"] <= 1000:
            raise BadConfig(f"[camera] fps = {c['fps']} must be between 0 and 1000")
        if not 1 <= c["exposure_us"] <= 1_000_000:
            raise BadConfig(f"[camera] exposure_us = {c['exposure_us']} must be between 1 and 1000000")
        if c["exposure_us"] > 1e6 / c["fps"]:
            raise BadConfig(f"[camera] exposure_us = {c['exposure_us']} is longer than a frame at "
                            f"fps = {c['fps']:g}; shorten it (motion blur) or lower fps")
        if not 1.0 <= c["analogue_gain"] <= 64.0:
            raise BadConfig(f"[camera] analogue_gain = {c['analogue_gain']} must be between 1 and 64")
        if (c["sensor_hfov_deg"] is None) != (c["sensor_vfov_deg"] is None):
            raise BadConfig("[camera] sensor_hfov_deg and sensor_vfov_deg go together; set both or neither")
        if not all(isinstance(p, int) and 0 <= p <= 27 for p in l["pins"]):
            raise BadConfig(f"[leds] pins = {l['pins']!r} must be BCM GPIO numbers 0..27, e.g. [12, 13]")
        if not 0 <= l["brightness"] <= 1:
            raise BadConfig(f"[leds] brightness = {l['brightness']} must be between 0 and 1")
        if not 0 <= l["target_grey"] <= 255:
            raise BadConfig(f"[leds] target_grey = {l['target_grey']} must be between 0 and 255")
        if z["mode"] not in (None, "peer", "client", "router"):
            raise BadConfig(f"[zenoh] mode = {z['mode']!r} must be peer, client or router")
        for k in ("listen", "connect"):
            for e in z[k]:
                if not (isinstance(e, str) and _endpoint_ok(e)):
                    raise BadConfig(f"[zenoh] {k} endpoint {e!r} must look like 'tcp/192.168.1.10:7447' "
                                    "(protocol/address:port, port 1..65535)")
        for k in ("publish_hz", "status_hz"):
            if not 0 < z[k] <= 1000:
                raise BadConfig(f"[zenoh] {k} = {z[k]} must be between 0 and 1000")
        if not st["checkpoint_s"] > 0:
            raise BadConfig(f"[state] checkpoint_s = {st['checkpoint_s']} must be > 0")

    def default_roi(self) -> tuple[int, int, int, int]:
        """The thesis's window: a square under the centre row, centred across, as tall as half the frame."""
        w, h = self.camera["width"], self.camera["height"]
        size = min(h // 2, w)
        return ((w - size) // 2, h // 2, size, size)

    def roi(self) -> tuple[int, int, int, int]:
        roi = self.odometry["roi"]
        if roi is None:
            return self.default_roi()
        w, h = self.camera["width"], self.camera["height"]
        if len(roi) != 4 or not all(isinstance(v, int) and not isinstance(v, bool) for v in roi):
            raise BadConfig(f"[odometry] roi = {roi!r} must be four integers [x, y, w, h] in frame pixels")
        x, y, rw, rh = roi
        if x < 0 or y < 0 or rw < 32 or rh < 32 or x + rw > w or y + rh > h:
            raise BadConfig(f"[odometry] roi = {roi!r} must lie inside the {w}x{h} frame and be at "
                            "least 32x32 pixels")
        return (x, y, rw, rh)

    def make_camera(self) -> Camera:
        c = self.camera
        kw = dict(hflip=c["hflip"], vflip=c["vflip"], readout_s=c["readout_ms"] / 1000.0)
        if c["calibration"]:
            cam = Camera.from_calibration(c["calibration"], **kw)
            if (cam.width, cam.height) != (c["width"], c["height"]):
                if abs(cam.width * c["height"] - cam.height * c["width"]) > 0.01 * cam.width * c["height"]:
                    raise BadConfig(
                        f"[camera] calibration is for {cam.width}x{cam.height} frames, another shape than "
                        f"[camera] width/height {c['width']}x{c['height']}; calibrate at the video's size")
                cam = cam.with_size(c["width"], c["height"])
            return cam
        dist = tuple(float(v) for v in (c["distortion"] or ()))
        return Camera.from_fov(c["width"], c["height"], c["vfov_deg"], c["hfov_deg"], distortion=dist, **kw)

    def make_mount(self) -> Mount:
        m = self.mount
        if m["height_m"] is not None:
            return Mount.from_height(m["pipe_diameter_m"], m["height_m"], m["tilt_deg"])
        return Mount.from_car(m["pipe_diameter_m"], m["car_width_m"], m["camera_offset_m"], m["tilt_deg"])

    def geometry(self) -> Geometry:
        camera, mount = self.make_camera(), self.make_mount()
        projection = make_projection(self.odometry["method"], mount)
        roi = self.roi()
        check_distortion(camera, roi)
        # the exact model decides whether the view is usable, whatever method then measures
        exact = make_projection("cylinder", mount)
        worst = check_view(camera, exact, roi, self.odometry["max_incidence_deg"])
        if self.odometry["method"] == "plane":
            check_view(camera, projection, roi, self.odometry["max_incidence_deg"])
        vfov = 2 * math.atan((camera.height / 2) / camera.fy)
        eq31 = 2 * mount.height_m * math.tan(vfov / 2) / camera.height
        return Geometry(camera, mount, projection, roi, worst, eq31)

    def odometry_params(self) -> OdometryParams:
        o = self.odometry
        fp = FlowParams(max_features=o["max_features"], win_px=o["win_px"], levels=o["levels"],
                        max_roundtrip_px=float(o["max_roundtrip_px"]))
        return OdometryParams(flow=fp, min_tracks=o["min_tracks"],
                              max_baseline_px=float(o["max_baseline_px"]),
                              speed_window_s=float(o["speed_window_s"]))

    def summary(self) -> dict:
        """The derived geometry an operator checks before a run (crawlerd --check-config)."""
        g = self.geometry()
        x, y, w, h = g.roi
        corners = g.camera.normalise([[x, y], [x + w - 1, y], [x, y + h - 1], [x + w - 1, y + h - 1]])
        wall = g.projection.to_wall(corners)
        return {
            "name": self.name,
            "method": self.odometry["method"],
            "camera_height_m": round(g.mount.height_m, 6),
            "tilt_deg": g.mount.tilt_deg,
            "frame": [g.camera.width, g.camera.height],
            "intrinsics": {k: round(getattr(g.camera, k), 3) for k in ("fx", "fy", "cx", "cy")},
            "m_per_px_eq31": round(g.m_per_px_eq31, 9),
            "roi": list(g.roi),
            "roi_on_wall_m": {"axial": [round(float(wall[:, 1].min()), 5), round(float(wall[:, 1].max()), 5)],
                              "arc": [round(float(wall[:, 0].min()), 5), round(float(wall[:, 0].max()), 5)]},
            "worst_incidence_deg": round(g.worst_incidence_deg, 2),
            "readout_ms": self.camera["readout_ms"],
        }
