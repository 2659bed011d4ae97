"""A fake of picamera2's Picamera2 that films hw_sim's pipe wall, paced in real time.

crawlerd drives the Pi camera through picamera2 (crawler/camera.py). This class copies picamera2's
API (names, signatures, config dicts, errors, array shapes, metadata units) and the real sensor-mode
tables of the OV5647, IMX219 and IMX708, and renders each frame with hw_sim's Simulator through the
sensor mode, ScalerCrop and output size in force, so the chain plan -> intrinsics -> odometry is
checked end to end against ground truth. Frame k has SensorTimestamp start + k * frame duration on
the world's clock; like the real camera, a consumer that falls behind gets the newest frame.

    world = SimWorld("imx219", tilt_deg=20, speed_m_s=0.2)     # any SimConfig field
    Picamera2 = make_picamera2(world)        # the class crawlerd injects; called as Picamera2(0)
    world.true_distance_m(request.get_metadata()["SensorTimestamp"])    # 0 at the first frame

hw_sim's own render time does not pass in the world (SimWorld.standstill), as a real frame costs its
consumer nothing. Simplifications (docs/simulator.md): no sensor flips, lores is main resized, raw
buffers are zeros, controls act from the next frame to start, captures are blocking only.
"""
from __future__ import annotations

import contextlib
import math
import re
import threading
import time
from dataclasses import dataclass, replace

import cv2
import numpy as np

from .config import SimConfig
from .motion import Motion
from .render import Simulator

ISP_MIN_CROP = (32, 32)     # smallest ISP crop, mode pixels (libcamera asks the ISP; assumed here)
EXPOSURE_MIN_LINES = 4      # approximate: the drivers' shortest integration
FRAME_LINES_MAX = 0xFFFF    # approximate: the drivers' longest frame
REF_EXPOSURE = 8000.0       # exposure (us) x analogue gain that gives SimConfig.brightness
NR_FAST, NR_HIGH_QUALITY, NR_MINIMAL = 1, 2, 3   # libcamera draft.NoiseReductionModeEnum
_YUV, _RGB = ("YUV420", "YVU420"), {"XBGR8888": 4, "XRGB8888": 4, "BGR888": 3, "RGB888": 3}
_RAW_EXTRA = ("bit_depth", "crop_limits", "exposure_limits", "fps", "unpacked")
# Controls the RPi IPA advertises whatever the mode: name -> (min, max, default)
_CONTROLS = {
    "AeEnable": (False, True, True), "ExposureTimeMode": (0, 1, 0), "AnalogueGainMode": (0, 1, 0),
    "AeMeteringMode": (0, 3, 0), "AeConstraintMode": (0, 3, 0), "AeExposureMode": (0, 3, 0),
    "ExposureValue": (-8.0, 8.0, 0.0), "AeFlickerMode": (0, 1, 0), "AeFlickerPeriod": (100, 1000000, None),
    "Brightness": (-1.0, 1.0, 0.0), "Contrast": (0.0, 32.0, 1.0), "Sharpness": (0.0, 16.0, 1.0),
    "Saturation": (0.0, 32.0, 1.0), "NoiseReductionMode": (0, 4, 0), "AwbEnable": (False, True, None),
    "AwbMode": (0, 7, 0), "ColourGains": (0.0, 32.0, None), "ColourTemperature": (100, 100000, None),
    "StatsOutputEnable": (False, True, False), "SyncMode": (0, 2, 0), "SyncFrames": (100, 100000, 1000)}
_AF_CONTROLS = {"AfMode": (0, 2, 0), "AfRange": (0, 2, 0), "AfSpeed": (0, 1, 0), "AfTrigger": (0, 1, 0),
                "AfPause": (0, 2, 0), "LensPosition": (0.0, 15.0, 1.0)}


@dataclass(frozen=True)
class SensorMode:
    """One raw mode, timings from the RPi kernel driver: line = HTS / pixel rate."""
    size: tuple[int, int]
    crop: tuple[int, int, int, int]     # crop_limits: analogue crop, active-area native pixels
    hts: int
    pixel_rate_mhz: float
    vblank_min: int

    @property
    def line_us(self) -> float:
        return self.hts / self.pixel_rate_mhz

    @property
    def min_lines(self) -> int:
        return self.size[1] + self.vblank_min


@dataclass(frozen=True)
class SensorSpec:
    model: str
    i2c: str                            # last part of the libcamera Id
    rotation: int                       # device-tree mounting; libcamera undoes it with sensor flips
    pixel_array: tuple[int, int]
    active: tuple[int, int, int, int]
    formats: tuple[str, ...]            # raw formats in libcamera's order; each has every mode
    modes: tuple[SensorMode, ...]
    fov_deg: tuple[float, float]        # (horizontal, vertical) across the active area
    max_gain: float
    cfa: int                            # ColorFilterArrangement: 0 RGGB, 2 GBRG
    unit_cell_nm: int


def _imx219(size, crop):
    return SensorMode(size, crop, 3448, 182.4, 32)


