"""The composition root: settings and run options in, every part built, run, and closed in reverse.

This is the one place that knows which parts a run has. The camera (or its fallback recording), the
simulator or a recording; LEDs or none; the outputs (Zenoh, log, annotated video, progress,
checkpoint, watchdog, auto-brightness, the simulator's truth); the measurement model from the
camera the source delivers. `contextlib.ExitStack` closes whatever was opened, in reverse order,
whatever fails. Tests build the daemon through this same class, with fakes injected through
`Hardware`.
"""

from __future__ import annotations

import enum
import logging
import tempfile
import time
from contextlib import ExitStack
from dataclasses import dataclass, field, replace
from pathlib import Path

from .checkpoint import Checkpoint, CheckpointOutput
from .codec import CodecBias
from .daemon import Daemon
from .distance import DistanceChain
from .gaps import GapBridge
from .errors import CameraUnavailable
from .errors import BadConfig
from .inspection import Inspection
from .leds import AutoBrightness, BrightnessLoop, Leds, NoLeds, pwm_exposure_us
from .commands import CommandQueue
from .link import ZenohLink, ZenohOutput
from .measurement import bridge_params, build_odometer, describe, recording_camera, thesis_roi
from .outputs import Annotator, JsonlLog, Progress
from .sdnotify import Notifier, WatchdogOutput
from .settings import Settings
from .sim import SIM_COUNTS_PER_M, SimClock, SimOptions, SimSource, make_world
from .stats import RunStats
from .zenoh_config import check_zenoh_config, command_access

_log = logging.getLogger("crawlerd")
SIM_PINS = (12, 13)                 # --sim lights mock LEDs on these when [leds] pins is empty
SIM_STATE_DIR = Path(tempfile.gettempdir()) / "crawlerd-sim"


class Mode(enum.Enum):
    CAMERA = "camera"     # the CSI camera (systemd runs this)
    SIM = "sim"           # the same daemon on hw_sim's fake camera and mock pins
    REPLAY = "replay"     # a recording


@dataclass(frozen=True)
class RunOptions:
    """What the command line says about this run, beyond the settings."""

    mode: Mode = Mode.CAMERA
    video: str | None = None            # replay
    pts: str | None = None
    fps: float | None = None
    realtime: bool = False
    publish: bool | None = None         # None: the live modes publish, a replay does not
    log: str | None = None
    annotate: str | None = None
    max_frames: int | None = None
    sim: SimOptions = field(default_factory=SimOptions)

    @property
    def publishes(self) -> bool:
        return self.mode is not Mode.REPLAY if self.publish is None else self.publish


@dataclass
class Hardware:
    """The ports a test (or --sim) injects: camera class, GPIO pin factory, systemd notifier, clock."""

    camera_class: type | None = None
    mapped_array: type | None = None
    pin_factory: object = None
    notifier: Notifier | None = None
    clock: object = time.monotonic
    world: object = None                # --sim: a prepared hw_sim SimWorld (tests keep a handle)


