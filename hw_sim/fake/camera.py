"""FakePicamera2: picamera2.Picamera2 on a SimWorld."""
from __future__ import annotations

import contextlib
import math
import threading
from dataclasses import replace

import numpy as np

from ..render import Simulator
from .configs import (AF_CONTROLS, CONTROLS, NR_FAST, NR_HIGH_QUALITY, NR_MINIMAL, check_config, fill_stride,
                      mode_score, stream_config)
from .crop import default_isp_crop, isp_crop, native_crop
from .pump import AHEAD_S, PREFETCH_S, FrameJob, RenderAhead, RenderNow
from .request import CompletedRequest
from .sensors import EXPOSURE_MIN_LINES, FRAME_LINES_MAX, ISP_MIN_CROP, REF_EXPOSURE, SensorFormat, Transform
from .timeline import FrameQueue, FrameSettings, Timeline
from .world import SimWorld

PREFETCH_STEP_S = 0.05     # world time between two tile prefetches of the camera thread
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
        self._sims_lock, self._renderer = threading.Lock(), RenderNow(self._simulator)
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
        c = CONTROLS | (AF_CONTROLS if self.camera.model == "imx708" else {})
        m = self._mode
        if m is None:                       # the IPA's defaults until a mode is configured
            return c | {"ExposureTime": (1, 66666, 20000), "AnalogueGain": (1.0, 16.0, 1.0),
                        "FrameDurationLimits": (33333, 250000000, (33333, 33333)),
                        "ScalerCrop": ((0, 0, 0, 0), (65535, 65535, 65535, 65535), (0, 0, 0, 0))}
        ln = m.line_us
        return c | {"ExposureTime": (int(EXPOSURE_MIN_LINES * ln), int((FRAME_LINES_MAX - 4) * ln), 20000),
                    "AnalogueGain": (1.0, self.camera.max_gain, 1.0),
                    "FrameDurationLimits": (int(m.min_lines * ln), int(FRAME_LINES_MAX * ln), (33333, 33333)),
                    "ScalerCrop": (native_crop((0, 0) + ISP_MIN_CROP, m), m.crop,
                                   native_crop(self._default_isp, m))}

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
        main = stream_config({"format": fmt, "size": size, "preserve_ar": True}, a["main"])
        cs = a["colour_space"] or ("Smpte170m" if main["size"][0] < 1280 or main["size"][1] < 720 else "Rec709")
        c = {"use_case": a["use_case"], "transform": a["transform"] or Transform(), "colour_space": cs,
             "buffer_count": a["buffer_count"], "queue": a["queue"], "main": main,
             "lores": stream_config({"format": "YUV420", "size": main["size"], "preserve_ar": False}, a["lores"]),
             "raw": stream_config({"format": self.sensor_format, "size": main["size"]}, a["raw"], raw=True),
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
        check_config(c)
        sensor, raw = c.get("sensor") or {}, c["raw"]
        depth = sensor.get("bit_depth") or SensorFormat(raw["format"] if raw else self.sensor_format).bit_depth
        size = sensor.get("output_size") or (raw["size"] if raw else c["main"]["size"])
        best = min(self._raw_modes, key=lambda r: mode_score(r, depth, size))
        mode = next(m for m in self.camera.modes if m.size == best["size"])
        ctl = self._checked(c["controls"])
        if raw is not None:
            raw["format"], raw["size"] = SensorFormat(best["format"]).format, mode.size
        for st in (c["main"], c["lores"], raw):
            if st is not None:
                fill_stride(st)
        c["sensor"] = {"bit_depth": SensorFormat(best["format"]).bit_depth, "output_size": mode.size}
        largest = max((c[n]["size"] for n in ("main", "lores") if c[n]), key=lambda s: s[0] * s[1])
        self._mode, self._out, self._default_isp = mode, c["main"]["size"], default_isp_crop(mode, largest)
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
                q, now = self._frames, self.world.clock()
                q.advance(now)
                k = q.timeline.k_at(now) + 1
                q.timeline.change(k, self._resolve(self._ctl), q.keep_from())
                self._renderer.retarget(k)

    def _resolve(self, ctl: dict) -> FrameSettings:
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
        isp = isp_crop(ctl["ScalerCrop"], m) if "ScalerCrop" in ctl else self._default_isp
        return FrameSettings(native_crop(isp, m), e, round(g, 6), int(round(lines * ln * 1000)))

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
            sim, t = self._simulator(st), 0.0 if w._auto_start else w.t_s(w.clock())
            sim.render(t)                   # the tiles of the first PREFETCH_S, before the clock runs
            for i in range(int(PREFETCH_S / PREFETCH_STEP_S) + 1):
                sim.prefetch(t + i * PREFETCH_STEP_S)
            if w._auto_start:
                w.start_ns, w._auto_start = w.clock(), False
            latency = int(self._mode.size[1] * self._mode.line_us * 1000)   # frame start -> buffer done
            self._frames = FrameQueue(Timeline(w.clock(), st), latency, self.camera_config["buffer_count"],
                                      self._queue, lambda ks, ts: w.lost(ks, ts, latency), w.counts)
            self._renderer = (RenderAhead(self._simulator, self._next_render, w.counts, self._prefetch) if w.render_ahead
                              else RenderNow(self._simulator))
            self._prefetched_t, self.started = -math.inf, True

    def stop(self) -> None:
        if self.started:
            with self._lock:
                self.started = False
                self.stop_count += 1
            self._renderer.stop()

    def close(self) -> None:
        if self.is_open:
            self.stop()
            self.world.busy, self.is_open, self.camera = False, False, None
            self.camera_config, self._sims = {}, {}

    def cancel_all_and_flush(self) -> None:
        """Forget timed-out captures (picamera2 leaves them queued: each would take a frame)."""
        with self._lock:
            if self.started:
                self._frames.orphans = 0

    @property
    def buffers_in_use(self) -> int:
        """Buffers the application and picamera2's latest-request slot hold (<= buffer_count)."""
        return self._frames.in_use if self.started else 0

    def _next_frame(self, timeout_s, flush) -> int:
        """Block until a frame is ours: the latest completed one (queue) or the next to complete."""
        w = self.world
        deadline = None if timeout_s is None else w.clock() + int(timeout_s * 1e9)
        waiter = None
        while True:
            with self._lock:
                now = w.clock()
                if self.started:
                    q = self._frames
                    q.advance(now)
                    k = waiter.frame if waiter is not None else q.take_kept(flush)
                    if k is not None:
                        return k
                    waiter = waiter or q.wait(flush)
                    due = q.completion_ns(q.next_k)
                elif deadline is None:
                    raise RuntimeError("the camera is not started: picamera2 would wait forever")
                else:
                    due = now + 10**7
                if deadline is not None and now >= deadline:
                    if self.started:
                        q.give_up(waiter)
                    raise TimeoutError(f"no frame within {timeout_s:g} s")
            w.sleep(max(min(due, deadline or due) - now, 100_000) / 1e9)

    def _job(self, k: int) -> FrameJob:
        st, m = self._frames.timeline.settings(k), self._mode
        row0 = (st.crop[1] - m.crop[1]) * m.size[1] / m.crop[3]       # the window's top row in the mode
        t = self.world.t_s(self._frames.timeline.ts(k)) + (row0 * m.line_us - st.exposure_us / 2) / 1e6
        return FrameJob(k, st, t, st.exposure_us * st.gain / REF_EXPOSURE)

    def _next_render(self, after: int) -> tuple[FrameJob | None, float]:
        """For the camera thread: the next frame after `after` that will (or just did) complete, if
        it completes within AHEAD_S; else how long to wait."""
        with self._lock:
            if not self.started:
                return None, 0.01
            q, now = self._frames, self.world.clock()
            k = max(after + 1, q.timeline.k_at(now - q.latency_ns), q.next_k - 1, 0)
            for _ in range(64):             # skip frames that will never complete
                ts = q.timeline.ts(k)
                if not self.world.lost(np.array([k]), np.array([ts]), q.latency_ns)[0]:
                    break
                k += 1
            early = (ts + q.latency_ns - now) / 1e9 - AHEAD_S
            return (self._job(k), 0.0) if early <= 0 else (None, min(early, 0.05))

    def _prefetch(self) -> None:
        """For the camera thread when idle: the texture tiles of the view PREFETCH_S ahead."""
        with self._lock:
            if not self.started:
                return
            now, tl = self.world.clock(), self._frames.timeline
            t = self.world.t_s(now) + PREFETCH_S
            if t < self._prefetched_t + PREFETCH_STEP_S:
                return
            st = tl.settings(tl.k_at(now) + 1)
        if self._simulator(st).prefetch(t, budget=1):    # one tile at a time: frames come first
            self._prefetched_t = t

    def capture_request(self, wait=None, signal_function=None, flush=None) -> "CompletedRequest":
        """The newest completed frame not yet returned, else the next one. wait None/True: block;
        seconds: TimeoutError (concurrent.futures.TimeoutError is the builtin on 3.11)."""
        if wait is False or (wait is None and signal_function is not None):
            raise NotImplementedError("the fake offers blocking captures only (wait=None, True or seconds)")
        k = self._next_frame(None if wait in (None, True) else float(wait),
                             self.world.clock() if flush is True else flush)
        with self._lock:
            job, ts = self._job(k), self._frames.timeline.ts(k)
            self.world.counts.delivered += 1
        st = job.settings
        md = {"SensorTimestamp": ts, "ScalerCrop": st.crop, "ExposureTime": st.exposure_us,
              "AnalogueGain": st.gain, "DigitalGain": 1.0, "FrameDuration": int(round(st.period_ns / 1000)),
              "ColourGains": (1.8, 1.6), "ColourTemperature": 4500, "Lux": 400.0, "AeLocked": True,
              "SensorBlackLevels": (4096, 4096, 4096, 4096), "FocusFoM": 1000,
              "ColourCorrectionMatrix": (1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0)}
        return CompletedRequest(self, md, job)

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

    def _simulator(self, st: FrameSettings) -> Simulator:
        """hw_sim's camera for these settings: the active array with the lens FOV, cropped to the
        effective ScalerCrop, scaled to main, this exposure, and the window's readout time."""
        m, s = self._mode, self.camera
        key = (st.crop, self._out, st.exposure_us, st.period_ns)
        with self._sims_lock:
            if key not in self._sims:
                rows = st.crop[3] * m.size[1] / m.crop[3]
                cfg = replace(self.world.sim, width=s.active[2], height=s.active[3], hfov_deg=s.fov_deg[0],
                              vfov_deg=s.fov_deg[1], window=st.crop, output_size=self._out,
                              fps=1e9 / st.period_ns, exposure_ms=st.exposure_us / 1000,
                              readout_ms=max(rows - 1, 0) * m.line_us / 1000, drop_prob=0.0)
                if len(self._sims) >= 4:
                    self._sims.pop(next(iter(self._sims)))
                self._sims[key] = self.world.simulator(cfg)
            return self._sims[key]

    def _pixels(self, job: FrameJob) -> np.ndarray:
        return self._renderer.pixels(job)

    def _released(self, request: "CompletedRequest") -> None:
        with self._lock:
            if request.stop_count == self.stop_count and self.started:
                self._frames.advance(self.world.clock())
                self._frames.release()


def make_picamera2(world: SimWorld) -> type:
    """A Picamera2 class bound to `world` (what crawlerd injects in place of picamera2's)."""
    return type("Picamera2", (FakePicamera2,), {
        "world": world, "__module__": "hw_sim.picamera2_fake", "global_camera_info": staticmethod(world.camera_info)})
