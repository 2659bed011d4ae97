"""crawlerd: distance and speed of an in-pipe crawler from the pipe wall it sees.

Usage:
  crawlerd [--config FILE]                 the service: CSI camera, LEDs, Zenoh (systemd runs this)
  crawlerd --sim [--sim-speed M_PER_S] [--sim-tilt DEG] [--sim-profile P]
                                           the same service on a simulated camera and mock GPIO
  crawlerd --replay FILE [--pts FILE | --fps N] [--log FILE.jsonl] [--annotate OUT.mp4]
           [--realtime] [--publish]        measure a recording
  crawlerd --check-config                  validate the configuration, print the derived geometry
  crawlerd calibrate intrinsics|drive ...  calibrate the camera (crawlerd calibrate --help)

Prints one JSON summary line on stdout when the run ends; progress goes to stderr on a terminal.
Exit status: 0 done, 1 a run that broke (the summary still says how far it got), 2 bad input or
a camera that cannot be opened.
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import os
import sys
from pathlib import Path

from . import __version__
from .errors import ENDINGS, ended
from .zenoh_flags import add_zenoh_flags, zenoh_values

PROG = "crawlerd"
DEFAULT_CONFIG = "/etc/crawler/crawlerd.toml"
_log = logging.getLogger(PROG)

# flag -> the settings key it sets (the flag's value, typed by argparse)
FLAG_KEYS = {"method": "odometry.method", "tilt": "mount.tilt_deg", "state_dir": "state.directory",
             "workers": "odometry.workers"}


def tilt_value(text: str):
    """--tilt: degrees, or "auto" (estimated from the flow, docs/calibration.md)."""
    if text.strip().lower() == "auto":
        return "auto"
    try:
        return float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} must be degrees or auto") from None


def _positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        value = 0
    if value < 1:
        raise argparse.ArgumentTypeError(f"{text!r} must be a whole number >= 1")
    return value


def _frame_rate(text: str) -> float:
    """A recording's frame rate: what cameras deliver, not 0, not a typo of a thousand."""
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not 0.1 <= value <= 1000:
        raise argparse.ArgumentTypeError(f"{text!r} must be a frame rate between 0.1 and 1000 fps")
    return value


def _intervals(text: str) -> tuple[float, float]:
    try:
        a, b = (float(v) for v in text.split(":"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} must be A:B in metres, e.g. 0.5:0.8") from None
    return (a, b)


def _interval_list(text: str) -> tuple[tuple[float, float], ...]:
    """'8:9,10:10.5' -> ((8.0, 9.0), (10.0, 10.5))."""
    try:
        return tuple(tuple(float(v) for v in part.split(":")) for part in text.split(",") if part)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} must be A:B[,A:B] in seconds, e.g. 8:9") from None


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog=PROG, description="Visual odometry for in-pipe crawlers.", allow_abbrev=False,
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
    cfg.add_argument("--tilt", type=tilt_value, metavar="DEG|auto",
                     help='= --set mount.tilt_deg=DEG; "auto": estimated from the flow')
    cfg.add_argument("--state-dir", metavar="DIR", help="= --set state.directory=DIR (checkpoint)")
    cfg.add_argument("--workers", type=_positive_int, metavar="N",
                     help="= --set odometry.workers=N: processes that track frames (1: this one; 4: a Pi 2's cores)")
    rep = p.add_argument_group("replay")
    rep.add_argument("--pts", metavar="FILE", help="frame times: rpicam-vid --save-pts or picamera2 pts file")
    rep.add_argument("--fps", type=_frame_rate, metavar="N", help="frame times for a raw stream without a pts file")
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
    sim.add_argument("--sim-featureless", action="append", default=[], type=_intervals, metavar="A:B",
                     help="a smooth, wet stretch of wall from A to B metres (repeatable)")
    sim.add_argument("--sim-wheel", action="store_true",
                     help="a simulated wheel encoder, read through the kernel rotary-encoder backend")
    sim.add_argument("--sim-slip", type=_interval_list, default=(), metavar="A:B[,A:B]",
                     help="seconds of the simulated world's clock (from the run's first start, kept across "
                          "restarts in the state dir) in which the wheel turns 20 %% faster than the ground "
                          "moves; frame times start up to ~0.5 s later, with the camera")
    sim.add_argument("--sim-wheel-scale", type=float, default=1.0, metavar="X",
                     help="true over nominal counts per metre of the simulated wheel (1.0)")
    net = add_zenoh_flags(p)
    net.add_argument("--no-publish", action="store_true", help="measure without opening a Zenoh session")
    out = p.add_argument_group("output")
    out.add_argument("--log", metavar="FILE.jsonl", help="one JSON object per processed frame")
    out.add_argument("--annotate", metavar="OUT.mp4", help="write the frames with ROI, tracks, distance, speed")
    out.add_argument("--max-frames", type=_positive_int, metavar="N", help="stop after N frames")
    out.add_argument("-v", "--verbose", action="store_true", help="log at debug level")
    return p