class Service:
    """One run of crawlerd, from settings to summary: `with Service(...) as svc: svc.run()`."""

    def __init__(self, settings: Settings, options: RunOptions, hardware: Hardware | None = None,
                 stop=lambda: False):
        self.settings, self.options = settings, options
        self.hw = hardware or Hardware()
        self.stop = stop
        self.mode = options.mode
        self.commands = CommandQueue()
        self.daemon: Daemon | None = None

    # -- building ---------------------------------------------------------------------------------------

    def __enter__(self) -> "Service":
        self._stack = ExitStack()
        try:
            self._build(self._stack)
        except BaseException:
            self._stack.close()
            raise
        return self

    def __exit__(self, *exc):
        """Close everything; a file that cannot be finished (a full disk) is recorded as the run's error
        instead of hiding the summary."""
        from .errors import CrawlerError

        try:
            self._stack.close()
        except CrawlerError as err:
            if self.daemon is None or exc[0] is not None:
                raise
            self.daemon.stats.error = self.daemon.stats.error or str(err)

    def _build(self, stack: ExitStack):
        self.settings = s = pwm_aligned(sim_wheel(self.settings, self.options), self.mode)
        self.store = None if self.mode is Mode.REPLAY else Checkpoint(s.state.directory)
        resume = self.store.load() if self.store else None
        self.source = self._open_source(resume)
        stack.push(self.source)         # entered already (so a camera can fall back): register its exit
        self.odometer = build_odometer(s, self.source.camera, self.source.default_roi)
        self.pool = stack.enter_context(self._pool()) if s.odometry.workers > 1 else None
        self.leds = stack.enter_context(self._leds())
        self.wheel = stack.enter_context(self._wheel())
        outputs = [stack.enter_context(out) for out in self._outputs()]
        fresh = Inspection(unit=s.inspection.unit, direction=s.inspection.direction)
        self.daemon = Daemon(self.source, self.odometer, name=s.name, leds=self.leds, outputs=outputs,
                             commands=self.commands, resume=resume, inspection=fresh,
                             chain=self._chain(resume), wheel=self.wheel, restart=self._restart(resume),
                             clock=self.hw.clock, stop=self.stop, max_frames=self.options.max_frames,
                             measure=self.pool.measure if self.pool else None)

    def _pool(self):
        """[odometry] workers > 1: tracking processes, forked before Zenoh opens its threads."""
        from .workers import TrackerPool

        cam = self.source.camera
        return TrackerPool(self.odometer, (cam.height, cam.width), self.settings.odometry.workers)

    def _restart(self, resume: dict | None):
        """A resumed run's downtime, with the frame to measure it against when one was saved."""
        if not resume:
            return None
        from .restart import RestartGap

        meta = resume.get("reference")
        img = self.store.load_reference(meta, self.odometer.roi) if meta else None
        ref = None if img is None else (img, meta["distance_m"], meta["lateral_m"])
        down = time.time() - resume["saved_unix_s"] if isinstance(resume.get("saved_unix_s"), (int, float)) else 0.0
        return RestartGap(down, resume["distance_m"], ref, wheel=self.settings.wheel.enabled)

    def _chain(self, resume: dict | None) -> DistanceChain:
        """Bridging and, with a wheel, the fusion; resumed from the checkpoint's sigma and wheel state."""
        resume = resume or {}
        bridge = GapBridge(bridge_params(self.settings, self.odometer), distance_m=resume.get("distance_m", 0.0),
                           sigma_m=resume.get("sigma_m") or 0.0)
        if resume.get("drive") is not None:
            try:
                bridge.drive.restore(resume["drive"])
            except ValueError as exc:
                _log.error("the checkpoint's %s; the drive's rates are learnt afresh", exc)
        codec = CodecBias(self.odometer.m_per_px)
        w = self.settings.wheel
        if not w.enabled:
            return DistanceChain(bridge, codec=codec)
        from .wheel import WheelFusion

        fusion = WheelFusion(w.fusion_params(), distance_m=resume.get("distance_m", 0.0))
        if resume.get("wheel"):
            try:
                fusion = WheelFusion.from_dict(resume["wheel"], w.fusion_params())
            except ValueError as exc:
                _log.error("the checkpoint's wheel state is unreadable (%s); the wheel starts afresh", exc)
        return DistanceChain(bridge, fusion, codec)

    def _wheel(self):
        from .wheel import open_wheel

        w = self.settings.wheel
        if not w.enabled:
            return open_wheel(w)
        hardware = {"pin_factory": self.hw.pin_factory} if w.backend == "gpiozero" else {}
        if isinstance(self.source, SimSource) and self.options.sim.wheel:
            device = self.source.encoder_device(self.options.sim)
            hardware = {"opener": lambda name: device, "boot_id": lambda: f"sim-{self.source.world.start_ns}"}
        return open_wheel(w, clock=self.source.clock_s, **hardware)

    def _open_source(self, resume):
        """The frame source, entered; a camera that cannot open falls back to [camera] fallback_video."""
        o, c = self.options, self.settings.camera
        if self.mode is Mode.REPLAY:
            return _entered(self._replay(o.video, o.pts, o.fps, o.realtime))
        if self.mode is Mode.SIM:
            clock = None
            if self.hw.world is None:           # the world goes on from its epoch while we are down
                clock = SimClock(self.settings.state.directory, time.monotonic_ns())
                if resume is None:
                    clock.origin_ns = None      # a new run: the truth counts from its first frame
                self.hw.world = make_world(self.settings, o.sim, start_ns=clock.epoch_ns)
            return _entered(SimSource(self.settings, self.hw.world, clock))
        from .camera import Picamera2Source

        try:
            return _entered(Picamera2Source(c, self.hw.camera_class, mapped_array=self.hw.mapped_array))
        except CameraUnavailable as exc:
            if not c.fallback_video:
                raise
            _log.error("CAMERA UNAVAILABLE (%s); FALLING BACK TO RECORDING %s", exc, c.fallback_video)
            source = _entered(self._replay(c.fallback_video, c.fallback_pts, c.fallback_fps, False,
                                           kind="replay-fallback"))
            source.description = f"FALLBACK {source.description} (camera: {exc})"
            return source

    def _replay(self, video, pts, fps, realtime, kind="replay"):
        from .video import VideoReplay

        camera = recording_camera(self.settings.camera)
        return VideoReplay(video, camera, pts=pts, fps=fps, realtime=realtime, kind=kind,
                           default_roi=thesis_roi(camera.width, camera.height))

    def _leds(self):
        pins = self.settings.leds.pins
        factory = self.hw.pin_factory
        if self.mode is Mode.SIM:
            pins = pins or SIM_PINS
            if factory is None:
                from gpiozero.pins.mock import MockFactory, MockPWMPin

                factory = MockFactory(pin_class=MockPWMPin)
        if not pins or self.source.kind.startswith("replay"):
            return NoLeds()
        led = self.settings.leds
        return Leds(pins, brightness=led.brightness, frequency_hz=led.frequency_hz,
                    active_high=led.active_high, pin_factory=factory)

    def _outputs(self) -> list:
        s, o = self.settings, self.options
        outs = []
        if o.log:
            outs.append(JsonlLog(o.log))
        if o.annotate:
            fps = o.fps or (30.0 if self.mode is Mode.REPLAY else s.camera.fps)
            outs.append(Annotator(o.annotate, self.odometer, fps=fps, pipe_id=s.inspection.pipe_id))
        outs.append(Progress())
        if self.pool is not None:
            from .workers import WorkersReport

            outs.append(WorkersReport(self.pool))
        if isinstance(self.source, SimSource):
            outs.append(self.source.truth)
        if s.leds.auto_brightness:
            outs.append(AutoBrightness(self.leds, self.odometer.roi, BrightnessLoop(target=s.leds.target_grey)))
        if self.store is not None:
            outs.append(CheckpointOutput(self.store, s.state.checkpoint_s, clock=self.hw.clock))
        if self.mode is not Mode.REPLAY:
            outs.append(WatchdogOutput(self.hw.notifier or Notifier(), lambda: self.source.description))
        if o.publishes:
            conf, access = zenoh_setup(s)
            link = ZenohLink(s.name, conf, self.commands)
            outs.append(ZenohOutput(link, s.zenoh.publish_hz, s.zenoh.status_hz, clock=self.hw.clock,
                                    control=access))
            if s.ros2.enabled:
                from .ros2 import Ros2Output

                r = s.ros2
                outs.append(Ros2Output(link, s.name, r.domain_id, r.topic, r.distro, s.zenoh.publish_hz,
                                       clock=self.hw.clock))
        return outs

    # -- running ----------------------------------------------------------------------------------------

    def run(self) -> RunStats:
        return self.daemon.run()

    def summary(self) -> dict:
        out = self.daemon.summary()
        out.update(source=self.source.description, method=self.settings.odometry.method)
        if self.source.warnings:
            out["warnings"] = list(self.source.warnings)
        return out


