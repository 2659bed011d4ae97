"""The camera's pose from the flow (issue 14): tilt auto, a tilt step, shake runs. Prints figures.

    python benchmarks/pose.py [--out DIR] [--jobs N] [--only tilt,table,step,sweep,stand,shake,ride,fixed,both] [--markdown]

Every case is an hw_sim recording (cached in --out, with the true tilt and camera height per frame
in its CSV) replayed by crawlerd's Service as `crawlerd --replay` would:

- tilt:  still-mounted runs at 0, 24 and 40 deg with `[mount] tilt_deg = "auto"`: the tilt found
         after 2 s and at the end, and when it came within 0.3 deg to stay;
- table: benchmarks/accuracy.py's cases (cylinder) with tilt auto: error in % of the path;
- step:  the operator turns the camera 24 -> 40 deg mid-run (a step and a 0.3 s turn), tilt auto;
- sweep: the operator turns it slowly (24 -> 40 deg over 6 s, 24 -> 30 over 8 s, 40 -> 10 over 3 s,
         and 24 -> 34 over 4 s on a shaking car), tilt auto;
- stand: the crawler stops, the operator turns the camera (over 2 s, 0.3 s, 1.5 s; out and back;
         on a shaking car; over 0.3 and 1.5 s with a rolling shutter; on three photographed walls at CRF 28)
         and drives on, or turns it while creeping at 2, 5 and 10 cm/s, tilt auto;
- shake: suspension bounce, pitch jitter, roll and sway at several tilts and speeds: configured
         tilt with the pose estimator on (shake) and off (shake-off, the default), and tilt auto: final error and the worst deviation from the
         true trajectory mid-run, in % of the path (and of the path so far, after its first 0.2 m);
- both:  tilt auto with the pose estimator on too (`estimate_pose = true`): the still, shake and
         table runs (not in the default --only);
- ride:  the shake runs (the sediment among them) and the table with the ride height's level off
         (`[odometry] ride_height = false`; unset, it is on with a configured tilt up to 30 deg);
- fixed: benchmarks/accuracy.py's cases with the configured tilt, pose estimator on (fixed) and off
         (fixed-off: the default, benchmarks/accuracy.py's cylinder column).

Not a test: it prints figures (docs/accuracy.md, "Pose").
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

SHAKE = dict(bounce_mm=1.0, pitch_jitter_deg=0.3, roll_deg=3.0, sway_mm=2.0)
BIG_SHAKE = dict(bounce_mm=2.0, pitch_jitter_deg=0.6, pitch_jitter_hz=1.5, bounce_hz=2.5, roll_deg=3.0, sway_mm=3.0)
ON = ["odometry.estimate_pose=true"]      # pitch and height per frame (the default with a configured tilt)
OFF = ["odometry.estimate_pose=false"]
RIDE_OFF = "odometry.ride_height=false"        # the ride height over sediment off (unset: on up to 30 deg)

TILT_CASES = {f"still-{t}deg-{v}": dict(tilt_deg=t, speed_m_s=v, duration_s=d, seed=30 + t)
              for t in (0, 24, 40) for v, d in ((0.04, 12), (0.3, 6))}
STEP_CASES = {
    "step-24-40-0.2": dict(tilt_deg=24, tilt_schedule=((4.0, 24.0), (4.0001, 40.0)), speed_m_s=0.2, duration_s=10,
                           seed=41),
    "turn-24-40-0.2": dict(tilt_deg=24, tilt_schedule=((4.0, 24.0), (4.3, 40.0)), speed_m_s=0.2, duration_s=10,
                           seed=42),
}
SWEEP_CASES = {                           # the operator turns the camera slowly: too slow for a step
    "sweep-24-40-0.2": dict(tilt_deg=24, tilt_schedule=((3.0, 24.0), (9.0, 40.0)), speed_m_s=0.2, duration_s=12,
                            seed=71),
    "sweep-24-30-0.1": dict(tilt_deg=24, tilt_schedule=((2.0, 24.0), (10.0, 30.0)), speed_m_s=0.1, duration_s=12,
                            seed=72),
    "sweep-40-10-0.3": dict(tilt_deg=40, tilt_schedule=((2.0, 40.0), (5.0, 10.0)), speed_m_s=0.3, duration_s=8,
                            seed=73),
    "sweep-shake-24-34-0.2": dict(tilt_deg=24, tilt_schedule=((3.0, 24.0), (7.0, 34.0)), speed_m_s=0.2,
                                  duration_s=10, seed=74, **SHAKE),
}
STAND = dict(profile="stopgo", stopgo_period_s=6.0, stopgo_dwell_s=3.0, duration_s=11.0)   # stands 3-6 s
STAND_CASES = {                           # the operator stops, turns the camera to inspect, drives on
    "stand-turn-24-34": dict(tilt_deg=24, tilt_schedule=((3.5, 24.0), (5.5, 34.0)), speed_m_s=0.3, seed=81, **STAND),
    "stand-turn-fast-24-34": dict(tilt_deg=24, tilt_schedule=((4.0, 24.0), (4.3, 34.0)), speed_m_s=0.3, seed=82,
                                  **STAND),
    "stand-turn-40-20": dict(tilt_deg=40, tilt_schedule=((3.4, 40.0), (4.9, 20.0)), speed_m_s=0.2, seed=83, **STAND),
    "stand-turn-back-24-34": dict(tilt_deg=24, tilt_schedule=((3.3, 24.0), (4.3, 34.0), (4.8, 34.0), (5.6, 24.0)),
                                  speed_m_s=0.3, seed=84, **STAND),
    "stand-turn-shake-24-36": dict(tilt_deg=24, tilt_schedule=((3.5, 24.0), (5.0, 36.0)), speed_m_s=0.25, seed=85,
                                   **STAND, **SHAKE),
    "stand-turn-fast-rs-24-34": dict(tilt_deg=24, tilt_schedule=((4.0, 24.0), (4.3, 34.0)), speed_m_s=0.3, seed=87,
                                     readout_ms=10.0, **STAND),   # a rolling shutter: rows turned further
    "stand-turn-rs-24-34": dict(tilt_deg=24, tilt_schedule=((3.4, 24.0), (4.9, 34.0)), speed_m_s=0.3, seed=89,
                                readout_ms=10.0, **STAND),
    **{f"stand-turn-{wall}-{a}-{b}": dict(tilt_deg=a, tilt_schedule=((3.4, a), (3.4 + s, b)), speed_m_s=v, seed=90 + i,
                                         texture="image", texture_image=f"skimage:{wall}", image_mm_per_px=0.4,
                                         crf=28, **STAND)      # photographed walls at CRF 28
       for i, (wall, a, b, s, v) in enumerate((("brick", 24, 34, 1.5, 0.3), ("grass", 40, 28, 1.0, 0.2),
                                               ("gravel", 12, 30, 2.0, 0.25)))},
    # ...or while it creeps on
    "creep-turn-0.02-40-25": dict(tilt_deg=40, tilt_schedule=((4.0, 40.0), (5.0, 25.0)), speed_m_s=0.02,
                                  duration_s=9, seed=97),
    "creep-turn-0.05-24-34": dict(tilt_deg=24, tilt_schedule=((3.0, 24.0), (5.0, 34.0)), speed_m_s=0.05,
                                  duration_s=9, seed=95),
    "creep-turn-0.1-24-34": dict(tilt_deg=24, tilt_schedule=((3.0, 24.0), (4.5, 34.0)), speed_m_s=0.1,
                                 duration_s=8, seed=96),
}
SHAKE_CASES = {
    **{f"shake-{t}deg-{v}": dict(tilt_deg=t, speed_m_s=v, duration_s=d, seed=50 + t, **SHAKE)
       for t in (0, 24, 40) for v, d in ((0.04, 20), (0.3, 8))},
    "big-shake-24deg-0.1": dict(tilt_deg=24, speed_m_s=0.1, duration_s=12, seed=61, **BIG_SHAKE),
    "big-shake-40deg-0.3": dict(tilt_deg=40, speed_m_s=0.3, duration_s=8, seed=62, **BIG_SHAKE),
    "sediment-24deg-0.2": dict(tilt_deg=24, speed_m_s=0.2, duration_s=12, seed=63, bounce_mm=0.5,
                               height_profile=((0.8, 0.0), (1.1, 15.0), (1.7, 15.0), (2.0, 0.0))),
}


def _readout(fields: dict) -> list:
    """A rolling-shutter render is replayed with its readout time configured, as on the crawler."""
    return [f"camera.readout_ms={fields['readout_ms']}"] if fields.get("readout_ms") else []


def render(out: Path, name: str, fields: dict) -> dict:
    """The run's sidecar, rendered once (accuracy.py's cache)."""
    from accuracy import render as cached

    return json.loads(cached(out, name, fields).read_text())


def replay(out: Path, name: str, overrides: list[str]) -> dict:
    """Replay with a per-frame log; the errors against the CSV's truth."""
    import numpy as np

    from crawler import settings
    from crawler.service import Mode, RunOptions, Service
    from hw_sim import read_ground_truth

    log = out / f"{name}.{abs(hash(tuple(overrides))) % 10 ** 8}.jsonl"
    options = RunOptions(mode=Mode.REPLAY, video=str(out / f"{name}.h264"), log=str(log))
    with Service(settings.load(None, overrides), options) as svc:
        svc.run()
        summary = svc.summary()
    rows = [json.loads(line) for line in log.read_text().splitlines()]
    log.unlink()
    truth = read_ground_truth(out / f"{name}.csv")
    n = min(len(rows), len(truth))
    true = truth["distance_m"][:n]
    err = np.array([r["distance_m"] for r in rows[:n]]) - true
    path = np.concatenate([[0.0], np.cumsum(np.abs(np.diff(true)))])
    late = path >= 0.2
    return {"summary": summary, "t": truth["t_s"][:n], "err": err, "path": path, "total": path[-1],
            "final_pct": 100 * err[-1] / path[-1], "worst_pct": 100 * np.abs(err).max() / path[-1],
            "worst_so_far_pct": 100 * float(np.max(np.abs(err[late]) / path[late])) if late.any() else None,
            "true_tilt": truth["tilt_deg"][:n], "tilts": [r.get("tilt_deg") for r in rows[:n]]}


