"""crawlerd calibrate drive: a drive between two marks of known distance, measured like any replay.

The recording is replayed through the same Service as `crawlerd --replay` (the configured geometry,
the distance chain, nothing rebuilt here) into a temporary JSONL log, and the distance between the
frames at the two marks is compared with the taped length. A wrong camera height and a wrong field
of view both scale every metre: the height H linearly, the FOV through tan(FOV/2) (the metres per
pixel), not exactly linearly once the camera is tilted and the wall curves. So each correction is
first taken to first order and then checked by replaying with it, refined by the secant method
until the replay measures the taped length (to REFINE_TOL_PCT).
"""

from __future__ import annotations

import json
import math
import os
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

from .errors import BadConfig

SPEC_PCT = 0.5              # the municipal spec for a cable counter: +-0.5 % of the distance
IMPLAUSIBLE_PCT = 30.0      # an error this large is a wrong length, marks, tilt or method, not H or FOV
REFINE_TOL_PCT = 0.01       # a correction is refined until its replay is this close to the taped length
MAX_REPLAYS = 3             # per correction, after the first replay


def add_drive_arguments(p):
    from .calibrate import _count, _number, add_replay_arguments
    from .cli import tilt_value

    p.add_argument("video", metavar="VIDEO", help="recording of the drive (.h264, .mp4, .mkv)")
    p.add_argument("--length", required=True, type=_number(0.05, 10_000, "a length in metres"), metavar="M",
                   help="taped distance between the two marks, metres (e.g. 2.000)")
    marks = p.add_argument_group("the marks (default: the first and the last frame)")
    start = marks.add_mutually_exclusive_group()
    start.add_argument("--start-frame", type=_count, metavar="N", help="frame (from 0) at the first mark")
    start.add_argument("--start-time", type=_number(0, 1e6, "seconds"), metavar="S",
                       help="time of the first mark, seconds from the first frame (the pts file's clock)")
    end = marks.add_mutually_exclusive_group()
    end.add_argument("--end-frame", type=_count, metavar="N", help="frame at the second mark")
    end.add_argument("--end-time", type=_number(0, 1e6, "seconds"), metavar="S", help="time of the second mark")
    rep = p.add_argument_group("replay (as crawlerd --replay)")
    add_replay_arguments(rep, "mount.height_m=0.226")
    rep.add_argument("--tilt", type=tilt_value, metavar="DEG|auto", help="= --set mount.tilt_deg=DEG")
    rep.add_argument("--method", choices=("pixel", "plane", "cylinder"), help="= --set odometry.method=M")
    p.add_argument("--tolerance", type=_number(0.01, 50, "a percentage"), default=SPEC_PCT, metavar="PCT",
                   help=f"PASS within +-PCT %% of the taped length ({SPEC_PCT:g}, the spec for a cable counter)")
    p.add_argument("--json", action="store_true", help="print the summary as one JSON object")


def load_settings(args):
    """The configuration crawlerd itself would use (the same file, --set items and flags), without
    the wheel: a replay has none, and the camera's own metres are what is calibrated."""
    from . import settings as S
    from .cli import DEFAULT_CONFIG

    path = args.config or os.environ.get("CRAWLERD_CONFIG")
    if path is None and Path(DEFAULT_CONFIG).is_file():
        path = DEFAULT_CONFIG
    values = {key: value for key, value in (("mount.tilt_deg", args.tilt), ("odometry.method", args.method))
              if value is not None}
    settings = S.load(path, args.set, values)
    if settings.wheel.enabled:          # the drive calibrates the camera: no wheel fused into its metres
        settings = settings.with_values({"wheel.backend": "none"}, "calibrate drive")
    return settings


@dataclass(frozen=True)
class Marks:
    """Where the drive starts and ends: frame indices, or times, or None for the recording's ends."""

    start_frame: int | None = None
    end_frame: int | None = None
    start_time: float | None = None
    end_time: float | None = None

    def __post_init__(self):
        a, b = self.start_frame, self.end_frame
        if a is not None and b is not None and b <= a:
            raise BadConfig(f"--end-frame {b} is not after --start-frame {a}; swap them")
        a, b = self.start_time, self.end_time
        if a is not None and b is not None and b <= a:
            raise BadConfig(f"--end-time {b:g} is not after --start-time {a:g}; swap them")

    def last_frame_needed(self) -> int | None:
        """The replay may stop after this many frames (an end given as a frame)."""
        return None if self.end_frame is None else self.end_frame + 1

    def pick(self, rows: list[dict]) -> tuple[dict, dict]:
        """The log rows at the two marks; BadConfig if a mark is not in the recording."""
        end = _row_at(rows, self.end_frame, self.end_time, "end") if self._end_given else rows[-1]
        if not self._start_given:
            return rows[0], end
        a, t = self.start_frame, self.start_time
        if (a is not None and a >= end["frame"]) or (t is not None and t >= end["t_s"]):
            mark = f"--start-frame {a}" if a is not None else f"--start-time {t:g}"
            raise BadConfig(f"the end mark (frame {end['frame']}, {end['t_s']:.3f} s) is not after the start "
                            f"mark ({mark}); swap them")
        return _row_at(rows, a, t, "start"), end

    @property
    def _start_given(self) -> bool:
        return self.start_frame is not None or self.start_time is not None

    @property
    def _end_given(self) -> bool:
        return self.end_frame is not None or self.end_time is not None


