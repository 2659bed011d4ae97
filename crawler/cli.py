"""crawlerd: distance and speed of an in-pipe crawler from the pipe wall it sees.

Usage:
  crawlerd --replay FILE [--pts FILE | --fps N] [--config FILE] [--log FILE.jsonl]
           [--annotate OUT.mp4] [--realtime] [--method M] [--tilt DEG] [--set section.key=value]
  crawlerd --check-config [--config FILE]

Prints one JSON summary line on stdout when the run ends; progress goes to stderr on a terminal.
Exit status: 0 done, 1 a run that broke (the summary still says how far it got), 2 bad input.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import signal
import sys
import traceback

from . import __version__
from .errors import BadConfig, CrawlerError

PROG = "crawlerd"


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog=PROG, description="Visual odometry for in-pipe crawlers.")
    p.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    mode = p.add_argument_group("what to run")
    mode.add_argument("--replay", metavar="FILE", help="process a recording (.h264, .mp4, .mkv)")
    mode.add_argument("--check-config", action="store_true",
                      help="validate the configuration, print the derived geometry and exit")
    cfg = p.add_argument_group("configuration")
    cfg.add_argument("--config", metavar="FILE", help="TOML configuration (see docs/odometry.md)")
    cfg.add_argument("--set", metavar="SECTION.KEY=VALUE", action="append", default=[],
                     help="override one config key, e.g. --set mount.tilt_deg=24 (repeatable)")
    cfg.add_argument("--method", choices=("pixel", "plane", "cylinder"), help="= --set odometry.method=M")
    cfg.add_argument("--tilt", type=float, metavar="DEG", help="= --set mount.tilt_deg=DEG")
    rep = p.add_argument_group("replay")
    rep.add_argument("--pts", metavar="FILE", help="frame times: rpicam-vid --save-pts or picamera2 pts file")
    rep.add_argument("--fps", type=float, metavar="N", help="frame times for a raw stream without a pts file")
    rep.add_argument("--realtime", action="store_true", help="pace frames to their timestamps")
    rep.add_argument("--max-frames", type=int, metavar="N", help="stop after N frames")
    out = p.add_argument_group("output")
    out.add_argument("--log", metavar="FILE.jsonl", help="one JSON object per processed frame")
    out.add_argument("--annotate", metavar="OUT.mp4", help="write the frames with ROI, tracks, distance, speed")
    out.add_argument("-v", "--verbose", action="store_true", help="log at debug level")
    return p


def load_config(args):
    from . import config

    overrides = list(args.set)
    if args.method:
        overrides.append(f"odometry.method={args.method}")
    if args.tilt is not None:
        overrides.append(f"mount.tilt_deg={args.tilt}")
    return config.load(args.config, overrides)


def replay(args, cfg) -> int:
    from .odometry import Odometer
    from .runner import run
    from .sinks import Annotator, JsonlLog, Progress
    from .video import VideoReplay

    g = cfg.geometry()
    odometer = Odometer(g.camera, g.projection, g.roi, cfg.odometry_params())
    source = VideoReplay(args.replay, pts=args.pts, fps=args.fps,
                         expect_size=(cfg.camera["width"], cfg.camera["height"]))
    sinks = []
    stopping = []

    def on_signal(signum, _frame):
        stopping.append(signum)

    old = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        with source:
            logging.getLogger(PROG).info("%s", source.description)
            if args.log:
                sinks.append(JsonlLog(args.log))
            if args.annotate:
                sinks.append(Annotator(args.annotate, fps=args.fps or 30.0))
            sinks.append(Progress())
            try:
                stats = run(source, odometer, sinks, realtime=args.realtime,
                            stop=lambda: bool(stopping), max_frames=args.max_frames)
            finally:
                for sink in sinks:
                    sink.close()
    finally:
        for s, h in old.items():
            signal.signal(s, h)
    stats.extra.update(source=source.description, method=cfg.odometry["method"])
    if source.warnings:
        stats.extra["warnings"] = source.warnings
    if stats.frames == 0 and not stats.error:
        stats.error = f"video {args.replay!r} holds no decodable frames"
    summary = stats.summary(odometer)
    print(json.dumps(summary), flush=True)
    if stats.error:
        print(f"{PROG}: error: {stats.error}", file=sys.stderr)
        return 1
    for w in source.warnings:
        print(f"{PROG}: warning: {w}", file=sys.stderr)
    return 0


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    logging.basicConfig(level=logging.DEBUG if args.verbose else logging.WARNING,
                        format=f"{PROG}: %(levelname)s: %(message)s")
    try:
        cfg = load_config(args)
        if args.check_config:
            print(json.dumps(cfg.summary(), indent=2))
            return 0
        if args.replay:
            return replay(args, cfg)
        print(f"{PROG}: error: nothing to run; pass --replay FILE (or --check-config)", file=sys.stderr)
        return 2
    except BadConfig as exc:
        return _fail(exc, 2)
    except CrawlerError as exc:
        return _fail(exc, 2)
    except KeyboardInterrupt:
        return 130


def _fail(exc, code: int) -> int:
    if os.environ.get("CRAWLERD_DEBUG") == "1":
        traceback.print_exc()
    print(f"{PROG}: error: {exc}", file=sys.stderr)
    return code


if __name__ == "__main__":
    sys.exit(main())