def _render(job):
    render(*job)


def measure(job) -> dict:
    out, kind, name, fields, overrides = job
    meta = render(out, name, fields)
    r = replay(out, name, overrides)
    pose = r["summary"].get("pose", {})
    row = {"kind": kind, "case": name, "tilt": fields.get("tilt_deg"), "speed": fields.get("speed_m_s"),
           "true_m": meta["true_distance_m"], "final_pct": r["final_pct"], "worst_pct": r["worst_pct"],
           "worst_so_far_pct": r["worst_so_far_pct"], "lost": r["summary"]["lost_frames"],
           "tilt_end": pose.get("tilt_deg"), "tilt_sigma": pose.get("tilt_sigma_deg"), "overrides": overrides}
    if any(o.startswith("mount.tilt_deg=auto") for o in overrides):
        row.update(_tilt_timing(r))
    return row


def _tilt_timing(r) -> dict:
    """The tilt found 2 s after the start (or after a step), and when it came within 0.3 deg to stay."""
    import numpy as np

    t, true = r["t"], np.asarray(r["true_tilt"])
    est = np.array([np.nan if x is None else x for x in r["tilts"]], dtype=float)
    off = np.abs(est - true)
    change = np.flatnonzero(np.abs(np.diff(true)) > 1.0)
    t0 = t[change[-1] + 1] if len(change) else t[0]
    bad = np.flatnonzero(~(off <= 0.3) & (t >= t0))
    settled = t[bad[-1] + 1] - t0 if len(bad) and bad[-1] + 1 < len(t) else (0.0 if not len(bad) else None)
    at2 = np.searchsorted(t, t0 + 2.0)
    return {"tilt_at_2s": float(est[min(at2, len(est) - 1)]), "true_end": float(true[-1]),
            "settled_s": None if settled is None else float(settled)}