def _row_at(rows: list[dict], frame: int | None, t_s: float | None, which: str) -> dict:
    last = rows[-1]
    if frame is not None:
        if frame > last["frame"]:
            raise BadConfig(f"--{which}-frame {frame} is after the recording's last frame ({last['frame']})")
        return next(r for r in rows if r["frame"] >= frame)        # a frame lost in decoding: the next
    if t_s > last["t_s"] + 1e-6:
        raise BadConfig(f"--{which}-time {t_s:g} is after the recording's last frame ({last['t_s']:.3f} s)")
    return min(rows, key=lambda r: abs(r["t_s"] - t_s))


class DriveReplay:
    """Replays the recording with a given configuration; the distance between the two marks."""

    def __init__(self, video: str, pts: str | None, fps: float | None, marks: Marks, folder: Path):
        self.video, self.pts, self.fps, self.marks, self.folder = video, pts, fps, marks, folder
        self.replays = 0

    def measure(self, settings, label: str = "the drive") -> tuple[float, dict, dict, list[dict]]:
        """(metres between the marks, start row, end row, rows between them) with these settings."""
        from .calibrate import CalibrationFailed
        from .service import Mode, RunOptions, Service

        self.replays += 1
        if sys.stderr.isatty():         # the replay's own progress line follows
            print(f"replay {self.replays}: {label}", file=sys.stderr)
        log = self.folder / f"replay{self.replays}.jsonl"
        options = RunOptions(mode=Mode.REPLAY, video=self.video, pts=self.pts, fps=self.fps, publish=False,
                             log=str(log), max_frames=self.marks.last_frame_needed())
        with Service(settings, options) as svc:
            stats = svc.run()
        if stats.error or not stats.tracked:
            why = stats.error or "tracking was never acquired: the wall shows no texture the odometry can follow"
            raise CalibrationFailed(f"the replay of {Path(self.video).name} broke off ({why})")
        rows = [json.loads(line) for line in log.read_text().splitlines()]
        log.unlink()
        start, end = self.marks.pick(rows)
        between = [r for r in rows if start["frame"] < r["frame"] <= end["frame"]]
        return abs(end["distance_m"] - start["distance_m"]), start, end, between


def secant(measure, x0: float, m0: float, x1: float, target: float, tol: float, max_evals: int):
    """Solve measure(x) = target from (x0, m0) and a first guess x1: (x, measured, evaluations).

    measure may raise BadConfig for an x the configuration refuses; the last good x is kept then."""
    xs, ms = [x0], [m0]
    x = x1
    for _ in range(max_evals):
        try:
            m = measure(x)
        except BadConfig:
            break
        xs.append(x)
        ms.append(m)
        if abs(m - target) <= tol * target or ms[-1] == ms[-2]:
            break
        x = xs[-1] + (target - ms[-1]) * (xs[-1] - xs[-2]) / (ms[-1] - ms[-2])
    return xs[-1], ms[-1], len(xs) - 1


def _tan_scaled(fov_deg: float, k: float) -> float:
    return math.degrees(2 * math.atan(math.tan(math.radians(fov_deg) / 2) * k))


def height_correction(settings, replay: DriveReplay, measured: float, known: float) -> dict:
    """The [mount] height_m that makes the drive exact."""
    h0 = settings.mount.mount().height_m

    def measure(h):
        return replay.measure(settings.with_values({"mount.height_m": h}, "the height correction"),
                              f"checking [mount] height_m = {h:.5f}")[0]

    h, m, n = secant(measure, h0, measured, h0 * known / measured, known, REFINE_TOL_PCT / 100, MAX_REPLAYS)
    source = "[mount] height_m" if settings.mount.height_m is not None else "the mount formula (Eq. 3.4)"
    return {"now": round(h0, 6), "from": source, "exact": round(h, 5), "check_m": round(m, 5), "replays": n,
            "set": f"--set mount.height_m={h:.5f}", "toml": f"[mount] height_m = {h:.5f}"}