SENSORS = {
    "ov5647": SensorSpec("ov5647", "ov5647@36", 0, (2624, 1956), (16, 6, 2592, 1944), ("SGBRG10_CSI2P",), (
        SensorMode((640, 480), (16, 0, 2560, 1920), 1852, 55.0, 24),
        SensorMode((1296, 972), (0, 0, 2592, 1944), 1896, 81.6667, 24),
        SensorMode((1920, 1080), (348, 434, 1928, 1080), 2416, 81.6667, 24),
        SensorMode((2592, 1944), (0, 0, 2592, 1944), 2844, 87.5, 24)), (53.50, 41.41), 63.9375, 2, 1400),
    "imx219": SensorSpec("imx219", "imx219@10", 180, (3296, 2480), (8, 8, 3280, 2464),
                         ("SRGGB10_CSI2P", "SRGGB8"), (
        _imx219((640, 480), (1000, 752, 1280, 960)), _imx219((1640, 1232), (0, 0, 3280, 2464)),
        _imx219((1920, 1080), (680, 692, 1920, 1080)), _imx219((3280, 2464), (0, 0, 3280, 2464))),
        (62.2, 48.8), 10.666667, 0, 1120),
    "imx708": SensorSpec("imx708", "imx708@1a", 180, (4640, 2658), (16, 24, 4608, 2592), ("SRGGB10_CSI2P",), (
        SensorMode((1536, 864), (768, 432, 3072, 1728), 5216, 566.4, 40),
        SensorMode((2304, 1296), (0, 0, 4608, 2592), 7824, 585.6, 40),
        SensorMode((4608, 2592), (0, 0, 4608, 2592), 15648, 595.2, 58)), (66.0, 41.0), 16.0, 0, 1400),
}


class SensorFormat:
    """picamera2.sensor_format.SensorFormat: 'SRGGB10_CSI2P' -> bit_depth 10, unpacked 'SRGGB10'."""

    def __init__(self, fmt: str):
        pixels, _, packing = str(fmt).partition("_")
        self.packing = packing or None
        self.bit_depth = int(re.search(r"\d+$", pixels).group())
        self.bayer_order = re.search("[RGB]+", pixels).group()

    @property
    def unpacked(self) -> str:
        return f"S{self.bayer_order}{self.bit_depth}"

    @property
    def format(self) -> str:
        return self.unpacked + (f"_{self.packing}" if self.packing else "")

    def __repr__(self) -> str:
        return self.format


class Transform:
    """Stand-in for libcamera.Transform, which exists only on Raspberry Pi OS."""

    def __init__(self, rotation=0, hflip=False, vflip=False, transpose=False):
        half = rotation % 360 == 180
        self.hflip, self.vflip, self.transpose = bool(hflip) ^ half, bool(vflip) ^ half, bool(transpose)


class ManualClock:
    """A clock for tests: sleep() advances ns() at once, so pacing costs no wall time."""

    def __init__(self, t_ns: int = 10**12):
        self.t = t_ns

    def ns(self) -> int:
        return self.t

    def sleep(self, s: float) -> None:
        self.t += max(1, int(round(s * 1e9)))


