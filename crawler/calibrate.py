"""crawlerd calibrate: measure the camera before trusting its metres (docs/calibration.md).

Usage:
  crawlerd calibrate board [--board SPEC] -o BOARD.pdf [--paper a4|a3|letter] [--dpi N]
      the board as a page to print at its true size
  crawlerd calibrate intrinsics VIDEO [--board SPEC] -o CALIB.json [--max-rms PX] [--scale-to WxH]
                                      [--max-views N] [--every N] [--k3] [--json]
      focal lengths, principal point and distortion from a recording of a checkerboard or ChArUco
      board, written as the JSON [camera] calibration reads
  crawlerd calibrate drive VIDEO --length METRES [--start-frame N] [--end-frame N]
                                 [--start-time S] [--end-time S] [--pts FILE | --fps N]
                                 [--config FILE] [--set SECTION.KEY=VALUE] [--tilt DEG] [--method M]
                                 [--tolerance PCT] [--json]
      replay a drive between two marks of known distance: the error, PASS/FAIL against +-0.5 %, and
      the camera height or field of view that would make it exact
  crawlerd calibrate check VIDEO [--pts FILE | --fps N] | --live SECONDS [--sim [--sim-tilt DEG]]
                           [--config FILE] [--set SECTION.KEY=VALUE] [--tilt-tolerance DEG]
                           [--height-tolerance MM] [--json]
      measure a drive with [mount] tilt_deg = "auto": the tilt (and, where the pipe's curvature shows
      it, the camera height) the flow shows against the configured, PASS/FAIL and the --set to fix it

A summary goes to stdout (--json: one JSON object), progress to stderr on a terminal.
Exit status: 0 done (drive: PASS), 1 a FAIL or a calibration that could not be made, 2 bad input.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
from pathlib import Path

from .errors import ENDINGS, BadConfig, CrawlerError, ended, fail

PROG = "crawlerd calibrate"
DEFAULT_MAX_RMS_PX = 1.0
GOOD_RMS_PX = 0.5


class _Usage(Exception):
    """A command-line mistake: one line, exit 2."""


class _Parser(argparse.ArgumentParser):
    def __init__(self, *args, **kwargs):    # --tilt must never be taken for --tilt-tolerance
        super().__init__(*args, **{"allow_abbrev": False, **kwargs})

    def error(self, message: str):          # one line, not argparse's usage dump
        raise _Usage(message)


class CalibrationFailed(CrawlerError):
    """The recording was read but gives no usable calibration (exit 1): the message says why and what to do."""


def _size(text: str) -> tuple[int, int]:
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} must be WIDTHxHEIGHT, e.g. 3280x2464") from None
    if w < 16 or h < 16:
        raise argparse.ArgumentTypeError(f"{text!r}: width and height must be at least 16 pixels")
    return w, h


def add_replay_arguments(group, set_example: str = "") -> None:
    """--pts | --fps, --config, --set: a recording replayed as crawlerd --replay replays it."""
    times = group.add_mutually_exclusive_group()
    times.add_argument("--pts", metavar="FILE", help="frame times: rpicam-vid --save-pts or picamera2 pts file")
    times.add_argument("--fps", type=_number(0.1, 1000, "a frame rate"), metavar="N",
                       help="frame times of a raw stream without a pts file")
    group.add_argument("--config", metavar="FILE", help="TOML configuration (default: as crawlerd)")
    example = f", e.g. --set {set_example}" if set_example else ""
    group.add_argument("--set", metavar="SECTION.KEY=VALUE", action="append", default=[],
                       help=f"override one config key{example} (repeatable)")


def _number(lo: float, hi: float, what: str):
    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            value = math.nan
        if not lo <= value <= hi:
            raise argparse.ArgumentTypeError(f"{text!r} must be {what} between {lo:g} and {hi:g}")
        return value
    return parse


def _whole(lo: int):
    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            value = lo - 1
        if value < lo:
            raise argparse.ArgumentTypeError(f"{text!r} must be a whole number >= {lo}")
        return value
    return parse


_count = _whole(0)


def build_parser() -> argparse.ArgumentParser:
    from .calibrate_board import DEFAULT_BOARD, FORMS
    from .calibrate_check import add_check_arguments
    from .calibrate_drive import add_drive_arguments
    from .calibrate_intrinsics import MAX_VIEWS, MIN_VIEWS

    p = _Parser(prog=PROG, description="Calibrate the camera (docs/calibration.md).")
    sub = p.add_subparsers(dest="what", metavar="{board,intrinsics,drive,check}", parser_class=_Parser)
    sub.required = True
    b = sub.add_parser("board", help="the board as a page to print at its true size")
    b.add_argument("--board", default=DEFAULT_BOARD, metavar="SPEC", help=f"{FORMS} ({DEFAULT_BOARD})")
    b.add_argument("-o", "--output", required=True, metavar="BOARD.pdf", help="the page: .pdf to print, or .png")
    b.add_argument("--paper", default="a4", choices=("a4", "a3", "letter"), help="paper size (a4)")
    b.add_argument("--dpi", type=_number(72, 1200, "dots per inch"), default=300.0, metavar="N",
                   help="resolution of a .png page (300)")
    i = sub.add_parser("intrinsics", help="lens intrinsics from a board recording")
    i.add_argument("video", metavar="VIDEO", help="recording of the board (.h264, .mp4, .mkv)")
    i.add_argument("--board", default=DEFAULT_BOARD, metavar="SPEC", help=f"{FORMS} ({DEFAULT_BOARD})")
    i.add_argument("-o", "--output", required=True, metavar="CALIB.json", help="the calibration file to write")
    i.add_argument("--max-rms", type=_number(0.01, 100, "pixels"), default=DEFAULT_MAX_RMS_PX, metavar="PX",
                   help=f"refuse a fit whose RMS reprojection error is above this ({DEFAULT_MAX_RMS_PX:g} px)")
    i.add_argument("--scale-to", type=_size, metavar="WxH",
                   help="write the intrinsics for another resolution of the same view, e.g. a 1280x960 "
                        "recording of the binned full view for the 3280x2464 sensor the live camera plans with")
    i.add_argument("--max-views", type=_whole(MIN_VIEWS), default=MAX_VIEWS, metavar="N",
                   help=f"calibrate on at most N views, chosen to differ ({MAX_VIEWS})")
    i.add_argument("--every", type=_count, default=0, metavar="N",
                   help="look for the board in every Nth frame (0: enough to examine about 300 frames)")
    i.add_argument("--k3", action="store_true", help="fit the 6th-order radial term too (wide-angle lenses)")
    i.add_argument("--json", action="store_true", help="print the summary as one JSON object")
    add_drive_arguments(sub.add_parser("drive", help="distance error over a drive of known length"))
    add_check_arguments(sub.add_parser("check", help="the tilt and height the flow shows against the configured"))
    return p


def main(argv=None) -> int:
    try:
        args = build_parser().parse_args(argv)
        if args.what == "intrinsics":
            return intrinsics_main(args)
        if args.what == "check":
            from .calibrate_check import check_main

            return check_main(args)
        if args.what == "board":
            from .calibrate_print import print_main

            return print_main(args)
        from .calibrate_drive import drive_main

        return drive_main(args)
    except _Usage as exc:
        print(f"{PROG}: error: {exc}", file=sys.stderr)
        return 2
    except CalibrationFailed as exc:
        return fail(PROG, exc, 1)
    except ENDINGS as exc:
        return ended(PROG, exc)


class Progress:
    """One self-overwriting line on a terminal's stderr; silent otherwise (a pipe, a test)."""

    def __init__(self, stream=None):
        self.stream = stream or sys.stderr
        self.enabled = hasattr(self.stream, "isatty") and self.stream.isatty()
        self.shown = False

    def show(self, text: str):
        if self.enabled:
            self.stream.write(f"\r{text:70s}")
            self.stream.flush()
            self.shown = True

    def done(self):
        if self.shown:
            self.stream.write("\n")
            self.shown = False