def _entered(source):
    """Enter a source outside the ExitStack, so a CameraUnavailable can fall back before anything
    is registered; the caller pushes its __exit__."""
    source.__enter__()
    return source


def zenoh_setup(settings: Settings):
    """The zenoh config, checked (a config error is exit 2, never a retry loop), and who may command."""
    conf = settings.zenoh.zenoh_config()
    check_zenoh_config(conf)
    access = command_access(conf, settings.name)
    if access == "open":
        from .daemon import COMMANDS

        _log.warning("commands (%s) are open to any peer that reaches this crawler: anyone can zero its "
                     "distance or mark observations; give [zenoh] config an access-control policy "
                     "(docs/deploy.md, 'Securing the network')", ", ".join(f"cmd/{c}" for c in COMMANDS))
    return conf, access


def pwm_aligned(settings: Settings, mode: Mode) -> Settings:
    """With dimmed LEDs on the live camera, an exposure of whole PWM periods (leds.py says why)."""
    led, cam = settings.leds, settings.camera
    pins = led.pins or (SIM_PINS if mode is Mode.SIM else ())
    if mode is Mode.REPLAY or not pins or (led.brightness >= 1.0 and not led.auto_brightness):
        return settings
    exposure = pwm_exposure_us(cam.exposure_us, led.frequency_hz)
    if exposure > 1e6 / cam.fps:
        raise BadConfig(f"[leds] frequency_hz = {led.frequency_hz:g}: one PWM period is longer than a frame at "
                        f"[camera] fps = {cam.fps:g}; raise frequency_hz (lgpio takes up to 10000)")
    if exposure != cam.exposure_us:
        _log.warning("[camera] exposure_us = %d is not a whole number of %g Hz PWM periods (the LEDs "
                     "would band the frames); using %d us", cam.exposure_us, led.frequency_hz, exposure)
    return replace(settings, camera=replace(cam, exposure_us=exposure))


