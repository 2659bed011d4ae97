"""crawlerd: distance and speed of an in-pipe crawler from the pipe wall it sees.

Usage:
  crawlerd [--config FILE]                 the service: CSI camera, LEDs, Zenoh (systemd runs this)
  crawlerd --sim [--sim-speed M_PER_S] [--sim-tilt DEG] [--sim-profile P]
                                           the same service on a simulated camera and mock GPIO
  crawlerd --replay FILE [--pts FILE | --fps N] [--log FILE.jsonl] [--annotate OUT.mp4]
           [--realtime] [--publish]        measure a recording
  crawlerd --check-config                  validate the configuration, print the derived geometry

Prints one JSON summary line on stdout when the run ends; progress goes to stderr on a terminal.
Exit status: 0 done, 1 a run that broke (the summary still says how far it got), 2 bad input or
a camera that cannot be opened.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import signal
import sys
import tempfile
from pathlib import Path

from . import __version__
from .errors import BadConfig, CameraUnavailable, CrawlerError, fail

PROG = "crawlerd"
DEFAULT_CONFIG = "/etc/crawler/crawlerd.toml"
_log = logging.getLogger(PROG)


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog=PROG, description="Visual odometry for in-pipe crawlers.",
                                epilog="Documentation: docs/odometry.md, docs/deploy.md, docs/topics.md")
    p.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    mode = p.add_argument_group("what to run (default: the live camera)")
    mode.add_argument("--replay", metavar="FILE", help="process a recording (.h264, .mp4, .mkv)")
    mode.add_argument("--sim", action="store_true", help="the daemon on hw_sim's simulated camera and mock pins")
    mode.add_argument("--check-config", action="store_true",
                      help="validate the configuration, print the derived geometry and exit")
    cfg = p.add_argument_group("configuration")
    cfg.add_argument("--config", metavar="FILE",
                     help=f"TOML configuration (default: $CRAWLERD_CONFIG or {DEFAULT_CONFIG} if present)")
    cfg.add_argument("--set", metavar="SECTION.KEY=VALUE", action="append", default=[],
                     help="override one config key, e.g. --set mount.tilt_deg=24 (repeatable)")
    cfg.add_argument("--method", choices=("pixel", "plane", "cylinder"), help="= --set odometry.method=M")
    cfg.add_argument("--tilt", type=float, metavar="DEG", help="= --set mount.tilt_deg=DEG")
    cfg.add_argument("--state-dir", metavar="DIR", help="= --set state.directory=DIR (checkpoint)")
    rep = p.add_argument_group("replay")
    rep.add_argument("--pts", metavar="FILE", help="frame times: rpicam-vid --save-pts or picamera2 pts file")
    rep.add_argument("--fps", type=float, metavar="N", help="frame times for a raw stream without a pts file")
    rep.add_argument("--realtime", action="store_true", help="pace frames to their timestamps")
    rep.add_argument("--publish", action="store_true", help="publish the replay over Zenoh like the daemon")
    sim = p.add_argument_group("simulator (--sim)")
    sim.add_argument("--sim-speed", type=float, default=0.2, metavar="M_PER_S", help="crawler speed (0.2)")
    sim.add_argument("--sim-tilt", type=float, metavar="DEG",
                     help="camera tilt of the simulated car (also sets mount.tilt_deg)")
    sim.add_argument("--sim-profile", default="constant", choices=("constant", "accel", "stopgo", "reverse"),
                     help="motion profile (constant)")
    sim.add_argument("--sim-sensor", default="imx219", choices=("imx219", "ov5647", "imx708"),
                     help="simulated camera module (imx219)")
    sim.add_argument("--sim-seed", type=int, default=0, metavar="N", help="wall texture seed")
    sim.add_argument("--sim-featureless", action="append", default=[], metavar="A:B",
                     help="a smooth, wet stretch of wall from A to B metres (repeatable)")
    net = p.add_argument_group("zenoh")
    net.add_argument("--listen", action="append", default=[], metavar="ENDPOINT",
                     help="e.g. tcp/0.0.0.0:7447 (repeatable; = [zenoh] listen)")
    net.add_argument("--connect", action="append", default=[], metavar="ENDPOINT",
                     help="e.g. tcp/192.168.1.10:7447 (repeatable; = [zenoh] connect)")
    net.add_argument("--zenoh-mode", choices=("peer", "client", "router"), help="= [zenoh] mode (peer)")
    net.add_argument("--zenoh-config", metavar="FILE", help="a full zenoh JSON5 config (TLS, access control)")
    net.add_argument("--no-multicast", action="store_true", help="no multicast scouting (fixed endpoints only)")
    net.add_argument("--no-publish", action="store_true", help="measure without opening a Zenoh session")
    out = p.add_argument_group("output")
    out.add_argument("--log", metavar="FILE.jsonl", help="one JSON object per processed frame")
    out.add_argument("--annotate", metavar="OUT.mp4", help="write the frames with ROI, tracks, distance, speed")
    out.add_argument("--max-frames", type=_positive_int, metavar="N", help="stop after N frames")
    out.add_argument("-v", "--verbose", action="store_true", help="log at debug level")
    return p


def _positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        value = 0
    if value < 1:
        raise argparse.ArgumentTypeError(f"{text!r} must be a whole number >= 1")
    return value


def load_config(args):
    from . import config

    overrides = list(args.set)
    if args.method:
        overrides.append(f"odometry.method={args.method}")
    tilt = args.tilt if args.tilt is not None else (args.sim_tilt if args.sim else None)
    if tilt is not None:
        overrides.append(f"mount.tilt_deg={tilt}")
    for flag, key in (("state_dir", "state.directory"), ("zenoh_mode", "zenoh.mode"),
                      ("listen", "zenoh.listen"), ("connect", "zenoh.connect"),
                      ("zenoh_config", "zenoh.config")):
        if getattr(args, flag):
            overrides.append(f"{key}={json.dumps(getattr(args, flag))}")
    if args.no_multicast:
        overrides.append("zenoh.multicast=false")
    if args.sim and not args.state_dir and not any(o.startswith("state.directory=") for o in args.set):
        # a simulated run must never overwrite the real run's checkpoint on the crawler
        overrides.append(f"state.directory={json.dumps(str(Path(tempfile.gettempdir()) / 'crawlerd-sim'))}")
    path = args.config or os.environ.get("CRAWLERD_CONFIG")
    if path is None and Path(DEFAULT_CONFIG).is_file():
        path = DEFAULT_CONFIG
    return config.load(path, overrides)


def make_replay_source(cfg, video, pts=None, fps=None):
    from .video import VideoReplay

    return VideoReplay(video, pts=pts, fps=fps, expect_size=(cfg.camera["width"], cfg.camera["height"]))


def make_camera_source(cfg, camera_class=None, description="camera", mapped_array=None):
    from .camera import Picamera2Source

    c = cfg.camera
    fov = (c["sensor_hfov_deg"], c["sensor_vfov_deg"]) if c["sensor_hfov_deg"] else None
    calibration = None
    if c["calibration"]:
        from .geometry import Camera

        calibration = Camera.from_calibration(c["calibration"])
    return Picamera2Source(camera_class, mapped_array=mapped_array, camera_num=c["camera_num"],
                           window=c["sensor_window"],
                           calibration=calibration,
                           output_size=tuple(c["output_size"]), fps=c["fps"], exposure_us=c["exposure_us"],
                           analogue_gain=c["analogue_gain"], fov_deg=fov, line_time_us=c["line_time_us"],
                           hflip=c["hflip"], vflip=c["vflip"], capture_timeout_s=c["capture_timeout_s"],
                           description=description)


def make_sim(cfg, args):
    """hw_sim's fake Picamera2 class bound to a simulated run, and its ground truth."""
    from hw_sim.picamera2_fake import SimWorld, make_picamera2

    try:
        featureless = tuple(tuple(float(v) for v in item.split(":")) for item in args.sim_featureless)
        if not all(len(f) == 2 and f[0] < f[1] for f in featureless):
            raise ValueError
    except ValueError:
        raise BadConfig(f"--sim-featureless {args.sim_featureless} must be A:B with A < B in metres, "
                        "e.g. 0.5:0.8") from None
    from hw_sim import SimError

    try:
        world = _sim_world(SimWorld, cfg, args, featureless)
    except (SimError, ValueError) as exc:
        flags = {"speed_m_s": "--sim-speed", "tilt_deg": "--sim-tilt (or mount.tilt_deg)"}
        field = getattr(exc, "field", "")
        raise BadConfig(f"simulator: {exc}" + (f"; set {flags[field]}" if field in flags else "")) from None
    return make_picamera2(world), world