class SimWorld:
    """The pipe run a fake camera looks at: sensor, mount/motion/disturbances, clock, ground truth.

    `sim` (default: a 24 h run) updated with `fields` (SimConfig fields: tilt_deg, speed_m_s,
    profile, seed, pipe_diameter_m, ...) gives everything but the camera fields (width, height, FOV,
    window, output_size, fps, exposure, readout), which come from the sensor and the camera's
    configuration. A bad value raises hw_sim's ConfigError here, not mid-run.
    """

    def __init__(self, sensor="imx219", sim: SimConfig | None = None, *, clock=time.monotonic_ns,
                 sleep=time.sleep, start_ns: int | None = None, free_render: bool = True, **fields):
        self.sensor = SENSORS[sensor] if isinstance(sensor, str) else sensor
        self.sim = replace(sim or SimConfig(duration_s=24 * 3600.0), **fields)
        (aw, ah), (hf, vf) = self.sensor.active[2:], self.sensor.fov_deg
        replace(self.sim, width=aw, height=ah, hfov_deg=hf, vfov_deg=vf, window=None,
                output_size=(640, 480))     # checks the mount against this lens
        s = self.sim
        self.motion = Motion(s.profile, s.speed_m_s, s.duration_s, s.accel_m_s2, s.stopgo_period_s,
                             s.stopgo_dwell_s)
        self._clock, self.sleep, self.free_render, self._paused_ns, self._depth = clock, sleep, free_render, 0, 0
        self._auto_start = start_ns is None     # then the run starts with the first camera start()
        self.start_ns = self.clock() if start_ns is None else int(start_ns)
        self.connected = True               # False: global_camera_info() is [] (no camera cable)
        self.busy = False                   # a Picamera2 holds the camera
        self.frames_delivered = 0
        self._stalls: list[list[float]] = []
        self._texture = None

    def clock(self) -> int:
        """The world's time (ns): the given clock, stood still while hw_sim computes (free_render)."""
        return self._clock() - self._paused_ns

    @contextlib.contextmanager
    def standstill(self):
        """On the Pi a frame costs its consumer nothing; here rendering takes ms and a new texture
        tile tens of ms. With free_render that time does not pass in the world, so the camera's
        pacing leaves the consumer exactly the time a real camera would."""
        t0, self._depth = self._clock(), self._depth + 1
        try:
            yield
        finally:
            self._depth -= 1
            if self.free_render and not self._depth:        # count nested stand-stills once
                self._paused_ns += self._clock() - t0

    def t_s(self, ns: int) -> float:
        return (ns - self.start_ns) / 1e9

    def true_distance_m(self, sensor_timestamp_ns: int) -> float:
        """Distance travelled since start_ns at the instant of a SensorTimestamp (a frame's start):
        0 at the first frame unless start_ns was given, like the crawler's own count."""
        return float(self.motion.distance(self.t_s(sensor_timestamp_ns)))

    def stall(self) -> None:
        """Frames completing from now until resume() are lost, as with a loose ribbon cable."""
        if not self.stalled:
            self._stalls.append([self.clock(), math.inf])

    def resume(self) -> None:
        if self.stalled:
            self._stalls[-1][1] = self.clock()

    @property
    def stalled(self) -> bool:
        return bool(self._stalls) and self._stalls[-1][1] == math.inf

    def _lost(self, t_ns):
        return next(((a, b) for a, b in reversed(self._stalls) if a <= t_ns < b), None)

    def camera_info(self) -> list[dict]:
        s = self.sensor
        return [{"Model": s.model, "Location": 2, "Rotation": s.rotation,
                 "Id": f"/base/soc/i2c0mux/i2c@1/{s.i2c}", "Num": 0}] if self.connected else []

    def simulator(self, cfg: SimConfig) -> Simulator:
        """A Simulator on the world's one wall texture (same seed and scale), so tiles are reused."""
        sim = Simulator(cfg)
        if self._texture is None:
            self._texture = sim.texture
        sim.texture = self._texture
        return sim


def make_picamera2(world: SimWorld) -> type:
    """A Picamera2 class bound to `world` (what crawlerd injects in place of picamera2's)."""
    return type("Picamera2", (FakePicamera2,), {
        "world": world, "__module__": __name__, "global_camera_info": staticmethod(world.camera_info)})


# --- libcamera's integer crop arithmetic (pipeline_base.cpp applyScalerCrop, scaleIspCrop) ---
def _tdiv(a: int, b: int) -> int:
    return a // b if a >= 0 else -(-a // b)    # C++ division truncates toward zero