def jobs(out: Path, only: set) -> list:
    from accuracy import CASES

    todo = []
    if "tilt" in only:
        todo += [(out, "tilt", n, f, ["mount.tilt_deg=auto"]) for n, f in TILT_CASES.items()]
    if "table" in only:
        todo += [(out, "table", n, f, ["mount.tilt_deg=auto", *x]) for n, (f, x) in CASES.items()]
    if "step" in only:
        todo += [(out, "step", n, f, ["mount.tilt_deg=auto"]) for n, f in STEP_CASES.items()]
        todo += [(out, "step-fixed", n, f, ["mount.tilt_deg=24"]) for n, f in STEP_CASES.items()]
    if "sweep" in only:
        todo += [(out, "sweep", n, f, ["mount.tilt_deg=auto"]) for n, f in SWEEP_CASES.items()]
    if "stand" in only:
        todo += [(out, "stand", n, f, ["mount.tilt_deg=auto"] + _readout(f)) for n, f in STAND_CASES.items()]
    if "shake" in only:
        for n, f in SHAKE_CASES.items():
            tilt = f"mount.tilt_deg={f['tilt_deg']}"
            todo += [(out, "shake", n, f, [tilt, *ON]), (out, "shake-off", n, f, [tilt, *OFF]),
                     (out, "shake-auto", n, f, ["mount.tilt_deg=auto"])]
    if "both" in only:                             # tilt auto and the pose estimator together
        both = ["mount.tilt_deg=auto", *ON]
        todo += [(out, "both", n, f, both) for n, f in {**TILT_CASES, **SHAKE_CASES}.items()]
        todo += [(out, "both", n, f, [*both, *x]) for n, (f, x) in CASES.items()]
    if "ride" in only:                             # [odometry] ride_height = false: shake runs, then the table
        todo += [(out, "ride-off", n, f, [f"mount.tilt_deg={f['tilt_deg']}", *ON, RIDE_OFF])
                 for n, f in SHAKE_CASES.items()]
        todo += [(out, "ride-off", n, f, [f"mount.tilt_deg={f.get('tilt_deg', 0)}", *x, *ON, RIDE_OFF])
                 for n, (f, x) in CASES.items()]
    if "fixed" in only:
        todo += [(out, "fixed", n, f, [f"mount.tilt_deg={f.get('tilt_deg', 0)}", *x, *ON])
                 for n, (f, x) in CASES.items()]
        todo += [(out, "fixed-off", n, f, [f"mount.tilt_deg={f.get('tilt_deg', 0)}", *x, *OFF])
                 for n, (f, x) in CASES.items()]
    return todo