def count_frames(path: str) -> int | None:
    """Frames in a recording by demuxing (no decoding): cheap; None if the container will not say."""
    import av

    try:
        with av.open(path) as c:
            return sum(1 for packet in c.demux(video=0) if packet.size)
    except (av.error.FFmpegError, OSError, ValueError, IndexError):
        return None


def collect_views(path: str, finder, every: int, progress: Progress):
    """(views, frame size, frames examined) of a board recording."""
    from .calibrate_intrinsics import View
    from .geometry import Camera
    from .video import VideoReplay

    # the frames' camera is what is being measured: no size to expect, and frame times do not matter
    source = VideoReplay(path, Camera(1, 1, 1.0, 1.0, 0.0, 0.0), fps=1.0)
    source.expect_size = None
    if every == 0:
        total = count_frames(path)
        every = max(1, (total or 0) // 300)
    views, size, examined = [], None, 0
    with source:
        for frame in source.frames():
            size = (frame.gray.shape[1], frame.gray.shape[0])
            if frame.index % every:
                continue
            examined += 1
            found = finder.find(frame.gray)
            if found is not None:
                views.append(View(frame.index, *found))
            progress.show(f"frame {frame.index}: board found in {len(views)} of {examined} frames examined")
    progress.done()
    return views, size, examined


def _check_output(path: Path):
    """Refuse an output that cannot be written now, not after minutes of detection."""
    if path.is_dir():
        raise BadConfig(f"-o {str(path)!r} is a folder; give the calibration file's name, e.g. calib.json")
    if path.suffix.lower() != ".json":
        raise BadConfig(f"-o {str(path)!r}: the calibration is written as JSON; name it *.json")
    folder = path.parent
    if not folder.is_dir() or not os.access(folder, os.W_OK):
        raise BadConfig(f"-o {str(path)!r}: folder {str(folder)!r} does not exist or is not writable")


def intrinsics_main(args) -> int:
    from .calibrate_board import make_finder, parse_board

    out = Path(args.output)
    _check_output(out)
    spec = parse_board(args.board)
    views, size, examined = collect_views(args.video, make_finder(spec), args.every, Progress())
    result, used = _solve(views, size, examined, spec, args)
    summary = _write(out, result, used, size, examined, len(views), spec, args)
    print(json.dumps(summary) if args.json else intrinsics_text(summary))
    return 0


def _solve(views, size, examined, spec, args):
    from .calibrate_intrinsics import MIN_VIEWS, calibrate, implausible, select_views

    if len(views) < MIN_VIEWS:
        corners = "x".join(str(n) for n in spec.corners)
        raise CalibrationFailed(
            f"the board ({spec.text()}, {corners} inner corners) was found in {len(views)} of {examined} frames "
            f"examined, {MIN_VIEWS} are needed; check --board (a checkerboard of 10x7 squares has 9x6 inner "
            "corners), light the board evenly, keep it in focus and move it slowly (docs/calibration.md)")
    used = [views[k] for k in select_views(views, size, args.max_views)]
    result = calibrate(used, size, k3=args.k3)
    problem = implausible(result, size)
    if problem:
        raise CalibrationFailed(f"no usable calibration: {problem}; record the board at more angles and all "
                                "over the frame (docs/calibration.md)")
    if result.rms_px > args.max_rms:
        raise CalibrationFailed(
            f"RMS reprojection error {result.rms_px:.3f} px is above --max-rms {args.max_rms:g} px; nothing was "
            "written. Blurred frames (move the board slower, more light), a board that is not flat, or the "
            "wrong --board size? (docs/calibration.md)")
    return result, used


def _write(out: Path, result, used, size, examined, found, spec, args) -> dict:
    from .calibrate_intrinsics import coverage
    from .calibration import write_calibration
    from .geometry import Camera

    camera = Camera(size[0], size[1], result.fx, result.fy, result.cx, result.cy,
                    distortion=tuple(float(x) for x in result.dist))
    if args.scale_to and tuple(args.scale_to) != tuple(size):
        w, h = args.scale_to
        if abs(w * size[1] - h * size[0]) > 0.01 * w * size[1]:
            raise BadConfig(f"--scale-to {w}x{h} is another shape than the {size[0]}x{size[1]} recording; "
                            "scale only between resolutions of the same view (e.g. 1640x1232 -> 3280x2464)")
        camera = camera.with_size(w, h)
    info = {"rms_px": round(result.rms_px, 4), "board": spec.text(), "recorded_size": list(size),
            "views": len(result.frames), "frames": result.frames}
    write_calibration(out, camera, calibrated_by="crawlerd calibrate intrinsics", **info)
    return {
        "output": str(out), "image_size": [camera.width, camera.height], **info,
        "fx": round(camera.fx, 3), "fy": round(camera.fy, 3), "cx": round(camera.cx, 3), "cy": round(camera.cy, 3),
        "std_px": {k: round(v * camera.width / size[0], 3) for k, v in result.std.items()},
        "dist_coeffs": [round(float(x), 6) for x in camera.distortion],
        "max_rms_px": args.max_rms, "examined": examined, "found": found, "dropped": result.dropped,
        "coverage": round(coverage(used, size), 3),
        "hfov_deg": round(math.degrees(2 * math.atan(camera.width / 2 / camera.fx)), 3),
        "vfov_deg": round(math.degrees(2 * math.atan(camera.height / 2 / camera.fy)), 3),
    }


def intrinsics_text(s: dict) -> str:
    """The summary as an operator reads it."""
    w, h = s["image_size"]
    std = s["std_px"]
    quality = "good" if s["rms_px"] <= GOOD_RMS_PX else "usable, but a sharper recording would do better"
    lines = [
        f"board {s['board']}: found in {s['found']} of {s['examined']} frames examined; calibrated on "
        f"{s['views']} views" + (f" ({len(s['dropped'])} dropped as outliers)" if s["dropped"] else ""),
        f"  fx {s['fx']:.2f} +- {std['fx']:.2f} px   fy {s['fy']:.2f} +- {std['fy']:.2f} px   "
        f"cx {s['cx']:.2f} +- {std['cx']:.2f} px   cy {s['cy']:.2f} +- {std['cy']:.2f} px   ({w}x{h})",
        "  distortion k1 k2 p1 p2 k3: " + " ".join(f"{d:.5g}" for d in s["dist_coeffs"]),
        f"  field of view {s['hfov_deg']:.2f} x {s['vfov_deg']:.2f} deg",
        f"  RMS reprojection error {s['rms_px']:.3f} px ({quality}; refused above {s['max_rms_px']:g} px)",
        f"  corners cover {100 * s['coverage']:.0f} % of the frame",
    ]
    if s["coverage"] < 0.6:
        lines.append("  warning: the board never reached much of the frame's edge, where the distortion is; "
                     "record again, moving it into the corners")
    lines.append(f"wrote {s['output']}; use it with [camera] calibration = \"{s['output']}\"")
    return "\n".join(lines)