def _isp_crop(native, m: SensorMode):
    """ScalerCrop -> ISP crop in mode pixels: at least the minimum size (same aspect), same centre,
    inside the mode."""
    (ax, ay, aw, ah), (ow, oh) = m.crop, m.size
    x, y, w, h = (int(v) for v in native)
    if not w or not h:
        x, y, w, h = 0, 0, 1, 1
    ix, iy, iw, ih = _tdiv((x - ax) * ow, aw), _tdiv((y - ay) * oh, ah), w * ow // aw, h * oh // ah
    mw, mh = ISP_MIN_CROP
    mw, mh = (w * mh // h, mh) if mw * h < w * mh else (mw, mw * h // w)
    sw, sh = max(iw, mw), max(ih, mh)
    x0, y0 = ix + iw // 2 - sw // 2, iy + ih // 2 - sh // 2
    sw, sh = min(sw, ow), min(sh, oh)
    return (min(max(x0, 0), ow - sw), min(max(y0, 0), oh - sh), sw, sh)


def _native_crop(isp, m: SensorMode):
    (ax, ay, aw, ah), (ow, oh), (x, y, w, h) = m.crop, m.size, isp
    return (_tdiv(x * aw, ow) + ax, _tdiv(y * ah, oh) + ay, w * aw // ow, h * ah // oh)


def _default_isp_crop(m: SensorMode, out):
    """VC4's default: the mode bounded to the largest output's aspect ratio, centred."""
    (w, h), (rw, rh) = m.size, out
    sw, sh = (rw * h // rh, h) if w * rh > rw * h else (w, w * rh // rw)
    return (w // 2 - sw // 2, h // 2 - sh // 2, sw, sh)


@dataclass(frozen=True)
class _Settings:
    """What one frame is made with."""
    crop: tuple[int, int, int, int]     # the effective ScalerCrop, native pixels
    exposure_us: int
    gain: float
    period_ns: int


class FakePicamera2:
    """picamera2.Picamera2 on a SimWorld; make_picamera2(world) gives a class bound to one."""

    world: SimWorld = None

    @staticmethod
    def global_camera_info() -> list[dict]:
        return []

    def __init__(self, camera_num=0, verbose_console=None, tuning=None, allocator=None):
        self.is_open, self.camera, self.started = False, None, False
        self.camera_idx = self.global_camera_info()[camera_num]["Num"]   # IndexError, as picamera2
        if self.world.busy:
            raise RuntimeError("Camera __init__ sequence did not complete.") from RuntimeError(
                "Failed to acquire camera: Device or resource busy")
        s = self.camera = self.world.sensor
        self.world.busy = self.is_open = True
        self._raw_modes = [{"format": f, "size": m.size} for f in s.formats for m in s.modes]
        self.sensor_resolution = max(s.modes, key=lambda m: m.size[0] * m.size[1]).size
        self.sensor_format = s.formats[0]
        self.camera_config, self.sensor_modes_, self.stop_count, self.configure_count = {}, [], 0, 0
        self._mode, self._ctl, self._sims, self._lock = None, {}, {}, threading.RLock()
        self._props = {"Model": s.model, "Location": 2, "Rotation": s.rotation, "PixelArraySize": s.pixel_array,
                       "PixelArrayActiveAreas": [s.active], "ScalerCropMaximum": (0, 0, 0, 0),
                       "UnitCellSize": (s.unit_cell_nm, s.unit_cell_nm), "ColorFilterArrangement": s.cfa}

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    # --- properties -------------------------------------------------------------------------------
    @property
    def camera_properties(self) -> dict:
        return {} if self.camera is None else dict(self._props)

    @property
    def camera_controls(self) -> dict:
        """name -> (min, max, default); the limits follow the configured mode, as libcamera's."""
        if self.camera is None:
            return {}
        c = _CONTROLS | (_AF_CONTROLS if self.camera.model == "imx708" else {})
        m = self._mode
        if m is None:                       # the IPA's defaults until a mode is configured
            return c | {"ExposureTime": (1, 66666, 20000), "AnalogueGain": (1.0, 16.0, 1.0),
                        "FrameDurationLimits": (33333, 250000000, (33333, 33333)),
                        "ScalerCrop": ((0, 0, 0, 0), (65535, 65535, 65535, 65535), (0, 0, 0, 0))}
        ln = m.line_us
        return c | {"ExposureTime": (int(EXPOSURE_MIN_LINES * ln), int((FRAME_LINES_MAX - 4) * ln), 20000),
                    "AnalogueGain": (1.0, self.camera.max_gain, 1.0),
                    "FrameDurationLimits": (int(m.min_lines * ln), int(FRAME_LINES_MAX * ln), (33333, 33333)),
                    "ScalerCrop": (_native_crop((0, 0) + ISP_MIN_CROP, m), m.crop,
                                   _native_crop(self._default_isp, m))}

    @property
    def sensor_modes(self) -> list[dict]:
        """Every raw mode. Like picamera2, the first read configures each mode in turn (so not while
        started) and leaves the camera configured in the last one."""
        if not self.sensor_modes_:
            for f in self.camera.formats:
                fmt = SensorFormat(f)
                for m in self.camera.modes:
                    self.configure(self.create_preview_configuration(raw={"format": f, "size": m.size}))
                    ctl = self.camera_controls
                    self.sensor_modes_.append({
                        "format": fmt, "unpacked": fmt.unpacked, "bit_depth": fmt.bit_depth, "size": m.size,
                        "fps": round(1e6 / ctl["FrameDurationLimits"][0], 2), "crop_limits": ctl["ScalerCrop"][1],
                        "exposure_limits": tuple(i for i in ctl["ExposureTime"] if i != 0)})
        return self.sensor_modes_

    # --- configuration ----------------------------------------------------------------------------
    def create_preview_configuration(self, main={}, lores=None, raw={}, transform=None, colour_space="Sycc",
                                     buffer_count=4, controls={}, display="main", encode="main", queue=True,
                                     sensor={}, use_case="preview") -> dict:
        return self._create(locals(), "XBGR8888", (640, 480), NR_MINIMAL, (100, 83333))

    def create_still_configuration(self, main={}, lores=None, raw={}, transform=None, colour_space="Sycc",
                                   buffer_count=1, controls={}, display=None, encode=None, queue=True,
                                   sensor={}, use_case="still") -> dict:
        return self._create(locals(), "BGR888", self.sensor_resolution, NR_HIGH_QUALITY, (100, 10**9))

    def create_video_configuration(self, main={}, lores=None, raw={}, transform=None, colour_space=None,
                                   buffer_count=6, controls={}, display="main", encode="main", queue=True,
                                   sensor={}, use_case="video") -> dict:
        return self._create(locals(), "XBGR8888", (1280, 720), NR_FAST, (33333, 33333))

    def _create(self, a, fmt, size, nr, fdl) -> dict:
        if self.camera is None:
            raise RuntimeError("Camera not opened")
        main = _stream({"format": fmt, "size": size, "preserve_ar": True}, a["main"])
        cs = a["colour_space"] or ("Smpte170m" if main["size"][0] < 1280 or main["size"][1] < 720 else "Rec709")
        c = {"use_case": a["use_case"], "transform": a["transform"] or Transform(), "colour_space": cs,
             "buffer_count": a["buffer_count"], "queue": a["queue"], "main": main,
             "lores": _stream({"format": "YUV420", "size": main["size"], "preserve_ar": False}, a["lores"]),
             "raw": _stream({"format": self.sensor_format, "size": main["size"]}, a["raw"], raw=True),
             "controls": {"NoiseReductionMode": nr, "FrameDurationLimits": fdl} | a["controls"],
             "sensor": a["sensor"]}
        for key in ("display", "encode"):
            if a[key] is not None and c.get(a[key]) is None:
                raise RuntimeError(f"{key.capitalize()} stream {a[key]} was not defined")
            c[key] = a[key]
        return c

    def configure(self, camera_config=None) -> None:
        if self.started:
            raise RuntimeError("Camera must be stopped before configuring")
        if camera_config is None or isinstance(camera_config, str):
            camera_config = {"still": self.create_still_configuration, "video": self.create_video_configuration
                             }.get(camera_config, self.create_preview_configuration)()
        if not isinstance(camera_config, dict):
            raise TypeError("Invalid type for `camera_config` given")
        c = camera_config.copy()            # shallow, as picamera2's: the stream dicts gain stride in place
        self.camera_config = {}
        _check_config(c)
        sensor, raw = c.get("sensor") or {}, c["raw"]
        depth = sensor.get("bit_depth") or SensorFormat(raw["format"] if raw else self.sensor_format).bit_depth
        size = sensor.get("output_size") or (raw["size"] if raw else c["main"]["size"])
        best = min(self._raw_modes, key=lambda r: _score(r, depth, size))
        mode = next(m for m in self.camera.modes if m.size == best["size"])
        ctl = self._checked(c["controls"])
        if raw is not None:
            raw["format"], raw["size"] = SensorFormat(best["format"]).format, mode.size
        for st in (c["main"], c["lores"], raw):
            if st is not None:
                _fill_stride(st)
        c["sensor"] = {"bit_depth": SensorFormat(best["format"]).bit_depth, "output_size": mode.size}
        largest = max((c[n]["size"] for n in ("main", "lores") if c[n]), key=lambda s: s[0] * s[1])
        self._mode, self._out, self._default_isp = mode, c["main"]["size"], _default_isp_crop(mode, largest)
        self._ctl, self._queue = ctl, c["queue"] and c["buffer_count"] > 1
        self._props |= {"ScalerCropMaximum": mode.crop, "SensorSensitivity": 1.0}
        self.camera_config = c
        self.configure_count += 1

    def camera_configuration(self) -> dict:
        return self.camera_config

    def stream_configuration(self, name="main") -> dict:
        return self.camera_config[name]

    # --- controls ---------------------------------------------------------------------------------
    def _checked(self, controls: dict) -> dict:
        known, out = self.camera_controls, {}
        for k, v in controls.items():
            if k == "FrameRate":            # picamera2's virtual control
                lo, hi = v if isinstance(v, (tuple, list)) else (v, v)
                k, v = "FrameDurationLimits", (int(1e6 / hi), int(1e6 / lo))
            if k not in known:
                raise RuntimeError(f"Control {k} is not advertised by libcamera")
            out[k] = tuple(v) if isinstance(v, list) else v
        return out

    def set_controls(self, controls: dict) -> None:
        """Applied at start(), or while running from the next frame whose exposure has not begun."""
        with self._lock:
            self._ctl |= self._checked(controls)
            if self.started:
                k = self._k_at(self.world.clock()) + 1
                segs = [s for s in self._segs if s[0] < k] + [(k, self._ts(k), self._resolve(self._ctl))]
                while len(segs) > 1 and segs[1][0] <= self._last_k + 1 and not self._orphans:
                    segs.pop(0)             # no frame of the first segment can be returned any more
                self._segs = segs

    def _resolve(self, ctl: dict) -> _Settings:
        """Controls -> what sensor and ISP do: the frame duration clamped and in whole lines, the
        exposure and gain (auto: exposure x gain = REF_EXPOSURE), the effective ScalerCrop."""
        m, ln = self._mode, self._mode.line_us
        lo, hi = ctl.get("FrameDurationLimits", (33333, 33333))
        lo = min(max(lo, m.min_lines * ln), FRAME_LINES_MAX * ln)
        hi = min(max(hi, lo), FRAME_LINES_MAX * ln)
        e, g = int(ctl.get("ExposureTime") or 0), float(ctl.get("AnalogueGain") or 0.0)
        e = e or REF_EXPOSURE / max(g, 1.0)
        lines = max(m.min_lines, round(min(max(lo, e + 4 * ln), hi) / ln))
        e = int(min(max(e, EXPOSURE_MIN_LINES * ln), (lines - 4) * ln))
        g = min(max(g or REF_EXPOSURE / e, 1.0), self.camera.max_gain)
        isp = _isp_crop(ctl["ScalerCrop"], m) if "ScalerCrop" in ctl else self._default_isp
        return _Settings(_native_crop(isp, m), e, round(g, 6), int(round(lines * ln * 1000)))

    # --- running ----------------------------------------------------------------------------------
    def start(self, config=None, show_preview=False) -> None:
        if not self.camera_config and config is None:
            config = "preview"
        if config is not None:
            self.configure(config)
        with self._lock:
            if self.started:
                return
            st, w = self._resolve(self._ctl), self.world
            if w._auto_start:
                w.start_ns, w._auto_start = w.clock(), False
            with w.standstill():                # the first view's tiles, before the first frame
                self._simulator(st).render(w.t_s(w.clock()))
            self._segs, self._last_k, self._held, self._orphans = [(0, w.clock(), st)], -1, 0, []
            self._lat = int(self._mode.size[1] * self._mode.line_us * 1000)   # frame start -> buffer done
            self.started = True

    def stop(self) -> None:
        if self.started:
            self.started = False
            self.stop_count += 1

    def close(self) -> None:
        if self.is_open:
            self.stop()
            self.world.busy, self.is_open, self.camera = False, False, None
            self.camera_config, self._sims = {}, {}

    def cancel_all_and_flush(self) -> None:
        """Forget timed-out captures (picamera2 leaves them queued: each would take a frame)."""
        self._orphans = []

    def _seg(self, k):
        return next((s for s in reversed(self._segs) if s[0] <= k), self._segs[0])

    def _ts(self, k) -> int:
        k0, ts0, st = self._seg(k)
        return ts0 + (k - k0) * st.period_ns

    def _k_at(self, t_ns) -> int:
        """The newest frame whose SensorTimestamp is <= t_ns."""
        for k0, ts0, st in reversed(self._segs):
            if t_ns >= ts0:
                return k0 + int((t_ns - ts0) // st.period_ns)
        return self._segs[0][0] - 1

    def _scan(self, lo, hi, down, flush):
        """The first usable frame in [lo, hi], searching down or up: not lost in a stall, not
        dropped (SimConfig.drop_prob), and exposed after `flush`."""
        k, w = (hi if down else lo), self.world
        while lo <= k <= hi:
            ts = self._ts(k)
            gap = w._lost(ts + self._lat)
            if gap:
                if not down and gap[1] == math.inf:
                    return None             # still stalled: nothing later has arrived
                k = self._k_at(gap[0] - self._lat - 1) if down else self._k_at(gap[1] - self._lat - 1) + 1
                continue
            p = w.sim.drop_prob
            if not (p and np.random.default_rng([w.sim.seed, 0xD0, k]).random() < p) and (
                    flush is None or ts - 1000 * self._seg(k)[2].exposure_us >= flush):
                return k
            k += -1 if down else 1
        return None

    def _pick(self, now, t_call, flush):
        newest = self._k_at(now - self._lat)
        while self._orphans:    # a timed-out capture takes the first frame after its timeout
            k = self._scan(max(self._last_k + 1, self._k_at(self._orphans[0] - self._lat) + 1), newest, False, None)
            if k is None:
                return None
            self._last_k, self._held = k, self._held + 1
            self._orphans.pop(0)
        if self._held >= self.camera_config["buffer_count"]:
            return None         # the application holds every buffer: the camera starves
        if self._queue:         # picamera2 keeps the latest completed request
            return self._scan(self._last_k + 1, newest, True, flush)
        return self._scan(max(self._last_k, self._k_at(t_call - self._lat)) + 1, newest, False, flush)

    def _next_frame(self, timeout_s, flush) -> int:
        w = self.world
        t_call = w.clock()
        deadline = None if timeout_s is None else t_call + int(timeout_s * 1e9)
        while True:
            with self._lock:
                now = w.clock()
                k = self._pick(now, t_call, flush) if self.started else None
                if k is not None:
                    self._last_k, self._held = k, self._held + 1
                    return k
                if deadline is not None and now >= deadline:
                    if self.started:
                        self._orphans.append(now)
                    raise TimeoutError(f"no frame within {timeout_s:g} s")
                if not self.started and deadline is None:
                    raise RuntimeError("the camera is not started: picamera2 would wait forever")
                due = self._ts(self._k_at(now - self._lat) + 1) + self._lat if self.started else now + 10**7
            w.sleep(max(min(due, deadline or due) - now, 100_000) / 1e9)

    def capture_request(self, wait=None, signal_function=None, flush=None) -> "CompletedRequest":
        """The newest completed frame not yet returned, else the next one. wait None/True: block;
        seconds: TimeoutError (concurrent.futures.TimeoutError is the builtin on 3.11)."""
        if wait is False or (wait is None and signal_function is not None):
            raise NotImplementedError("the fake offers blocking captures only (wait=None, True or seconds)")
        k = self._next_frame(None if wait in (None, True) else float(wait),
                             self.world.clock() if flush is True else flush)
        with self._lock:
            ts, st, m = self._ts(k), self._seg(k)[2], self._mode
            sim = self._simulator(st)
        row0 = (st.crop[1] - m.crop[1]) * m.size[1] / m.crop[3]       # the window's top row in the mode
        t = self.world.t_s(ts) + (row0 * m.line_us - st.exposure_us / 2) / 1e6   # ...its mid-exposure
        md = {"SensorTimestamp": ts, "ScalerCrop": st.crop, "ExposureTime": st.exposure_us,
              "AnalogueGain": st.gain, "DigitalGain": 1.0, "FrameDuration": int(round(st.period_ns / 1000)),
              "ColourGains": (1.8, 1.6), "ColourTemperature": 4500, "Lux": 400.0, "AeLocked": True,
              "SensorBlackLevels": (4096, 4096, 4096, 4096), "FocusFoM": 1000,
              "ColourCorrectionMatrix": (1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0)}
        self.world.frames_delivered += 1
        return CompletedRequest(self, md, sim, t, st.exposure_us * st.gain / REF_EXPOSURE)

    @contextlib.contextmanager
    def captured_request(self, wait=None, flush=None):
        request = self.capture_request(wait=wait, flush=flush)
        try:
            yield request
        finally:
            request.release()

    def capture_metadata(self, wait=None, signal_function=None) -> dict:
        with self.captured_request(wait=wait) as r:
            return r.get_metadata()

    def capture_array(self, name="main", wait=None, signal_function=None) -> np.ndarray:
        with self.captured_request(wait=wait) as r:
            return r.make_array(name)

    def _simulator(self, st: _Settings) -> Simulator:
        """hw_sim's camera for these settings: the active array with the lens FOV, cropped to the
        effective ScalerCrop, scaled to main, this exposure, and the window's readout time."""
        m, s = self._mode, self.camera
        key = (st.crop, self._out, st.exposure_us, st.period_ns)
        if key not in self._sims:
            rows = st.crop[3] * m.size[1] / m.crop[3]
            cfg = replace(self.world.sim, width=s.active[2], height=s.active[3], hfov_deg=s.fov_deg[0],
                          vfov_deg=s.fov_deg[1], window=st.crop, output_size=self._out,
                          fps=1e9 / st.period_ns, exposure_ms=st.exposure_us / 1000,
                          readout_ms=max(rows - 1, 0) * m.line_us / 1000, drop_prob=0.0)
            if len(self._sims) >= 4:
                self._sims.pop(next(iter(self._sims)))
            with self.world.standstill():
                self._sims[key] = self.world.simulator(cfg)
        return self._sims[key]

    def _released(self, request: "CompletedRequest") -> None:
        with self._lock:
            if request.stop_count == self.stop_count:
                self._held -= 1


class CompletedRequest:
    """A captured frame holding one camera buffer until release() (picamera2/request.py). Its
    pixels are rendered by the first make_array, so frames nobody looks at cost nothing."""

    def __init__(self, picam2: FakePicamera2, metadata: dict, sim: Simulator, t_s: float, brightness: float):
        self.picam2, self.request, self.ref_count = picam2, object(), 1
        self.stop_count, self.configure_count = picam2.stop_count, picam2.configure_count
        self.config = picam2.camera_config.copy()
        self._md, self._sim, self._t, self._b, self._grey = metadata, sim, t_s, brightness, None
        self._mapped: dict[str, np.ndarray] = {}

    def acquire(self) -> None:
        if self.ref_count == 0:
            raise RuntimeError("CompletedRequest: acquiring lock with ref_count 0")
        self.ref_count += 1

    def release(self) -> None:
        self.ref_count -= 1
        if self.ref_count < 0:
            raise RuntimeError("CompletedRequest: lock now has negative ref_count")
        if self.ref_count == 0:
            self.picam2._released(self)
            self.request, self.config = None, {}
            for buf in self._mapped.values():    # the camera refills this memory with a new frame
                buf[...] = 0

    def get_metadata(self) -> dict:
        assert self.request is not None
        return dict(self._md)

    def _image(self) -> np.ndarray:
        if self._grey is None:
            with self.picam2.world.standstill():
                img = self._sim.render(self._t)
            if abs(self._b - 1.0) > 1e-6:       # exposure x gain off the reference: brighter/darker
                img = np.clip(img * np.float32(self._b) + np.float32(0.5), 0, 255).astype(np.uint8)
            self._grey = img
        return self._grey

    def make_array(self, name: str) -> np.ndarray:
        """A copy shaped as picamera2's: YUV420 (h*3//2, stride) with Y = [:h, :w]; RGB (h, w, 3|4)."""
        cfg = self.config.get(name)
        if cfg is None:
            raise RuntimeError(f"Stream {name!r} is not defined")
        (w, h), fmt, stride = cfg["size"], cfg["format"], cfg["stride"]
        if name == "raw":
            return np.zeros((h, stride), np.uint8)     # raw Bayer pixels are not simulated
        y = self._image()
        if y.shape != (h, w):
            y = cv2.resize(y, (w, h), interpolation=cv2.INTER_AREA)
        if fmt in _YUV:
            buf = np.full((h * 3 // 2, stride), 128, np.uint8)
            buf[:h, :w], buf[:h, w:] = y, 0
            return buf
        out = np.repeat(y[:, :, None], _RGB[fmt], axis=2)
        if _RGB[fmt] == 4:
            out[:, :, 3] = 255
        return out

    def make_buffer(self, name: str) -> np.ndarray:
        return self.make_array(name).ravel()

    def _mapped_buffer(self, name: str) -> np.ndarray:
        if self.request is None:
            raise RuntimeError("CompletedRequest: mapping a released request")
        if name not in self._mapped:
            self._mapped[name] = self.make_array(name)
        return self._mapped[name]


class MappedArray:
    """picamera2.MappedArray(request, stream, reshape=True, write=True): the request's buffer in place,
    no copy. Valid only until the request is released: the fake then zeroes it, as the camera would
    overwrite it, so a consumer that keeps a view sees the mistake."""

    def __init__(self, request: CompletedRequest, stream: str, reshape: bool = True, write: bool = True):
        self._request, self._stream, self._write = request, stream, write
        self.array = None

    def __enter__(self) -> "MappedArray":
        self.array = self._request._mapped_buffer(self._stream)
        if not self._write:
            self.array = self.array.view()
            self.array.flags.writeable = False
        return self

    def __exit__(self, *exc) -> None:
        self.array = None


def _stream(defaults: dict, updates, raw: bool = False):
    """picamera2's _make_initial_stream_config, then align_stream(optimal=False) (even sizes)."""
    if updates is None:
        return None
    valid = ("format", "size", "stride", "preserve_ar")
    for k, v in updates.items():
        if k in valid:
            defaults[k] = str(v) if isinstance(v, SensorFormat) else v
        elif not (raw and k in _RAW_EXTRA):
            raise ValueError(f"Bad key {k!r}: valid stream configuration keys are {valid}")
    if not raw:
        w, h = defaults["size"]
        defaults["size"] = (w - w % 2, h - h % 2)
    return defaults


def _check_config(c: dict) -> None:
    """picamera2's check_camera_config, plus what the fake cannot do."""
    for name in ("colour_space", "transform", "main", "lores", "raw"):
        if name not in c:
            raise RuntimeError(f"{name!r} key expected in camera configuration")
    t = c["transform"]
    if not all(hasattr(t, a) for a in ("hflip", "vflip", "transpose")):
        raise RuntimeError("Transform has incorrect type")
    if t.hflip or t.vflip or t.transpose:
        raise NotImplementedError("sensor flips are not simulated (hw_sim's rolling shutter runs top-down)")
    bad = set(c.get("sensor") or {}) - {"bit_depth", "output_size"}
    if bad:
        raise RuntimeError(f"Unexpected keys {bad} in sensor configuration")
    for name in ("main", "lores", "raw"):
        st = c[name]
        if st is None and name != "main":
            continue
        if type(st) is not dict:
            raise RuntimeError(name + " stream should be a dictionary")
        if "format" not in st or "size" not in st:
            raise RuntimeError(f"{'size' if 'format' in st else 'format'} not found in {name} stream")
        fmt, size = st["format"], st["size"]
        if type(fmt) is not str:
            raise RuntimeError("format in " + name + " stream should be a string")
        if name == "raw" and not re.fullmatch(r"S[RGB]{4}\d+(_\w+)?", fmt):
            raise RuntimeError("Unrecognised raw format " + fmt)
        if name != "raw" and fmt not in _YUV and fmt not in _RGB:
            raise NotImplementedError(f"format {fmt} is not simulated: use YUV420, YVU420 or an RGB format")
        if type(size) is not tuple or len(size) != 2:
            raise RuntimeError("size in " + name + " stream should be (width, height)")
        if size[0] % 2 or size[1] % 2:
            raise RuntimeError("width and height should be even")
    if c["lores"] is not None:
        (mw, mh), (lw, lh) = c["main"]["size"], c["lores"]["size"]
        if lw > mw or lh > mh:
            raise RuntimeError("lores stream dimensions may not exceed main stream")
        if c["lores"]["format"] not in _YUV:
            raise RuntimeError("lores stream must be YUV")


def _score(raw_mode: dict, bit_depth: int, size) -> float:
    """picamera2's sensor-mode score (which copies libcamera's): a bit larger, same aspect, same depth."""
    def sf(desired, actual):
        d = desired - actual
        return -d / 4 if d < 0 else d * 2
    (w, h), (mw, mh) = size, raw_mode["size"]
    return (sf(w, mw) + sf(h, mh) + 1500 * sf(w / h, mw / mh)
            + 500 * abs(bit_depth - SensorFormat(raw_mode["format"]).bit_depth))


def _fill_stride(st: dict) -> None:
    """VC4 bytes per line: the width aligned to 32 pixels (bcm2835-isp), times bytes per pixel."""
    (w, h), fmt = st["size"], st["format"]
    if fmt in _YUV:
        st["stride"] = -(-w // 32) * 32
        st["framesize"] = st["stride"] * h * 3 // 2
    else:
        bpp = _RGB.get(fmt)
        st["stride"] = -(-w // 32) * 32 * bpp if bpp else -(-(w * SensorFormat(fmt).bit_depth // 8) // 32) * 32
        st["framesize"] = st["stride"] * h
