"""The CSI camera through picamera2, on a cropped sensor window, as a FrameSource.

Only the sensor mode raises the frame rate (ScalerCrop is an ISP crop), so the plan picks the fastest
mode whose field of view covers the wanted window, then crops the ISP to exactly that window and scales
it to a small YUV420 output whose Y plane the odometry reads in place (MappedArray, no copy). The
same plan gives the odometry the exact intrinsics of the output (mode crop, binning, ScalerCrop and
scale) and the rolling shutter readout of the window.

picamera2 is imported only when the camera is opened: it exists only on Raspberry Pi OS (apt
python3-picamera2). The camera class is injectable, so `--sim` and tests pass hw_sim's fake.
"""

from __future__ import annotations

import logging
import re
import time
from dataclasses import dataclass, replace

from .calibration import load_calibration
from .errors import BadConfig, CameraUnavailable, CrawlerError
from .geometry import Camera
from .ports import Frame
from .settings import CameraSettings

_log = logging.getLogger(__name__)

INSTALL_HINT = ("picamera2 is not installed; on Raspberry Pi OS run 'sudo apt install python3-picamera2' "
                "and create the venv with 'python3 -m venv --system-site-packages' (see docs/deploy.md); "
                "off the Pi use --sim or --replay FILE")

# Lens field of view across the full active pixel array (datasheets), by libcamera Model name.
SENSOR_FOV_DEG = {
    "ov5647": (53.50, 41.41),
    "imx219": (62.2, 48.8),
    "imx708": (66.0, 41.0), "imx708_noir": (66.0, 41.0),
    "imx708_wide": (102.0, 67.0), "imx708_wide_noir": (102.0, 67.0),
}
# Minimum vertical blanking lines of each sensor's driver: line time = 1 / (fps_max * (rows + vblank)).
# The IMX708 driver's differs per mode: 58 lines at full resolution, 40 in the binned modes.
SENSOR_VBLANK_MIN = {"ov5647": 24, "imx219": 32, "imx708": {(4608, 2592): 58, None: 40}}


def vblank_lines(model: str, mode_size) -> int:
    """The driver's minimum vertical blanking of `model` in the mode of `mode_size` (0 if unknown)."""
    v = SENSOR_VBLANK_MIN.get(model.split("_")[0], 0)
    return v.get(tuple(mode_size), v[None]) if isinstance(v, dict) else v


class CameraStalled(CrawlerError, TimeoutError):
    """The camera stopped delivering frames."""


@dataclass(frozen=True)
class WindowPlan:
    """How the sensor is driven and what the odometry then sees."""

    mode: dict                       # the chosen picamera2 sensor mode
    scaler_crop: tuple[int, int, int, int]   # ISP crop, native pixels of the active area
    output_size: tuple[int, int]
    fps: float
    camera: Camera                   # intrinsics and readout (top output row to bottom) of the output
    line_time_s: float = 0.0
    top_row_s: float = 0.0           # the window's top row is read this long after the mode's first

    @property
    def frame_duration_us(self) -> int:
        return int(round(1e6 / self.fps))

    def describe(self) -> dict:
        x, y, w, h = self.scaler_crop
        return {"sensor_mode": list(self.mode["size"]), "mode_fps": self.mode["fps"],
                "mode_crop": list(self.mode["crop_limits"]), "scaler_crop": [x, y, w, h],
                "output_size": list(self.output_size), "fps": round(self.fps, 3),
                "readout_ms": round(self.camera.readout_s * 1000, 4)}