def _sim_world(SimWorld, cfg, args, featureless):
    return SimWorld(sensor=args.sim_sensor, tilt_deg=cfg.mount["tilt_deg"], speed_m_s=args.sim_speed,
                    profile=args.sim_profile, seed=args.sim_seed, featureless=featureless,
                    pipe_diameter_m=cfg.mount["pipe_diameter_m"], car_width_m=cfg.mount["car_width_m"],
                    offset_m=cfg.mount["camera_offset_m"], camera_height_m=cfg.mount["height_m"])


def make_link(cfg, daemon_ref):
    from .link import ZenohLink, make_zenoh_config

    z = cfg.zenoh
    conf = make_zenoh_config(z["mode"], z["listen"], z["connect"], z["config"], z["multicast"])
    return ZenohLink(cfg.name, conf, on_command=lambda req: daemon_ref[0].commands.submit(req))


def run(args, cfg) -> int:
    from .checkpoint import Checkpoint
    from .daemon import Daemon
    from .leds import BrightnessLoop, Leds, NoLeds
    from .sdnotify import Notifier
    from .sinks import Annotator, JsonlLog, Progress

    mode = "replay" if args.replay else "sim" if args.sim else "camera"
    truth = None
    pin_factory = None
    if mode == "replay":
        source = make_replay_source(cfg, args.replay, args.pts, args.fps)
    elif mode == "sim":
        from gpiozero.pins.mock import MockFactory, MockPWMPin

        from hw_sim.picamera2_fake import MappedArray

        camera_class, world = make_sim(cfg, args)
        truth = world.true_distance_m
        pin_factory = MockFactory(pin_class=MockPWMPin)
        source = make_camera_source(cfg, camera_class, description="sim", mapped_array=MappedArray)
    else:
        source = make_camera_source(cfg)

    stopping = []
    old = {s: signal.signal(s, lambda signum, _f: stopping.append(signum))
           for s in (signal.SIGINT, signal.SIGTERM)}
    publish = (mode != "replay" or args.publish) and not args.no_publish
    daemon_ref = [None]
    link = None
    leds = NoLeds()
    notifier = Notifier() if mode != "replay" else None
    try:
        try:
            source.__enter__()
        except CameraUnavailable as exc:
            fallback = cfg.camera["fallback_video"]
            if mode != "camera" or not fallback:
                raise
            _log.error("CAMERA UNAVAILABLE (%s); FALLING BACK TO RECORDING %s", exc, fallback)
            mode = "replay-fallback"
            source = make_replay_source(cfg, fallback, cfg.camera["fallback_pts"], cfg.camera["fallback_fps"])
            source.__enter__()
            source.description = f"FALLBACK {source.description} (camera: {exc})"
        try:
            pins = cfg.leds["pins"] or ([12, 13] if mode == "sim" else [])   # sim: mock pins anyway
            if pins and not mode.startswith("replay"):
                leds = Leds(pins, brightness=cfg.leds["brightness"],
                            frequency_hz=cfg.leds["frequency_hz"], active_high=cfg.leds["active_high"],
                            pin_factory=pin_factory)
            sinks = []
            if args.log:
                sinks.append(JsonlLog(args.log))
            if args.annotate:
                sinks.append(Annotator(args.annotate, fps=args.fps or (
                    30.0 if mode.startswith("replay") else cfg.camera["fps"])))
            sinks.append(Progress())
            checkpoint = Checkpoint(cfg.state["directory"], cfg.state["checkpoint_s"]) if mode != "replay" else None
            brightness = BrightnessLoop(target=cfg.leds["target_grey"]) if cfg.leds["auto_brightness"] else None
            daemon = Daemon(cfg, source, mode=mode, leds=leds, notifier=notifier,
                            checkpoint=checkpoint, truth=truth, brightness=brightness,
                            stop=lambda: bool(stopping), max_frames=args.max_frames, sinks=sinks,
                            realtime=args.realtime)
            daemon_ref[0] = daemon
            if publish:     # after the daemon exists: a control query may arrive at once
                link = daemon.link = make_link(cfg, daemon_ref).open()
            try:
                stats = daemon.run()
            finally:
                for sink in sinks:
                    sink.close()
        finally:
            source.__exit__(None, None, None)
    finally:
        leds.close()
        if link is not None:
            link.close()
        if notifier is not None:
            notifier.close()
        for s, h in old.items():
            signal.signal(s, h)

    stats.extra.update(source=source.description, method=cfg.odometry["method"])
    warnings = list(getattr(source, "warnings", []))
    if warnings:
        stats.extra["warnings"] = warnings
    if daemon.true_distance_m() is not None:
        stats.extra["sim_true_distance_m"] = round(daemon.true_distance_m(), 6)
    if stats.frames == 0 and not stats.error:
        stats.error = "no frames were processed"
    print(json.dumps(daemon.summary()), flush=True)
    if stats.error:
        print(f"{PROG}: error: {stats.error}", file=sys.stderr)
        return 2 if stats.frames == 0 else 1    # nothing measured: the input was bad
    for w in warnings:
        print(f"{PROG}: warning: {w}", file=sys.stderr)
    return 0


