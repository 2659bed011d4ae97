"""Stress suite for "never lose distance": hw_sim runs with one hard disturbance each, replayed by crawlerd.

    python benchmarks/stress.py [--out DIR] [--jobs N] [--cases a,b] [--markdown] [--set SECTION.KEY=VALUE]
                                [--reseed N] [--wall skimage:brick|IMAGE]
                                [--held-out | --probes | --lobes | --stops | --independent]

Each case renders once (cached in --out; the .csv keeps the true tilt, camera height, LED light, wet
share and lost frames per frame) and is replayed with crawlerd's Daemon as `crawlerd --replay` would
(the .pts beside the video gives the frame times, so dropped frames leave real gaps). Prints per case
the true distance, the measured one, the error in percent of the path length, and the frames the
odometry lost. Not a test: it prints figures (docs/accuracy.md).
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

SHAKE = dict(bounce_mm=1.0, pitch_jitter_deg=0.3, roll_deg=2.0, sway_mm=1.5)
LIT = dict(lighting=True, vignetting=True, noise_sigma=1.5)


def wall_image(image: str) -> dict:
    """hw_sim fields for a photographed wall: a grey image file or skimage:brick|gravel|grass."""
    return dict(texture="image", texture_image=image, image_mm_per_px=0.4)


def photo() -> dict:
    """A photographic wall (scikit-image's gravel) if scikit-image is installed, else masonry."""
    if importlib.util.find_spec("skimage") is not None:
        return wall_image("skimage:gravel")
    print("stress: scikit-image missing (pip install -e '.[textures]'): the photo case uses masonry",
          file=sys.stderr)
    return dict(texture="masonry")


# name: (SimConfig fields, extra crawlerd --set overrides). Tilt is also the crawler's mount tilt.
CASES = {
    "wet-highlight-0deg-0.3": (dict(tilt_deg=0, speed_m_s=0.3, duration_s=12, seed=21,
                                    wet_patches=((0.8, 1.6), (2.4, 2.7)), **LIT), []),
    "blackout-24deg-0.4": (dict(tilt_deg=24, speed_m_s=0.4, duration_s=12, seed=22, exposure_ms=2.0,
                                led_blackouts=((3.0, 3.6), (7.0, 7.15)), **LIT), []),
    "drop-burst-40deg-0.1": (dict(tilt_deg=40, speed_m_s=0.1, duration_s=15, seed=23,
                                  dropped_bursts=((4.0, 4.8), (9.0, 9.3))), []),
    "crf35-masonry-shake-24deg-0.5": (dict(tilt_deg=24, speed_m_s=0.5, duration_s=10, seed=24, texture="masonry",
                                           crf=35, **SHAKE), []),
    "crf40-masonry-shake-24deg-0.5": (dict(tilt_deg=24, speed_m_s=0.5, duration_s=10, seed=24, texture="masonry",
                                           crf=40, **SHAKE), []),
    "reverse-stop-and-back-40deg-0.8": (dict(tilt_deg=40, profile="reverse", speed_m_s=0.8, accel_m_s2=1.0,
                                             duration_s=12, fps=60, seed=25), []),
    "photo-wall-0deg-0.2": (dict(tilt_deg=0, speed_m_s=0.2, duration_s=12, seed=26, **photo()), []),
    "all-at-once-24deg-0.4": (dict(tilt_deg=24, profile="stopgo", speed_m_s=0.4, stopgo_period_s=4.0,
                                   stopgo_dwell_s=0.8, duration_s=16, seed=28, texture="masonry", crf=38,
                                   wet_patches=((0.9, 1.5),), led_blackouts=((5.0, 5.5),),
                                   dropped_bursts=((9.0, 9.5),), exposure_ms=2.0, **SHAKE, **LIT), []),
}

# held out (--held-out): the same disturbances at other tilts and speeds, never tuned on
HELD_OUT = {
    "wet-highlight-40deg-0.2": ("wet-highlight-0deg-0.3", dict(tilt_deg=40, speed_m_s=0.2, seed=121)),
    "blackout-0deg-0.6": ("blackout-24deg-0.4", dict(tilt_deg=0, speed_m_s=0.6, seed=122)),
    "drop-burst-0deg-0.4": ("drop-burst-40deg-0.1", dict(tilt_deg=0, speed_m_s=0.4, seed=123)),
    "crf38-masonry-shake-40deg-0.3": ("crf35-masonry-shake-24deg-0.5", dict(tilt_deg=40, speed_m_s=0.3, crf=38,
                                                                             seed=124)),
    "all-at-once-0deg-0.3": ("all-at-once-24deg-0.4", dict(tilt_deg=0, speed_m_s=0.3, seed=128)),
    "all-at-once-40deg-0.5": ("all-at-once-24deg-0.4", dict(tilt_deg=40, speed_m_s=0.5, seed=129)),
}
for _name, (_base, _change) in HELD_OUT.items():
    CASES[_name] = ({**CASES[_base][0], **_change}, CASES[_base][1])
MAIN = [n for n in CASES if n not in HELD_OUT]


# probes (--probes): stands, reversals and ramps inside gaps, on photographed walls; each found a fault
PROBES = {
    "probe-drop-stopgo-24deg-0.3": dict(tilt_deg=24, profile="stopgo", speed_m_s=0.3, accel_m_s2=0.5,
                                        stopgo_period_s=4.0, stopgo_dwell_s=1.0, duration_s=16, seed=306,
                                        dropped_bursts=((2.5, 3.4), (6.8, 7.3), (11.0, 12.5)), texture="masonry",
                                        crf=30),
    "probe-reverse-all-brick-24deg-0.4": dict(tilt_deg=24, profile="reverse", speed_m_s=0.4, accel_m_s2=1.0,
                                              duration_s=15, seed=301, crf=35, wet_patches=((1.9, 2.3),),
                                              led_blackouts=((9.0, 9.6),), dropped_bursts=((12.0, 12.5),),
                                              exposure_ms=2.0, **SHAKE, **LIT, **wall_image("skimage:brick")),
    "probe-stopgo-wet-gravel-0deg-0.3": dict(tilt_deg=0, profile="stopgo", speed_m_s=0.3, accel_m_s2=0.8,
                                             stopgo_period_s=3.0, stopgo_dwell_s=0.7, duration_s=12, seed=404,
                                             wet_patches=((0.55, 0.75), (1.6, 1.9)), **LIT,
                                             **wall_image("skimage:gravel")),
    "probe-stopgo-blackout-grass-40deg-0.4": dict(tilt_deg=40, profile="stopgo", speed_m_s=0.4, accel_m_s2=0.6,
                                                  stopgo_period_s=4.0, stopgo_dwell_s=1.2, duration_s=16,
                                                  seed=406, led_blackouts=((2.5, 3.9), (10.9, 12.3)),
                                                  exposure_ms=2.0, **LIT, **wall_image("skimage:grass")),
    "probe-accel-drops-grass-24deg-60fps": dict(tilt_deg=24, profile="accel", speed_m_s=0.6, accel_m_s2=0.1,
                                                duration_s=10, fps=60, seed=403, **SHAKE, **wall_image("skimage:grass"),
                                                dropped_bursts=((2.0, 2.4), (5.0, 5.6), (8.0, 8.2))),
    "probe-slow-blackout-wet-brick-40deg-0.05": dict(tilt_deg=40, speed_m_s=0.05, duration_s=16, seed=402,
                                                     wet_patches=((0.3, 0.4),), exposure_ms=2.0,
                                                     led_blackouts=((2.0, 3.0), (11.0, 11.4)), **LIT,
                                                     **wall_image("skimage:brick")),
}
CASES.update({name: (fields, []) for name, fields in PROBES.items()})


def _lobe(tilt, speed, wall, seed, **more) -> dict:
    """A wet stretch under the LED's highlight, 0.15 m into the run and as long as 4 s of driving."""
    a = 0.15 + 0.1
    return dict(tilt_deg=tilt, speed_m_s=speed, duration_s=min(16.0, (a + 4 * speed + 0.35) / speed), seed=seed,
                wet_patches=((a, a + 4 * speed),), **LIT, **wall_image(f"skimage:{wall}"), **more)


# lobes (--lobes): a wet stretch under the LED's highlight that stays in the image, not saturated
# where the features are, on photographed walls, from a crawl to a walk
LOBES = {
    "lobe-brick-40deg-0.05": _lobe(40, 0.05, "brick", 501),
    "lobe-grass-40deg-0.05": _lobe(40, 0.05, "grass", 502),
    "lobe-gravel-24deg-0.05": _lobe(24, 0.05, "gravel", 503),
    "lobe-brick-0deg-0.1": _lobe(0, 0.1, "brick", 504),
    "lobe-grass-24deg-0.1": _lobe(24, 0.1, "grass", 505, wet_highlight=1.2, wet_highlight_deg=8.0),
    "lobe-brick-24deg-0.2": _lobe(24, 0.2, "brick", 506, wet_highlight_at=(480.0, 560.0)),
    "lobe-gravel-0deg-0.2": _lobe(0, 0.2, "gravel", 507, wet_highlight=1.0),
    "lobe-grass-40deg-0.1": _lobe(40, 0.1, "grass", 508, wet_highlight_at=(400.0, 600.0), wet_highlight=0.8),
    "lobe-brick-40deg-0.3": _lobe(40, 0.3, "brick", 509, wet_contrast=0.04),
    "lobe-gravel-40deg-0.03": _lobe(40, 0.03, "gravel", 510, wet_highlight_deg=10.0),
}
CASES.update({name: (fields, []) for name, fields in LOBES.items()})


def _stop(tilt, speed, wall, seed, period_s, dwell_s) -> dict:
    """A lobe whose crawler stops and goes (every period_s, standing dwell_s) inside its wet stretch."""
    return _lobe(tilt, speed, wall, seed, profile="stopgo", stopgo_period_s=period_s, stopgo_dwell_s=dwell_s)


# stops (--stops): the lobes' wet stretches with a crawler that stops and goes (0.5 m/s^2) inside them,
# written to look for faults: its stands are where a bridged stretch can only say them in its sigma
STOPS = {
    "stop-lobe-brick-0deg-0.1": _stop(0, 0.1, "brick", 601, 2.0, 0.6),
    "stop-lobe-brick-24deg-0.2": _stop(24, 0.2, "brick", 602, 2.0, 0.6),
    "stop-lobe-grass-40deg-0.1": _stop(40, 0.1, "grass", 603, 2.5, 1.0),
    "stop-lobe-gravel-0deg-0.2": _stop(0, 0.2, "gravel", 604, 2.0, 1.0),
    "stop-lobe-brick-0deg-0.1-long": _stop(0, 0.1, "brick", 605, 3.0, 1.5),
}
CASES.update({name: (fields, []) for name, fields in STOPS.items()})

# independent (--independent): five reviewers' sets, written without seeing the cases above
from independent import INDEPENDENT  # noqa: E402

CASES.update(INDEPENDENT)


def replay(h264: Path, overrides: list[str], log: Path) -> dict:
    from crawler import settings
    from crawler.service import Mode, RunOptions, Service

    options = RunOptions(mode=Mode.REPLAY, video=str(h264), log=str(log))
    with Service(settings.load(None, overrides), options) as svc:
        svc.run()
    return svc.summary()


def calibration(log: Path, csv: Path) -> dict:
    """Per frame: |measured - true| against the published sigma (the share within 2 sigma), and the
    worst deviation from the true trajectory in % of the path so far."""
    import numpy as np

    from hw_sim import read_ground_truth

    rows = [json.loads(line) for line in log.read_text().splitlines()]
    truth = read_ground_truth(csv)
    n = min(len(rows), len(truth))
    err = np.array([r["distance_m"] for r in rows[:n]]) - truth["distance_m"][:n]
    sigma = np.array([r.get("sigma_m") or 0.0 for r in rows[:n]])
    bridged = np.array([bool(r.get("bridged")) for r in rows[:n]])
    return {"within_2sigma": float(np.mean(np.abs(err) <= 2 * sigma)) if sigma.any() else None,
            "bridged_frames": int(bridged.sum()), "worst_err_m": float(np.max(np.abs(err)))}


def measure(args) -> dict:
    from accuracy import render

    out, name, common, reseed, wall = args
    fields, extra = CASES[name]
    fields = {**fields, "seed": fields["seed"] + reseed}     # another wall, shake and noise, same physics
    if wall:                                                 # ...or a photograph of a real one
        fields = {**fields, **wall_image(wall)}
    t0 = time.perf_counter()
    meta = json.loads(render(out, name, fields).read_text())
    t1 = time.perf_counter()
    tilt = meta["tilt_deg"]                   # the tilt at t = 0: what the crawler is mounted with
    log = out / f"{name}.log.jsonl"
    s = replay(out / f"{name}.h264", [f"mount.tilt_deg={tilt}", *extra, *common], log)
    cal = calibration(log, out / f"{name}.csv")
    return {**cal, "case": name, "tilt": tilt, "speed": fields["speed_m_s"], "frames": meta["frames"],
            "sensor_frames": meta["sensor_frames"], "true_m": meta["true_distance_m"],
            "path_m": meta["path_length_m"], "measured_m": s["distance_m"],
            "err_pct": 100 * (s["distance_m"] - meta["true_distance_m"]) / meta["path_length_m"],
            "lost": s["lost_frames"], "render_s": t1 - t0, "replay_s": time.perf_counter() - t1}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=str(ROOT / "out" / "stress"), help="where rendered runs are cached")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--markdown", action="store_true", help="print a Markdown table")
    ap.add_argument("--set", action="append", default=[], metavar="SECTION.KEY=VALUE",
                    help="config override for every case, e.g. odometry.method=plane")
    ap.add_argument("--cases", help="comma-separated subset of the cases")
    ap.add_argument("--reseed", type=int, default=0,
                    help="add this to every case's seed: the same disturbances on another wall (a held-out check)")
    ap.add_argument("--held-out", action="store_true",
                    help="the held-out variants instead: the same disturbances at other tilts and speeds")
    ap.add_argument("--probes", action="store_true",
                    help="the probe runs instead: stands, reversals and ramps inside gaps on photographed walls")
    ap.add_argument("--lobes", action="store_true",
                    help="the lobe runs instead: wet stretches under the LED's highlight, from a crawl to a walk")
    ap.add_argument("--stops", action="store_true",
                    help="the stop runs instead: a crawler that stops and goes inside the lobes' wet stretches")
    ap.add_argument("--independent", action="store_true",
                    help="five reviewers' independent sets instead (benchmarks/independent.py)")
    ap.add_argument("--wall", metavar="IMAGE",
                    help="every case on this photographed wall instead of its own texture: a grey image "
                         "file, or skimage:brick|gravel|grass (a held-out check)")
    args = ap.parse_args(argv)
    out = Path(args.out) if not args.reseed else Path(args.out) / f"reseed{args.reseed}"
    if args.wall:
        out = out / ("wall-" + Path(args.wall.split(":")[-1]).stem)
    if args.probes:
        out = out / "probes"
    if args.lobes:
        out = out / "lobes"
    if args.stops:
        out = out / "stops"
    if args.independent:
        out = out / "independent"

    out.mkdir(parents=True, exist_ok=True)
    names = (args.cases.split(",") if args.cases else list(HELD_OUT) if args.held_out
             else list(PROBES) if args.probes else list(LOBES) if args.lobes
             else list(STOPS) if args.stops else list(INDEPENDENT) if args.independent else MAIN)
    t0 = time.time()
    rows = []
    with ProcessPoolExecutor(args.jobs) as pool:
        for row in pool.map(measure, [(out, n, args.set, args.reseed, args.wall) for n in names]):
            rows.append(row)
            w2 = "-" if row["within_2sigma"] is None else f"{100 * row['within_2sigma']:.0f} %"
            print(f"[{time.time() - t0:6.0f} s] {row['case']:34s} {row['err_pct']:+8.3f} %  lost {row['lost']}  "
                  f"bridged {row['bridged_frames']}  within 2 sigma {w2}", file=sys.stderr)
    head = ["case", "tilt", "m/s", "frames", "true m", "measured m", "error % of path", "lost frames",
            "bridged frames", "within 2σ"]
    fmt, sep = ("| {} |", " | ") if args.markdown else ("{}", "  ")
    print(fmt.format(sep.join(head)))
    if args.markdown:
        print("|" + "---|" * len(head))
    for r in rows:
        print(fmt.format(sep.join([r["case"], f"{r['tilt']:g}", f"{r['speed']:g}",
                                   f"{r['frames']}/{r['sensor_frames']}", f"{r['true_m']:.4f}",
                                   f"{r['measured_m']:.4f}", f"{r['err_pct']:+.3f}", str(r["lost"]),
                                   str(r["bridged_frames"]),
                                   "-" if r["within_2sigma"] is None else f"{100 * r['within_2sigma']:.0f} %"])))
    errs = [abs(r["err_pct"]) for r in rows]
    print(f"mean |error| {sum(errs) / len(errs):.3f} %   max {max(errs):.3f} %")
    (out / "results.json").write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