def sim_wheel(settings: Settings, options: RunOptions) -> Settings:
    """--sim-wheel: the simulated encoder read through the kernel backend, as on the crawler.
    A replay has no wheel: a recording comes without its encoder counts."""
    if options.mode is Mode.REPLAY and settings.wheel.enabled:
        _log.warning("[wheel] is not used in --replay: a recording has no live encoder counts; the "
                     "distance is the camera's alone")
        from .settings import _wheel_settings

        return replace(settings, wheel=_wheel_settings({"backend": "none"}, settings.name))
    if options.mode is not Mode.SIM or not options.sim.wheel or settings.wheel.enabled:
        return settings
    from .settings import _wheel_settings

    wheel = _wheel_settings({"backend": "evdev", "device": "sim-rotary", "counts_per_m": SIM_COUNTS_PER_M},
                            settings.name)
    return replace(settings, wheel=wheel)


def sim_settings(settings: Settings, options: RunOptions, state_dir_given: bool) -> Settings:
    """--sim: the simulated car's tilt is the mount's, and its checkpoint never the real run's."""
    if options.sim.tilt_deg is not None and not settings.mount.tilt_auto:
        settings = replace(settings, mount=replace(settings.mount, tilt_deg=options.sim.tilt_deg))
    if not state_dir_given:
        settings = replace(settings, state=replace(settings.state, directory=str(SIM_STATE_DIR)))
    return settings


def check_config(settings: Settings, options: RunOptions, hardware: Hardware | None = None) -> dict:
    """The derived geometry of recordings, and of the live window (simulated with --sim, the real
    camera when it can be opened)."""
    camera = recording_camera(settings.camera)
    out = {"name": settings.name, **describe(settings, camera, thesis_roi(camera.width, camera.height))}
    if options.publishes:
        out["zenoh"] = {"control": zenoh_setup(settings)[1]}
    if options.mode is Mode.REPLAY:
        return out
    hw = hardware or Hardware()
    try:
        if options.mode is Mode.SIM:
            source = SimSource(settings, make_world(settings, options.sim))
        else:
            from .camera import Picamera2Source

            source = Picamera2Source(settings.camera, hw.camera_class, mapped_array=hw.mapped_array)
        with source:
            live = describe(settings, source.camera, source.default_roi)
            out["live"] = dict(source.info(), model=source.model, intrinsics=live["intrinsics"],
                               m_per_px_centre=live["m_per_px_centre"])
    except CameraUnavailable as exc:
        out["live"] = f"camera unavailable: {exc}"
    return out
