"""crawlerd calibrate check: the tilt and camera height the flow shows, against the configured ones.

A recording (or N seconds of the live camera) is measured through the same Service as a run, with
`[mount] tilt_deg = "auto"` (crawler/autotilt.py): the tilt the tracks agree on best is the camera's.
The camera height cannot be seen that way (a camera twice as high over a wall twice as far sees the
same flow): only the pipe's curvature shows it, as the features across the image disagreeing on
the step at a wrong height. So it is searched for over the steps the tilt estimate kept, at the
tilt found, and said with its uncertainty; where that is wider than the tolerance, the height is
not judged (calibrate drive measures it, over a taped length). docs/calibration.md.
"""

from __future__ import annotations

import argparse
import json
import math
from dataclasses import replace

import numpy as np

from .errors import BadConfig

TILT_TOL_DEG = 0.5          # 0.5 deg at 24 deg of tilt is ~0.8 % of every metre
HEIGHT_TOL_MM = 3.0         # ~1.3 % of the thesis car's 0.226 m
HEIGHT_SPAN = 0.3           # the height is searched within +-30 % of the configured one
MIN_STEPS = 6               # keyframe steps needed to say anything of the height


def add_check_arguments(p):
    from .calibrate import _number, _whole, add_replay_arguments

    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("video", nargs="?", metavar="VIDEO", help="a recording of a drive (.h264, .mp4, .mkv)")
    src.add_argument("--live", type=_number(1, 3600, "seconds"), metavar="SECONDS",
                     help="measure the live camera for this long instead (the crawler driving)")
    p.add_argument("--sim", action="store_true", help="with --live: hw_sim's simulated camera (--sim-tilt)")
    p.add_argument("--sim-tilt", type=_number(-80, 80, "degrees"), metavar="DEG",
                   help="with --sim: the simulated camera's real tilt")
    add_replay_arguments(p)
    p.add_argument("--tilt-tolerance", type=_number(0.01, 20, "degrees"), default=TILT_TOL_DEG, metavar="DEG",
                   help=f"PASS when the tilt found is within DEG of the configured ({TILT_TOL_DEG:g})")
    p.add_argument("--height-tolerance", type=_number(0.1, 100, "millimetres"), default=HEIGHT_TOL_MM,
                   metavar="MM", help=f"PASS when the height is within MM of the configured ({HEIGHT_TOL_MM:g})")
    p.add_argument("--max-frames", type=_whole(1), metavar="N", help=argparse.SUPPRESS)
    p.add_argument("--json", action="store_true", help="print the summary as one JSON object")


def check_main(args, hardware=None) -> int:
    from .calibrate_drive import load_settings

    args.tilt, args.method = None, None
    configured = load_settings(args)
    if configured.odometry.method == "pixel":
        raise BadConfig('calibrate check needs [odometry] method = "cylinder" or "plane": the pixel method has '
                        "no tilt")
    estimator, summary = measure(configured.with_values({"mount.tilt_deg": "auto"}, "calibrate check"), args,
                                 hardware)
    result = verdict(configured, estimator, summary, args)
    print(json.dumps(result) if args.json else check_text(result))
    return 0 if result["pass"] else 1


def measure(settings, args, hardware=None):
    """Run the recording or the live camera with tilt auto: (the pose estimator, the run's summary)."""
    from .service import Mode, RunOptions, Service
    from .sim import SimOptions

    if args.video is not None:
        options = RunOptions(mode=Mode.REPLAY, video=args.video, pts=args.pts, fps=args.fps,
                             max_frames=args.max_frames)
    else:
        mode = Mode.SIM if args.sim else Mode.CAMERA
        fps = settings.camera.fps
        options = RunOptions(mode=mode, publish=False, max_frames=args.max_frames or int(args.live * fps),
                             sim=SimOptions(tilt_deg=args.sim_tilt))
        settings = settings.with_values({"state.directory": _scratch_state()}, "calibrate check")
    with Service(settings, options, hardware) as svc:
        svc.run()
        return svc.odometer.pose, svc.summary()


def _scratch_state() -> str:
    import tempfile

    return tempfile.mkdtemp(prefix="crawlerd-check-")


def verdict(configured, estimator, summary: dict, args) -> dict:
    """Tilt and height found against the configured ones, and the --set items that fix the config."""
    mount = configured.mount
    tilt = estimator.tilt
    found = getattr(tilt, "track", None) is not None
    est_tilt, sigma = estimator.tilt_deg, math.degrees(tilt.sigma_rad)
    out = {"source": summary.get("source"), "frames": summary.get("frames"), "distance_m": summary.get("distance_m"),
           "tilt": {"configured_deg": mount.tilt_deg, "estimated_deg": round(est_tilt, 3) if found else None,
                    "sigma_deg": round(sigma, 3) if found else None, "tolerance_deg": args.tilt_tolerance,
                    "steps": tilt.steps}}
    fix = []
    if not found:
        out["tilt"]["verdict"] = "UNDETERMINED"
        out["tilt"]["why"] = ("the tilt was not found: the features never moved far enough (drive the crawler at "
                              "least 0.1 m over textured wall, and keep it moving)")
    elif mount.tilt_auto:
        out["tilt"]["verdict"] = "INFO"
        fix.append(f"mount.tilt_deg={est_tilt:.1f}")
    else:
        ok = abs(est_tilt - mount.tilt_deg) <= args.tilt_tolerance + 2 * sigma
        out["tilt"]["verdict"] = "PASS" if ok else "FAIL"
        if not ok:
            fix.append(f"mount.tilt_deg={est_tilt:.1f}")
    out["height"] = height_verdict(configured, estimator, args.height_tolerance / 1000.0, fix)
    out["set"] = fix
    out["pass"] = out["tilt"]["verdict"] in ("PASS", "INFO") and out["height"]["verdict"] != "FAIL"
    return out


