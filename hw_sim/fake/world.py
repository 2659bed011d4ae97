"""The pipe run the fake cameras film: a SimConfig, a clock and the ground truth."""
from __future__ import annotations

import contextlib
import math
import time
from dataclasses import replace

from ..config import SimConfig
from ..motion import Motion
from ..render import Simulator
from .sensors import SENSORS


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