def check_config(args, cfg) -> int:
    """Validate, then print the derived geometry: of the recording frames, and of the live window
    (from the simulated camera with --sim, from the real one when it can be opened)."""
    out = cfg.summary()
    if not args.replay:
        if args.sim:
            camera_class, _ = make_sim(cfg, args)
            source = make_camera_source(cfg, camera_class, description="sim")
        else:
            source = make_camera_source(cfg)
        try:
            with source:
                plan = source.plan
                cam = plan.camera
                out["live"] = dict(plan.describe(), model=source.model,
                                   intrinsics={k: round(getattr(cam, k), 3) for k in ("fx", "fy", "cx", "cy")},
                                   m_per_px_centre=round(cfg.make_mount().height_m / cam.fy, 9))
        except CameraUnavailable as exc:
            out["live"] = f"camera unavailable: {exc}"
    print(json.dumps(out, indent=2))
    return 0


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    logging.basicConfig(level=logging.DEBUG if args.verbose else logging.WARNING,
                        format=f"{PROG}: %(levelname)s: %(message)s")
    try:
        cfg = load_config(args)
        if args.check_config:
            return check_config(args, cfg)
        return run(args, cfg)
    except CrawlerError as exc:
        return _fail(exc, 2)
    except KeyboardInterrupt:
        return 130


def _fail(exc, code: int) -> int:
    return fail(PROG, exc, code)


if __name__ == "__main__":
    sys.exit(main())
