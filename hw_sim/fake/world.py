"""The pipe run the fake cameras film: a SimConfig, a clock and the ground truth."""
from __future__ import annotations

import math
import time
from dataclasses import replace

import numpy as np

from ..config import SimConfig
from ..light import led_light
from ..motion import Motion
from ..pose import PoseModel
from ..render import Simulator
from ..texture import hash_uniform
from .sensors import SENSORS
from .timeline import FrameCounts


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
                 sleep=time.sleep, start_ns: int | None = None, render_ahead: bool | None = None, **fields):
        self.sensor = SENSORS[sensor] if isinstance(sensor, str) else sensor
        self.sim = replace(sim or SimConfig(duration_s=24 * 3600.0), **fields)
        (aw, ah), (hf, vf) = self.sensor.active[2:], self.sensor.fov_deg
        replace(self.sim, width=aw, height=ah, hfov_deg=hf, vfov_deg=vf, window=None,
                output_size=(640, 480))     # checks the mount against this lens
        s = self.sim
        self.motion = Motion(s.profile, s.speed_m_s, s.duration_s, s.accel_m_s2, s.stopgo_period_s,
                             s.stopgo_dwell_s)
        self.poses = PoseModel(s, self.motion)
        self.clock, self.sleep = clock, sleep
        # a camera thread renders ahead on the wall clock; an injected clock renders on demand
        self.render_ahead = clock is time.monotonic_ns if render_ahead is None else bool(render_ahead)
        self._auto_start = start_ns is None     # then the run starts with the first camera start()
        self.start_ns = self.clock() if start_ns is None else int(start_ns)
        self.connected = True               # False: global_camera_info() is [] (no camera cable)
        self.busy = False                   # a Picamera2 holds the camera
        self.counts = FrameCounts()
        self._stalls: list[list[float]] = []
        self._texture = None

    @property
    def frames_delivered(self) -> int:
        """Requests handed out so far (FrameCounts.delivered)."""
        return self.counts.delivered

    def t_s(self, ns: int) -> float:
        return (ns - self.start_ns) / 1e9

    def true_distance_m(self, sensor_timestamp_ns: int) -> float:
        """Distance travelled since start_ns at the instant of a SensorTimestamp (a frame's start):
        0 at the first frame unless start_ns was given, like the crawler's own count."""
        return float(self.motion.distance(self.t_s(sensor_timestamp_ns)))

    def truth(self, sensor_timestamp_ns: int) -> dict[str, float]:
        """Ground truth at a SensorTimestamp: distance_m, speed_m_s, tilt_deg, camera_height_m (H),
        led_light (1 lit, 0 in a blackout, instantaneous), dropped (1 inside a dropped burst)."""
        t = self.t_s(sensor_timestamp_ns)
        c = self.sim
        return {"distance_m": float(self.motion.distance(t)), "speed_m_s": float(self.motion.speed(t)),
                "tilt_deg": float(self.poses.tilt_deg(t)), "camera_height_m": float(self.poses.camera_height_m(t)),
                "led_light": float(led_light(t, 0.0, c.led_blackouts, c.blackout_decay_ms / 1000)),
                "dropped": float(any(a <= t < b for a, b in c.dropped_bursts))}

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

    def lost(self, frames: np.ndarray, timestamps: np.ndarray, latency_ns: int) -> np.ndarray:
        """Which frames never complete: their buffer was due during a stall, they started in one of
        SimConfig.dropped_bursts (world time), or drop_prob drew them (from the seed and the frame
        number). Never the first frame of a start() but for a stall."""
        done = timestamps + latency_ns
        gone = np.zeros(len(frames), bool)
        for a, b in self._stalls:
            gone |= (done >= a) & (done < b)
        t = (timestamps - self.start_ns) / 1e9
        for a, b in self.sim.dropped_bursts:
            gone |= (t >= a) & (t < b) & (frames > 0)
        p = self.sim.drop_prob
        if p:
            gone |= (hash_uniform(self.sim.seed, 0xD0, frames, 0) < p) & (frames > 0)
        return gone

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