def report(rows: list, markdown: bool):
    fmt, sep = ("| {} |", " | ") if markdown else ("{}", "  ")

    def num(v, f="{:+.4f}"):
        return "-" if v is None else f.format(v)

    kinds = []
    for r in rows:
        if r["kind"] not in kinds:
            kinds.append(r["kind"])
    for kind in kinds:
        sub = [r for r in rows if r["kind"] == kind]
        print(f"\n{kind} ({' '.join(sub[0]['overrides'])})")
        head = ["case", "final %", "worst % of path", "worst % so far", "lost", "tilt end", "sigma", "at 2 s",
                "within 0.3 deg after s"]
        print(fmt.format(sep.join(head)))
        if markdown:
            print("|" + "---|" * len(head))
        for r in sub:
            print(fmt.format(sep.join([r["case"], num(r["final_pct"]), num(r["worst_pct"], "{:.4f}"),
                                       num(r["worst_so_far_pct"], "{:.4f}"), str(r["lost"]),
                                       num(r.get("tilt_end"), "{:.3f}"), num(r.get("tilt_sigma"), "{:.3f}"),
                                       num(r.get("tilt_at_2s"), "{:.3f}"), num(r.get("settled_s"), "{:.2f}")])))
        finals = [abs(r["final_pct"]) for r in sub]
        worst = [r["worst_pct"] for r in sub]
        print(f"  mean |final| {sum(finals) / len(finals):.4f} %   max |final| {max(finals):.4f} %   "
              f"max worst {max(worst):.4f} %")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=str(ROOT / "out" / "pose"), help="where rendered runs are cached")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--only", default="tilt,table,step,sweep,stand,shake,ride,fixed")
    ap.add_argument("--cases", help="comma-separated subset of the case names")
    ap.add_argument("--markdown", action="store_true")
    args = ap.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    todo = jobs(out, set(args.only.split(",")))
    if args.cases:
        todo = [j for j in todo if j[2] in args.cases.split(",")]
    t0 = time.time()
    rows = []
    unique = {name: (out, name, fields) for out, _, name, fields, _ in todo}
    with ProcessPoolExecutor(args.jobs) as pool:
        list(pool.map(_render, unique.values()))       # each case once: two jobs must not write one file
        for row in pool.map(measure, todo):
            rows.append(row)
            print(f"[{time.time() - t0:6.0f} s] {row['kind']:10s} {row['case']:30s} final {row['final_pct']:+.4f} %  "
                  f"worst {row['worst_pct']:.4f} %  tilt {row.get('tilt_end')}", file=sys.stderr)
    report(rows, args.markdown)
    (out / "results.json").write_text(json.dumps(rows, indent=1, default=str))


if __name__ == "__main__":
    main()
