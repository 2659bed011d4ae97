"""The service: camera (or recording, or simulator) in, metres out over Zenoh, LEDs under control.

Everything that touches hardware or the network is handed in (source, LEDs, link, notifier, clock),
so tests run this exact loop with hw_sim's fake Picamera2, gpiozero's MockFactory and a loopback
Zenoh peer. The loop owns all state; Zenoh threads only queue commands for it.
"""

from __future__ import annotations

import logging
import math
import time

import numpy as np

from .checkpoint import Checkpoint
from .errors import CrawlerError
from .geometry import check_view, make_projection
from .leds import BrightnessLoop
from .link import CommandQueue
from .odometry import Odometer
from .runner import Pacer, RunStats

_log = logging.getLogger(__name__)


class Daemon:
    """One measurement run of a crawler: open the source, light up, measure, publish, checkpoint."""

    def __init__(self, cfg, source, *, mode: str, leds, link=None, notifier=None,
                 checkpoint: Checkpoint | None = None, truth=None, clock=time.monotonic,
                 brightness: BrightnessLoop | None = None, stop=None, max_frames: int | None = None,
                 sinks=(), realtime: bool = False):
        self.cfg = cfg
        self.source = source
        self.mode = mode                    # "camera" | "replay" | "sim" (and "replay-fallback")
        self.leds = leds
        self.link = link
        self.notifier = notifier
        self.checkpoint = checkpoint
        self.truth = truth                  # sim only: t_sensor_ns -> true distance
        self.clock = clock
        self.brightness = brightness
        self.stop = stop or (lambda: False)
        self.max_frames = max_frames
        self.sinks = list(sinks)
        self.commands = CommandQueue()
        self.pacer = Pacer() if realtime else None
        self.stats = RunStats()
        self.started = 0.0
        self.last_error: str | None = None
        self._fps_window: list[float] = []
        self.odometer: Odometer | None = None
        self._last_pub = -math.inf
        self._last_status = -math.inf
        self._last_est = None
        self._start_distance = 0.0

    # -- geometry -----------------------------------------------------------------------------------

    def _make_odometer(self) -> Odometer:
        cfg = self.cfg
        plan = getattr(self.source, "plan", None)
        if plan is None:          # a recording: the config describes its frames
            g = cfg.geometry()
            return Odometer(g.camera, g.projection, g.roi, cfg.odometry_params())
        mount = cfg.make_mount()
        camera = plan.camera
        roi = (0, 0, camera.width, camera.height)
        check_view(camera, make_projection("cylinder", mount), roi, cfg.odometry["max_incidence_deg"])
        projection = make_projection(cfg.odometry["method"], mount)
        return Odometer(camera, projection, roi, cfg.odometry_params())

    # -- control ------------------------------------------------------------------------------------

    def handle(self, request: dict) -> dict:
        """A control request, run in the frame loop. Raises ValueError for a malformed one."""
        cmd = request.get("cmd")
        if cmd == "reset":
            self.odometer.set_distance(0.0)
            if self.truth is not None and getattr(self.source, "last_sensor_ns", None) is not None:
                self._start_distance = 0.0
                self.source.first_sensor_ns = self.source.last_sensor_ns
            if self.checkpoint:
                self.checkpoint.new_run()
                self.checkpoint.save(self._state())
            _log.info("distance reset by operator; new run %s", self.checkpoint and self.checkpoint.run_id)
            return {"cmd": "reset", "distance_m": 0.0,
                    "run_id": self.checkpoint.run_id if self.checkpoint else None}
        if cmd == "led":
            try:
                level = float(request.get("level"))
            except (TypeError, ValueError):
                raise ValueError(f"led level {request.get('level')!r} must be a number 0..1") from None
            if not 0.0 <= level <= 1.0:
                raise ValueError(f"led level {level} must be between 0 and 1")
            self.leds.set(level)
            return {"cmd": "led", "level": level}
        if cmd == "status":
            return self.status()
        raise ValueError(f"unknown cmd {cmd!r}; use reset, led or status")

    # -- reporting ----------------------------------------------------------------------------------

    @property
    def distance_m(self) -> float:
        return self.odometer.distance if self.odometer else 0.0

    def _state(self) -> dict:
        return {"distance_m": round(self.distance_m, 6), "frames": self.stats.frames}

    def status(self) -> dict:
        now = self.clock()
        win = self._fps_window
        fps = (len(win) - 1) / (win[-1] - win[0]) if len(win) > 1 and win[-1] > win[0] else 0.0
        est = self._last_est
        out = {
            "name": self.cfg.name, "source": self.mode, "source_detail": self.source.description,
            "fps": round(fps, 2), "frames": self.stats.frames,
            "tracks": est.inliers if est else 0, "tracking": bool(est and est.tracking),
            "distance_m": round(self.distance_m, 6),
            "led_level": round(float(self.leds.level), 3),
            "uptime_s": round(now - self.started, 3),
            "last_error": self.last_error or (self.link.last_error if self.link else None),
            "run_id": self.checkpoint.run_id if self.checkpoint else None,
        }
        plan = getattr(self.source, "plan", None)
        if plan is not None:
            out["camera"] = plan.describe()
        true = self.true_distance_m()
        if true is not None:
            out["sim_true_distance_m"] = round(true, 6)
        return out

    def true_distance_m(self) -> float | None:
        """Simulator only: the ground truth on the same footing as distance_m (same start, same run)."""
        src = self.source
        if self.truth is None or getattr(src, "last_sensor_ns", None) is None:
            return None
        return self._start_distance + self.truth(src.last_sensor_ns) - self.truth(src.first_sensor_ns)

    def _publish(self, est, now):
        if self.link is None:
            return
        if now - self._last_pub >= 1.0 / self.cfg.zenoh["publish_hz"]:
            self._last_pub = now
            d = est.as_dict()
            d["name"] = self.cfg.name
            self.link.publish_estimate(d)
        if now - self._last_status >= 1.0 / self.cfg.zenoh["status_hz"]:
            self._last_status = now
            self.link.publish_status(self.status())

    # -- the loop -----------------------------------------------------------------------------------

    def run(self) -> RunStats:
        """Measure until the source ends, stop() is true, or a fault; returns the run's statistics.

        A source that breaks mid-way ends the run with the error recorded in the stats and the status
        (what was measured up to the break is kept). Lights go off, the checkpoint is written and a last
        status is published whatever happens.
        """
        self.started = self.clock()
        self.odometer = self._make_odometer()
        if self.checkpoint:
            saved = self.checkpoint.load()
            if saved:
                self.odometer.reset(distance=saved["distance_m"])
                _log.warning("resuming run %s at %.4f m", self.checkpoint.run_id, saved["distance_m"])
        self._start_distance = self.odometer.distance
        if self.notifier:
            self.notifier.ready(f"measuring from {self.source.description}")
        self.leds.on()
        try:
            for frame in self.source.frames():
                if self.pacer is not None:
                    self.pacer.wait(frame.t_s)
                self._step(frame)
                if self.stop() or (self.max_frames and self.stats.frames >= self.max_frames):
                    break
        except CrawlerError as exc:
            self.last_error = self.stats.error = str(exc)
            _log.debug("run ended: %s", exc)          # the caller reports it, once
        finally:
            self.stats.wall_s = self.clock() - self.started
            self.leds.off()
            if self.checkpoint:
                self.checkpoint.save(self._state())
            if self.link is not None:
                self.link.publish_status(self.status())
            if self.notifier:
                self.notifier.stopping()
        return self.stats

    def _step(self, frame):
        now = self.clock()
        est = self.odometer.update(frame.gray, frame.t_s)
        self._last_est = est
        self.stats.add(est)
        win = self._fps_window
        win.append(now)
        if len(win) > 60:
            del win[0]
        self.commands.drain(self.handle)
        if self.brightness is not None:
            x, y, w, h = self.odometer.roi
            mean = float(np.mean(frame.gray[y:y + h:4, x:x + w:4]))
            self.leds.set(self.brightness.update(self.leds.level, mean))
        for sink in self.sinks:
            sink.write(frame, est, self.odometer)
        self._publish(est, now)
        if self.checkpoint:
            self.checkpoint.maybe_save(self._state())
        if self.notifier:
            self.notifier.watchdog()

    def summary(self) -> dict:
        """The closing JSON line."""
        lateral = self.odometer.lateral if self.odometer else 0.0
        return self.stats.summary(self.distance_m, lateral)