def height_verdict(configured, estimator, tol_m: float, fix: list) -> dict:
    h_cfg = configured.mount.mount().height_m
    hops = list(getattr(estimator.tilt, "hops", ()))
    out = {"configured_m": round(h_cfg, 5), "estimated_m": None, "sigma_m": None, "tolerance_m": tol_m}
    if len(hops) < MIN_STEPS or getattr(estimator.tilt, "track", None) is None:
        out.update(verdict="UNDETERMINED", why=f"{len(hops)} keyframe steps at the tilt found; {MIN_STEPS} are needed")
        return out
    proj = estimator.projection
    m = replace(proj.mount, tilt_rad=proj.mount.tilt_rad + estimator.tilt.tau)
    samples = [(h.xy_k, h.xy_c) for h in hops]
    best = [height_search(type(proj), m, part) for part in (samples[0::2], samples[1::2])]
    est = height_search(type(proj), m, samples)
    # the halves' disagreement, never below 1 % of the height (short drives are biased by a few mm)
    sigma = max(abs(best[0] - best[1]) / 2.0, 0.01 * h_cfg)
    out.update(estimated_m=round(est, 5), sigma_m=round(sigma, 5))
    if abs(est - h_cfg) > tol_m + 2 * sigma:       # off by more than its uncertainty can explain
        out["verdict"] = "FAIL"
        fix.append(f"mount.height_m={est:.4f}")
    elif sigma > tol_m:
        out.update(verdict="UNDETERMINED", why=f"the pipe's curvature shows the height only to +-{1000 * sigma:.1f} mm "
                   "in this recording; measure it with crawlerd calibrate drive")
    else:
        out["verdict"] = "PASS"
    return out


def height_search(kind, mount, samples) -> float:
    """The camera height at which the features across the pipe agree best on their steps."""
    from .tiltfit import disagreement

    def cost(h):
        return sum(disagreement(kind(replace(mount, height_m=float(h))), *s) for s in samples)

    h0 = mount.height_m
    grid = h0 * (1 + np.linspace(-HEIGHT_SPAN, HEIGHT_SPAN, 31))
    grid = grid[grid < 2 * mount.pipe_radius_m * 0.98]
    c = np.array([cost(h) for h in grid])
    i = int(np.clip(np.argmin(c), 1, len(c) - 2))
    fine = np.linspace(grid[i - 1], grid[i + 1], 9)
    cf = np.array([cost(h) for h in fine])
    j = int(np.clip(np.argmin(cf), 1, len(cf) - 2))
    c0, c1, c2 = cf[j - 1:j + 2]
    den = c0 - 2 * c1 + c2
    shift = 0.5 * (c0 - c2) / den if den > 0 else 0.0
    return float(fine[j] + np.clip(shift, -1, 1) * (fine[1] - fine[0]))


def check_text(s: dict) -> str:
    """The summary as an operator reads it."""
    t, h = s["tilt"], s["height"]
    lines = [f"check {s['source']}: {s['frames']} frames, {s['distance_m']:.3f} m"]
    if t["estimated_deg"] is None:
        lines.append(f"  tilt   configured {t['configured_deg']}, not found   {t['verdict']}: {t['why']}")
    else:
        lines.append(f"  tilt   configured {t['configured_deg']} deg, found {t['estimated_deg']:.2f} +- "
                     f"{t['sigma_deg']:.2f} deg   {t['verdict']} (limit +-{t['tolerance_deg']:g} deg)")
    if h["estimated_m"] is None or h["verdict"] == "UNDETERMINED":
        lines.append(f"  height configured {h['configured_m']:.4f} m   {h['verdict']}: {h['why']}")
    else:
        lines.append(f"  height configured {h['configured_m']:.4f} m, found {h['estimated_m']:.4f} +- "
                     f"{h['sigma_m']:.4f} m   {h['verdict']} (limit +-{1000 * h['tolerance_m']:g} mm)")
    if s["set"]:
        lines.append("fix: " + " ".join(f"--set {item}" for item in s["set"]) + "   (or in the config: "
                     + "; ".join(_toml(item) for item in s["set"]) + ")")
    lines.append("PASS" if s["pass"] else "FAIL")
    return "\n".join(lines)


def _toml(item: str) -> str:
    key, value = item.split("=", 1)
    section, name = key.split(".", 1)
    return f"[{section}] {name} = {value}"
