"""crawlerd --sim: the live camera path on hw_sim's Picamera2 fake, and the simulator's ground truth.

The source is the real Picamera2Source with hw_sim's fake class injected (not patched), so the
window plan, the zero-copy frames and the sensor timestamps are the live path's own. The truth is an
Output the sim source supplies: the true distance on the daemon's footing (same start, and rebased
on an operator reset), in the status and the summary.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

from .camera import Picamera2Source
from .errors import BadConfig
from .ports import Output
from .settings import Settings

PROFILES = ("constant", "accel", "stopgo", "reverse")
SENSORS = ("imx219", "ov5647", "imx708")


@dataclass(frozen=True)
class SimOptions:
    """The simulated run (--sim-* flags). tilt_deg None: the mount's tilt."""

    speed_m_s: float = 0.2
    tilt_deg: float | None = None
    profile: str = "constant"
    sensor: str = "imx219"
    seed: int = 0
    featureless: tuple[tuple[float, float], ...] = ()
    wheel: bool = False                               # a simulated encoder through the kernel backend
    slip: tuple[tuple[float, float], ...] = ()        # s: the wheel turns 20 % faster than the ground
    wheel_scale: float = 1.0                          # true / nominal counts per metre

    def __post_init__(self):
        if self.profile not in PROFILES:
            raise BadConfig(f"--sim-profile {self.profile!r} must be one of {', '.join(PROFILES)}")
        if self.sensor not in SENSORS:
            raise BadConfig(f"--sim-sensor {self.sensor!r} must be one of {', '.join(SENSORS)}")
        if not all(a < b for a, b in self.featureless):
            raise BadConfig(f"--sim-featureless {list(self.featureless)} must be A:B with A < B in metres, "
                            "e.g. 0.5:0.8")
        if not all(0 <= a < b for a, b in self.slip):
            raise BadConfig(f"--sim-slip {list(self.slip)} must be A:B with 0 <= A < B in seconds, e.g. 8:9")
        if not 0.5 <= self.wheel_scale <= 2.0:
            raise BadConfig(f"--sim-wheel-scale {self.wheel_scale:g} must be between 0.5 and 2 (true counts per "
                            "metre over the nominal ones)")


def make_world(settings: Settings, options: SimOptions, **kw):
    """hw_sim's world for this mount and motion; a bad value is a BadConfig naming the flag."""
    from hw_sim import SimError
    from hw_sim.picamera2_fake import SimWorld

    m = settings.mount
    tilt = options.tilt_deg if options.tilt_deg is not None else 0.0 if m.tilt_auto else m.tilt_deg
    try:
        return SimWorld(sensor=options.sensor, tilt_deg=tilt, speed_m_s=options.speed_m_s,
                        profile=options.profile, seed=options.seed, featureless=options.featureless,
                        pipe_diameter_m=m.pipe_diameter_m, car_width_m=m.car_width_m,
                        offset_m=m.camera_offset_m, camera_height_m=m.height_m, **kw)
    except (SimError, ValueError) as exc:
        flags = {"speed_m_s": "--sim-speed", "tilt_deg": "--sim-tilt (or mount.tilt_deg)"}
        field = getattr(exc, "field", "")
        raise BadConfig(f"simulator: {exc}" + (f"; set {flags[field]}" if field in flags else "")) from None


SIM_COUNTS_PER_M = 5000.0            # the simulated encoder: edges per metre (x4 decoding)


class SimClock:
    """The simulated world's epoch and the run's origin, kept in the state directory: the crawler
    goes on moving while a killed daemon is down, and the truth still counts from the run's start."""

    def __init__(self, directory: str | Path, now_ns: int):
        self.path = Path(directory) / "sim.json"
        try:
            data = json.loads(self.path.read_text())
            epoch, origin = int(data["epoch_ns"]), data.get("origin_ns")
            if not 0 < epoch <= now_ns:         # another boot (the monotonic clock restarted)
                raise ValueError
        except (OSError, ValueError, KeyError, TypeError):
            epoch, origin = now_ns, None
        self.epoch_ns, self.origin_ns = epoch, origin
        self.save()

    def save(self):
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self.path.write_text(json.dumps({"epoch_ns": self.epoch_ns, "origin_ns": self.origin_ns}))
        except OSError:
            pass                                # the checkpoint output reports the state directory


class SimSource(Picamera2Source):
    """The live camera source on a simulated world; `truth` is its ground-truth output."""

    def __init__(self, settings: Settings, world, clock: SimClock | None = None):
        from hw_sim.picamera2_fake import MappedArray, make_picamera2

        super().__init__(settings.camera, make_picamera2(world), mapped_array=MappedArray, kind="sim")
        self.world = world
        self.sensor_clock_ns = world.clock
        self.truth = SimTruth(self, clock)
        self.sensor_ns: dict[int, int] = {}     # SensorTimestamp of the recent frames, by index

    def frames(self):
        """The camera's frames, remembering each one's SensorTimestamp: a loop that measures frames a
        few behind the camera ([odometry] workers) gets the truth of the frame it measured."""
        for frame in super().frames():
            self.sensor_ns[frame.index] = self.last_sensor_ns
            if len(self.sensor_ns) > 64:
                del self.sensor_ns[next(iter(self.sensor_ns))]
            yield frame

    def encoder_device(self, options: SimOptions):
        """The kernel rotary-encoder device of the simulated wheel (hw_sim's fake evdev device),
        counting from the world's epoch as the driver counts from boot."""
        from hw_sim.encoder import FakeInputDevice, SimEncoder

        world = self.world
        encoder = SimEncoder(lambda t: world.motion.distance(t), counts_per_m=SIM_COUNTS_PER_M,
                             scale=options.wheel_scale, slip=options.slip,
                             clock=lambda: world.t_s(world.clock()), t_boot=0.0, seed=options.seed)
        return FakeInputDevice(encoder, absolute=True, name="sim-rotary")


class SimTruth(Output):
    """The simulator's true distance on the same footing as the measured one: from the run's origin
    (kept across restarts by SimClock), or from the first frame of a resumed run without one."""

    def __init__(self, source: SimSource, clock: SimClock | None = None):
        self.source, self.clock = source, clock
        self._base_m = 0.0          # the measured distance when the footing was set
        self._t0_ns = clock.origin_ns if clock else None
        self._last_ns = None        # SensorTimestamp of the frame measured last

    def start(self, run):
        if self._t0_ns is None:     # no origin kept: a resumed run starts where it was
            self._base_m = run.distance_m

    def write(self, frame, estimate, run):
        self._last_ns = self.source.sensor_ns.get(frame.index, self.source.last_sensor_ns)
        if self._t0_ns is None:
            self._t0_ns = self.source.first_sensor_ns
            if self.clock is not None:
                self.clock.origin_ns = self._t0_ns
                self.clock.save()

    def reset(self, run):
        self._base_m, self._t0_ns = 0.0, self._last_ns or self.source.last_sensor_ns
        if self.clock is not None:
            self.clock.origin_ns = self._t0_ns
            self.clock.save()

    @property
    def distance_m(self) -> float | None:
        if self._last_ns is None or self._t0_ns is None:
            return None
        world = self.source.world
        return self._base_m + world.true_distance_m(self._last_ns) - world.true_distance_m(self._t0_ns)

    def report(self, status):
        if self.distance_m is not None:
            status["sim_true_distance_m"] = round(self.distance_m, 6)

    summarize = report