def load_settings(args):
    """The settings: defaults, the config file, --set items, then the flags' typed values."""
    from . import settings as S
    from .service import sim_settings

    values = {key: getattr(args, flag) for flag, key in FLAG_KEYS.items() if getattr(args, flag) is not None}
    values.update(zenoh_values(args))
    path = args.config or os.environ.get("CRAWLERD_CONFIG")
    if path is None and Path(DEFAULT_CONFIG).is_file():
        path = DEFAULT_CONFIG
    settings = S.load(path, args.set, values)
    if args.sim:
        given = args.state_dir is not None or any(s.startswith("state.directory=") for s in args.set)
        settings = sim_settings(settings, run_options(args), given)
    return settings


def run_options(args):
    from .service import Mode, RunOptions
    from .sim import SimOptions

    mode = Mode.REPLAY if args.replay else Mode.SIM if args.sim else Mode.CAMERA
    sim = SimOptions(speed_m_s=args.sim_speed, tilt_deg=args.sim_tilt, profile=args.sim_profile,
                     sensor=args.sim_sensor, seed=args.sim_seed, featureless=tuple(args.sim_featureless),
                     wheel=args.sim_wheel, slip=args.sim_slip, wheel_scale=args.sim_wheel_scale)
    publish = False if args.no_publish else (True if args.publish else None)
    return RunOptions(mode=mode, video=args.replay, pts=args.pts, fps=args.fps, realtime=args.realtime,
                      publish=publish, log=args.log, annotate=args.annotate, max_frames=args.max_frames,
                      sim=sim)


def run(settings, options, hardware=None, stop=None) -> int:
    """Build, run and report one run; the exit code. A stop signal ends it cleanly, even one that
    arrived during start-up (then no frame is measured, the checkpoint is kept, the exit is 0)."""
    from .service import Service

    stop = stop if stop is not None else []
    with Service(settings, options, hardware, stop=lambda: bool(stop)) as svc:
        stats = svc.run()
    summary = svc.summary()             # after closing: a file that could not be finished is in it
    stopped = bool(stop)
    if stats.frames == 0 and not stats.error and not stopped:
        stats.error = summary["error"] = "no frames were processed"
    elif stats.frames == 1 and not stats.error and not stopped:
        stats.error = summary["error"] = ("only one frame could be read: motion needs two (a truncated or "
                                          "damaged recording?)")
    elif stats.frames and not stats.tracked and not stats.error:
        stats.error = summary["error"] = (
            f"tracking was never acquired in {stats.frames} frames: the wall shows no texture the "
            "odometry can follow (black, uniform, out of focus or overexposed frames?)")
    elif stats.frames and stats.tracked < stats.frames / 2 and not stats.error:
        summary.setdefault("warnings", []).append(
            f"tracking was lost in {stats.frames - stats.tracked} of {stats.frames} frames: the distance over "
            "them is the motion model's bridge, not a measurement (a damaged recording, or a wall without "
            "texture?)")
    print(json.dumps(summary), flush=True)
    if stats.error:
        print(f"{PROG}: error: {stats.error}", file=sys.stderr)
        return 2 if stats.frames == 0 else 1    # nothing measured at all: the input was bad
    for w in summary.get("warnings", []):
        print(f"{PROG}: warning: {w}", file=sys.stderr)
    return 0


def main(argv=None) -> int:
    from .signals import StopSignals

    argv = sys.argv[1:] if argv is None else list(argv)
    if argv and argv[0] == "calibrate":
        from .calibrate import main as calibrate_main

        return calibrate_main(argv[1:])
    with StopSignals() as stop:          # first: a SIGTERM during start-up is a clean stop too
        args = build_parser().parse_args(argv)
        logging.basicConfig(level=logging.DEBUG if args.verbose else logging.WARNING,
                            format=f"{PROG}: %(levelname)s: %(message)s")
        try:
            settings = load_settings(args)
            options = run_options(args)
            if args.check_config:
                from .service import check_config

                print(json.dumps(check_config(settings, options), indent=2))
                return 0
            return run(settings, options, stop=stop)
        except ENDINGS as exc:
            return ended(PROG, exc)


if __name__ == "__main__":
    sys.exit(main())