def default_window(modes, active_size, output_size, vflip: bool = False):
    """The thesis's view on the sensor: a window of the output's aspect under the centre row,
    centred across (above the centre in sensor rows if the camera is mounted upside down), as large
    as the fastest mode that can deliver output_size without upscaling allows (at most half the
    array tall). If that mode's crop leaves too little room below the centre, the window moves up
    just enough."""
    aw, ah = active_size
    ow, oh = output_size
    centre = ah // 2
    for mode in sorted(modes, key=lambda m: -m["fps"]):
        mx, my, mw, mh = mode["crop_limits"]
        need = -(-oh * mh // mode["size"][1])           # native rows that give oh mode rows
        room = (centre - my) if vflip else (my + mh - centre)
        h = min(ah // 2, max(room, need), mh, mw * oh // ow) & ~1
        w = (h * ow // oh) & ~1
        if h < need or w * mode["size"][0] / mw < ow:
            continue
        x = max(mx, min(aw // 2 - w // 2, mx + mw - w)) & ~1
        y = centre - h if vflip else centre
        y = max(my, min(y, my + mh - h)) & ~1
        return (x, y, w, h)
    raise BadConfig(f"no sensor mode can deliver [camera] output_size = {list(output_size)}; "
                    "choose a smaller output_size or set [camera] sensor_window")


def _contains(outer, inner) -> bool:
    ox, oy, ow, oh = outer
    x, y, w, h = inner
    return ox <= x and oy <= y and x + w <= ox + ow and y + h <= oy + oh


def plan_window(modes: list[dict], active_size, window, output_size, fps: float,
                lens, vblank=0,
                hflip: bool = False, vflip: bool = False) -> WindowPlan:
    """Choose the sensor mode and ScalerCrop for a window of the active array.

    The fastest mode whose crop covers the window wins; among equally fast ones, the one that keeps
    more sensor pixels across the window (less binning). A mode that would have to upscale the window
    is taken only when no other covers it.
    """
    aw, ah = active_size
    if window is None:
        window = default_window(modes, active_size, output_size, vflip)
    x, y, w, h = (int(v) for v in window)
    if w <= 0 or h <= 0 or not _contains((0, 0, aw, ah), (x, y, w, h)):
        raise BadConfig(f"[camera] sensor_window = {[x, y, w, h]} must lie inside the active pixel "
                        f"array (0, 0, {aw}, {ah})")
    ow, oh = output_size
    covering = [m for m in modes if _contains(m["crop_limits"], (x, y, w, h))]
    if not covering:
        raise BadConfig(f"[camera] sensor_window = {[x, y, w, h]} is not covered by any sensor mode "
                        f"(mode crops: {[tuple(m['crop_limits']) for m in modes]}); move it toward the centre")

    def density(m):   # mode pixels per native pixel across
        return m["size"][0] / m["crop_limits"][2]

    sharp = [m for m in covering if w * density(m) >= ow and h * m["size"][1] / m["crop_limits"][3] >= oh]
    pool = sharp or covering
    mode = max(pool, key=lambda m: (round(m["fps"], 1), density(m)))
    if not sharp:
        _log.warning("sensor mode %s must upscale the %dx%d window to %dx%d; a smaller output_size "
                     "would be as sharp", mode["size"], w, h, ow, oh)
    use_fps = min(fps, mode["fps"])
    if use_fps < fps:
        _log.warning("[camera] fps = %g exceeds the %s mode's %.1f fps; running at %.1f",
                     fps, mode["size"], mode["fps"], use_fps)
    blank = vblank(tuple(mode["size"])) if callable(vblank) else vblank    # lines, or size -> lines
    line_time_s = 1.0 / (mode["fps"] * (mode["size"][1] + blank))
    return plan_for_mode(mode, snap_to_mode((x, y, w, h), mode), active_size, output_size, use_fps,
                         lens, line_time_s, hflip, vflip)


def snap_to_mode(window, mode):
    """The window on the mode's pixel grid, as libcamera will apply it (binned modes move in steps)."""
    ax, ay, aw, ah = mode["crop_limits"]
    mw, mh = mode["size"]
    x, y, w, h = window
    return (ax + (x - ax) * mw // aw * aw // mw, ay + (y - ay) * mh // ah * ah // mh,
            w * mw // aw * aw // mw, h * mh // ah * ah // mh)


def plan_for_mode(mode, window, active_size, output_size, fps, lens, line_time_s,
                  hflip=False, vflip=False) -> WindowPlan:
    """Intrinsics and readout of the output when `window` of the active array is scaled to it.

    `lens` is the full active array's (hfov, vfov) in degrees, or its calibrated Camera.
    """
    aw, ah = active_size
    x, y, w, h = window
    ow, oh = output_size
    rows_per_native = mode["size"][1] / mode["crop_limits"][3]
    readout = (h * rows_per_native - 1) * line_time_s   # first to last sensor row of the window
    if isinstance(lens, Camera):
        full = lens
    else:
        hfov, vfov = lens
        full = Camera.from_fov(aw, ah, vfov, hfov)
    cam = full.window(x, y, w, h, ow, oh)
    cam = Camera(cam.width, cam.height, cam.fx, cam.fy, cam.cx, cam.cy, cam.distortion, hflip=hflip,
                 vflip=vflip, readout_s=readout)
    return WindowPlan(mode=mode, scaler_crop=(x, y, w, h), output_size=(ow, oh), fps=fps,
                      camera=cam, line_time_s=line_time_s,
                      top_row_s=(y - mode["crop_limits"][1]) * rows_per_native * line_time_s)


PICAMERA2_MIN = (0, 3, 20)      # older ones block forever in capture_request(wait=...)


def import_picamera2():
    """The real Picamera2 and MappedArray classes, or CameraUnavailable saying why and what to do."""
    try:
        from picamera2 import MappedArray, Picamera2
    except ImportError as exc:
        if exc.name == "picamera2":
            raise CameraUnavailable(INSTALL_HINT) from None
        raise CameraUnavailable(f"picamera2 is installed but cannot be imported ({type(exc).__name__}: {exc}); "
                                "a venv that shadows apt's numpy or OpenCV is the usual cause: see "
                                "docs/deploy.md") from None
    _check_picamera2_version()
    return Picamera2, MappedArray


def _check_picamera2_version():
    from importlib.metadata import PackageNotFoundError, version

    try:
        text = version("picamera2")
    except PackageNotFoundError:
        _log.warning("picamera2's version is unknown; crawlerd needs %s or newer",
                     ".".join(map(str, PICAMERA2_MIN)))
        return
    have = tuple(int(p) for p in re.findall(r"\d+", text)[:3])
    if have < PICAMERA2_MIN:
        raise CameraUnavailable(f"picamera2 {text} is too old: before {'.'.join(map(str, PICAMERA2_MIN))} "
                                "capture_request(wait=...) can block forever on a stalled camera; "
                                "run 'sudo apt update && sudo apt install python3-picamera2'")


class Picamera2Source:
    """Frames from a (real or fake) Picamera2 on a planned window; `frames()` yields Y-plane views.

    A FrameSource: after entering, `camera` is the exact camera of the frames (from the window plan)
    and `default_roi` the whole output frame (the window already is the region to measure).
    """

    def __init__(self, settings: CameraSettings, camera_class=None, *, mapped_array=None,
                 kind: str = "camera"):
        self.settings = settings
        self.camera_class = camera_class
        self.mapped_array = mapped_array    # picamera2.MappedArray: frames without a copy
        self.kind = kind
        self.description = kind
        self.output_size = tuple(settings.output_size)
        # full active array intrinsics from a calibration file, else the lens FOV (from the model)
        self.calibration = load_calibration(settings.calibration) if settings.calibration else None
        self.plan: WindowPlan | None = None
        self.model = None
        self.cam = None
        self.first_sensor_ns = self.last_sensor_ns = None
        self.origin_ns = None               # sensor time of frame 0's t_s = 0
        self.sensor_clock_ns = time.monotonic_ns    # SensorTimestamp's clock (V4L2: CLOCK_MONOTONIC)
        self.warnings: list[str] = []

    def clock_s(self) -> float:
        """Now, on the frames' time base (t_s): for other sensors read beside the camera (the wheel)."""
        return 0.0 if self.origin_ns is None else (self.sensor_clock_ns() - self.origin_ns) / 1e9

    @property
    def camera(self) -> Camera:
        return self.plan.camera

    @property
    def default_roi(self) -> tuple[int, int, int, int]:
        return (0, 0, self.plan.camera.width, self.plan.camera.height)

    def info(self) -> dict:
        """The sensor plan, for the status."""
        return self.plan.describe() if self.plan else {}

    def __enter__(self):
        if self.camera_class is None:
            self.camera_class, self.mapped_array = import_picamera2()
        cls = self.camera_class
        try:
            info = cls.global_camera_info()
        except Exception as exc:
            raise CameraUnavailable(f"libcamera cannot list cameras: {exc}") from None
        if not info:
            raise CameraUnavailable("no CSI camera found; check the ribbon cable and that the camera is "
                                    "enabled (rpicam-hello --list-cameras), or run with --sim / --replay FILE")
        if self.settings.camera_num >= len(info):
            raise CameraUnavailable(f"[camera] camera_num = {self.settings.camera_num} but only {len(info)} "
                                    "camera(s) found")
        try:
            self.cam = cls(self.settings.camera_num)
        except (RuntimeError, IndexError, OSError) as exc:
            raise CameraUnavailable(f"camera {self.settings.camera_num} cannot be opened ({exc}); is another "
                                    "process (rpicam-vid, a second crawlerd) using it?") from None
        try:
            self._configure()
        except Exception:
            self._close()
            raise
        return self

    def _configure(self):
        cam = self.cam
        props = cam.camera_properties
        self.model = str(props.get("Model", "unknown"))
        active = props.get("PixelArrayActiveAreas") or [(0, 0) + tuple(props["PixelArraySize"])]
        active_size = tuple(active[0][2:])
        c = self.settings
        fov = (c.sensor_hfov_deg, c.sensor_vfov_deg) if c.sensor_hfov_deg else SENSOR_FOV_DEG.get(self.model)
        if self.calibration is not None:
            if (self.calibration.width, self.calibration.height) != tuple(active_size):
                raise BadConfig(
                    f"[camera] calibration is for {self.calibration.width}x{self.calibration.height} but the "
                    f"{self.model}'s active array is {active_size[0]}x{active_size[1]}; calibrate at full "
                    "sensor resolution")
            fov = self.calibration
        if fov is None:
            raise BadConfig(f"camera model {self.model!r} has no known field of view; set [camera] "
                            "sensor_hfov_deg and sensor_vfov_deg (or a calibration file)")
        modes = cam.sensor_modes            # reconfigures the camera: read before configure()
        self._active_size, self._fov = active_size, fov
        self.plan = self._with_readout(plan_window(
            modes, active_size, c.sensor_window, self.output_size, c.fps, fov,
            lambda size: vblank_lines(self.model, size), hflip=c.hflip, vflip=c.vflip))
        p = self.plan
        d = p.frame_duration_us
        controls = {"FrameDurationLimits": (d, d), "ExposureTime": c.exposure_us,
                    "AnalogueGain": c.analogue_gain, "ScalerCrop": p.scaler_crop}
        kw = dict(raw=None, sensor={"output_size": tuple(p.mode["size"]), "bit_depth": p.mode["bit_depth"]},
                  controls=controls, buffer_count=4)
        main = {"size": p.output_size, "format": "YUV420"}
        try:
            # picamera2 >= 0.3.23 would otherwise centre an aspect-preserving crop over our window
            config = cam.create_video_configuration(main=dict(main, preserve_ar=False), **kw)
        except ValueError:     # an older picamera2 has no preserve_ar
            config = cam.create_video_configuration(main=main, **kw)
        cam.configure(config)
        cam.start()
        self._check_crop()
        self.description = (f"{self.description} {self.model} mode {p.mode['size'][0]}x{p.mode['size'][1]} "
                            f"crop {list(self.plan.scaler_crop)} -> {p.output_size[0]}x{p.output_size[1]} "
                            f"@ {p.fps:.1f} fps")
        _log.info("%s", self.description)

    def _check_crop(self):
        """Metres are only right for the crop the ISP really applies: read it back from a frame."""
        request = self._capture()
        try:
            actual = tuple(int(v) for v in request.get_metadata().get("ScalerCrop", self.plan.scaler_crop))
        finally:
            request.release()
        if actual != tuple(self.plan.scaler_crop):
            p = self.plan
            _log.warning("camera applied ScalerCrop %s instead of %s; intrinsics follow the camera",
                         list(actual), list(p.scaler_crop))
            self.plan = self._with_readout(plan_for_mode(
                p.mode, actual, self._active_size, p.output_size, p.fps, self._fov, p.line_time_s,
                self.settings.hflip, self.settings.vflip))

    def _with_readout(self, plan: WindowPlan) -> WindowPlan:
        """[camera] readout_ms, when set, overrides the readout computed from the sensor mode."""
        given = self.settings.readout_s
        if given is None or abs(given - plan.camera.readout_s) < 1e-9:
            return plan
        _log.warning("[camera] readout_ms = %g overrides the %.3f ms the sensor mode gives; remove the "
                     "key to use the computed one", given * 1000, plan.camera.readout_s * 1000)
        return replace(plan, camera=replace(plan.camera, readout_s=given))

    def _capture(self):
        try:
            return self.cam.capture_request(wait=self.settings.capture_timeout_s)
        except TimeoutError:
            # the timed-out job would later hold a buffer nobody releases (picamera2 keeps it queued)
            try:
                self.cam.cancel_all_and_flush()
            except Exception:
                _log.debug("cancel_all_and_flush failed", exc_info=True)
            raise CameraStalled(f"camera delivered no frame for {self.settings.capture_timeout_s:g} s") from None

    def frames(self):
        """Y-plane views, valid until the next frame: with a MappedArray class they are the camera's
        own buffer (no copy), released back to the camera when the consumer asks for the next."""
        w, h = self.output_size
        t0, n, period_ns = None, 0, 1000 * self.plan.frame_duration_us
        while True:
            request = self._capture()
            try:
                md = request.get_metadata()
                ts = md.get("SensorTimestamp")
                if ts is None:
                    raise CrawlerError("camera metadata carries no SensorTimestamp")
                # SensorTimestamp marks the start of readout; the frame's time is the middle of its
                # top row's exposure (docs/conventions.md)
                t_ns = ts + self.plan.top_row_s * 1e9 - md.get("ExposureTime", self.settings.exposure_us) * 500.0
                if t0 is None:
                    t0 = self.origin_ns = t_ns
                    self.first_sensor_ns = ts
                else:       # numbered as the sensor counts: frames the camera dropped leave a gap
                    n += max(1, round((ts - self.last_sensor_ns) / period_ns))
                self.last_sensor_ns = ts
                if self.mapped_array is not None:
                    with self.mapped_array(request, "main", write=False) as mapped:
                        yield Frame(n, (t_ns - t0) / 1e9, mapped.array[:h, :w])
                else:
                    yield Frame(n, (t_ns - t0) / 1e9, request.make_array("main")[:h, :w])
            finally:
                request.release()

    def _close(self):
        cam, self.cam = self.cam, None
        if cam is not None:
            try:
                cam.stop()
            finally:
                cam.close()

    def __exit__(self, *exc):
        self._close()

