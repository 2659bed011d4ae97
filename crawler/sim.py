"""crawlerd --sim: the live camera path on hw_sim's Picamera2 fake, and the simulator's ground truth.

The source is the real Picamera2Source with hw_sim's fake class injected (not patched), so the
window plan, the zero-copy frames and the sensor timestamps are the live path's own. The truth is an
Output the sim source supplies: the true distance on the daemon's footing (same start, and rebased
on an operator reset), in the status and the summary.
"""

from __future__ import annotations

from dataclasses import dataclass

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

    def __post_init__(self):
        if self.profile not in PROFILES:
            raise BadConfig(f"--sim-profile {self.profile!r} must be one of {', '.join(PROFILES)}")
        if self.sensor not in SENSORS:
            raise BadConfig(f"--sim-sensor {self.sensor!r} must be one of {', '.join(SENSORS)}")
        if not all(a < b for a, b in self.featureless):
            raise BadConfig(f"--sim-featureless {list(self.featureless)} must be A:B with A < B in metres, "
                            "e.g. 0.5:0.8")


def make_world(settings: Settings, options: SimOptions, **kw):
    """hw_sim's world for this mount and motion; a bad value is a BadConfig naming the flag."""
    from hw_sim import SimError
    from hw_sim.picamera2_fake import SimWorld

    m = settings.mount
    try:
        return SimWorld(sensor=options.sensor, tilt_deg=m.tilt_deg, speed_m_s=options.speed_m_s,
                        profile=options.profile, seed=options.seed, featureless=options.featureless,
                        pipe_diameter_m=m.pipe_diameter_m, car_width_m=m.car_width_m,
                        offset_m=m.camera_offset_m, camera_height_m=m.height_m, **kw)
    except (SimError, ValueError) as exc:
        flags = {"speed_m_s": "--sim-speed", "tilt_deg": "--sim-tilt (or mount.tilt_deg)"}
        field = getattr(exc, "field", "")
        raise BadConfig(f"simulator: {exc}" + (f"; set {flags[field]}" if field in flags else "")) from None


class SimSource(Picamera2Source):
    """The live camera source on a simulated world; `truth` is its ground-truth output."""

    def __init__(self, settings: Settings, world):
        from hw_sim.picamera2_fake import MappedArray, make_picamera2

        super().__init__(settings.camera, make_picamera2(world), mapped_array=MappedArray, kind="sim")
        self.world = world
        self.truth = SimTruth(self)


class SimTruth(Output):
    """The simulator's true distance on the same footing as the measured one."""

    def __init__(self, source: SimSource):
        self.source = source
        self._base_m = 0.0          # the measured distance when the footing was set
        self._t0_ns = None          # ...and the sensor time then

    def start(self, run):
        self._base_m, self._t0_ns = run.distance_m, None     # a resumed run starts where it was

    def reset(self, run):
        self._base_m, self._t0_ns = 0.0, self.source.last_sensor_ns

    @property
    def distance_m(self) -> float | None:
        src = self.source
        if src.last_sensor_ns is None:
            return None
        t0 = self._t0_ns if self._t0_ns is not None else src.first_sensor_ns
        world = src.world
        return self._base_m + world.true_distance_m(src.last_sensor_ns) - world.true_distance_m(t0)

    def report(self, status):
        if self.distance_m is not None:
            status["sim_true_distance_m"] = round(self.distance_m, 6)

    summarize = report