def fov_correction(settings, replay: DriveReplay, measured: float, known: float) -> dict | None:
    """The [camera] hfov_deg/vfov_deg (scaled together: the focal length) that make the drive exact;
    None when a calibration file gives the focal length."""
    cam = settings.camera
    if cam.calibration:
        return None

    def fovs(k):
        return {"camera.hfov_deg": _tan_scaled(cam.hfov_deg, k), "camera.vfov_deg": _tan_scaled(cam.vfov_deg, k)}

    def measure(k):
        return replay.measure(settings.with_values(fovs(k), "the FOV correction"),
                              f"checking the FOV x tan {k:.5f}")[0]

    k, m, n = secant(measure, 1.0, measured, known / measured, known, REFINE_TOL_PCT / 100, MAX_REPLAYS)
    new = fovs(k)
    h, v = new["camera.hfov_deg"], new["camera.vfov_deg"]
    return {"now": [cam.hfov_deg, cam.vfov_deg], "exact": [round(h, 3), round(v, 3)], "tan_scale": round(k, 6),
            "check_m": round(m, 5), "replays": n, "set": f"--set camera.hfov_deg={h:.3f} --set camera.vfov_deg={v:.3f}",
            "toml": f"[camera] hfov_deg = {h:.3f}, vfov_deg = {v:.3f}"}


def suggestion(settings) -> tuple[str, str]:
    """(which correction, why): the quantity the configuration is less sure of."""
    if settings.camera.calibration:
        return "height", ("the focal length comes from [camera] calibration, a measurement; if that file is "
                          "old or from another lens, recalibrate it instead")
    return "fov", ("[camera] hfov_deg/vfov_deg are a lens's nominal values, often a few percent off, while a "
                   "height measured with a rule is good to ~1 mm (0.4 %); better still, calibrate the "
                   "intrinsics (crawlerd calibrate intrinsics) and then correct the height")


def drive_main(args) -> int:
    settings = load_settings(args)
    marks = Marks(args.start_frame, args.end_frame, args.start_time, args.end_time)
    known = float(args.length)
    with tempfile.TemporaryDirectory(prefix="crawlerd-drive-") as folder:
        replay = DriveReplay(args.video, args.pts, args.fps, marks, Path(folder))
        measured, start, end, between = replay.measure(settings)
        error_pct = 100 * (measured - known) / known
        if abs(error_pct) > IMPLAUSIBLE_PCT:
            from .calibrate import CalibrationFailed

            raise CalibrationFailed(
                f"measured {measured:.4f} m between frame {start['frame']} and frame {end['frame']} against "
                f"--length {known:g} m ({error_pct:+.1f} %): more than a camera height or FOV error makes; check "
                "--length, the marks, [mount] tilt_deg and [odometry] method")
        passed = abs(error_pct) <= args.tolerance
        summary = {
            "video": str(args.video), "known_m": known, "measured_m": round(measured, 5),
            "error_pct": round(error_pct, 4), "tolerance_pct": args.tolerance, "pass": passed,
            "start": {"frame": start["frame"], "t_s": start["t_s"]}, "end": {"frame": end["frame"], "t_s": end["t_s"]},
            "bridged_frames": sum(1 for r in between if r.get("bridged")),
            "method": settings.odometry.method, "tilt_deg": settings.mount.tilt_deg,
            "height": height_correction(settings, replay, measured, known),
            "fov": fov_correction(settings, replay, measured, known),
        }
    summary["suggest"], summary["why"] = suggestion(settings)
    print(json.dumps(summary) if args.json else drive_text(summary))
    return 0 if passed else 1


def drive_text(s: dict) -> str:
    """The summary as an operator reads it."""
    a, b = s["start"], s["end"]
    verdict = "PASS" if s["pass"] else "FAIL"
    h, f = s["height"], s["fov"]
    lines = [
        f"drive {Path(s['video']).name}: frames {a['frame']}..{b['frame']} ({a['t_s']:.3f} s .. {b['t_s']:.3f} s), "
        f"method {s['method']}, tilt {s['tilt_deg'] if isinstance(s['tilt_deg'], str) else format(s['tilt_deg'], 'g')} deg",
        f"  measured {s['measured_m']:.4f} m, taped {s['known_m']:.4f} m: error {s['error_pct']:+.3f} %   "
        f"{verdict} (limit +-{s['tolerance_pct']:g} %)",
    ]
    if s["bridged_frames"]:
        lines.append(f"  warning: {s['bridged_frames']} frames between the marks were bridged (no texture "
                     "tracked); drive the calibration over a textured stretch")
    lines.append("  to make it exact, change ONE of (the one you are less sure of):")
    lines.append(f"    camera height  {h['from']} {h['now']:.5f} m -> {h['exact']:.5f} m   {h['set']}"
                 f"   (replay: {h['check_m']:.4f} m)")
    if f is not None:
        lines.append(f"    field of view  [camera] hfov_deg {f['now'][0]:g} -> {f['exact'][0]:.3f}, vfov_deg "
                     f"{f['now'][1]:g} -> {f['exact'][1]:.3f}   {f['set']}   (replay: {f['check_m']:.4f} m)")
        lines.append(f"      (for the live camera: tan(FOV/2) of [camera] sensor_hfov_deg/sensor_vfov_deg "
                     f"times {f['tan_scale']:.5f})")
    else:
        lines.append("    field of view  set by [camera] calibration: recalibrate (crawlerd calibrate intrinsics) "
                     "rather than edit it")
    lines.append(f"  suggested: the {'camera height' if s['suggest'] == 'height' else 'field of view'}: {s['why']}")
    return "\n".join(lines)
