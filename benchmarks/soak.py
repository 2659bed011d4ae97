"""A long `crawlerd --sim` run: worst frame-loop iteration, memory, error against the simulator; and
the distance a kill -9 loses.

    python benchmarks/soak.py [--minutes 10] [--speed 0.4] [--profile stopgo] [--kills 0]
    python benchmarks/soak.py --cpu-frames 2400      # the loop's wall time against its own CPU time

Starts the real daemon as a subprocess on loopback Zenoh (multicast off), listens to its status once a
second (loop latency, fps, sim error) and samples its memory every 5 s, then stops it with SIGTERM and
prints the summary's loop figures. With --kills N it first kills the daemon N times with SIGKILL, at
varied moments once it measures, restarting it each time, and reports the distance each kill lost:
the last distance the operator received before the kill against the checkpoint the next run resumes
from (negative: the checkpoint was written after the last sample that arrived, nothing was lost).
The loop figures are wall time on this machine, shared with whatever else runs: the load average is
printed with them. --cpu-frames N runs the same daemon in-process for N frames instead and times each
loop iteration twice, in wall time and in the loop thread's own CPU time: an iteration whose wall
time is far above its CPU time was waiting (for a core, or for the GIL that the simulated camera's
render thread holds), not working. Not a test: it prints figures (docs/reliability.md).
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
KILL_DELAYS_S = (0.53, 1.27, 0.91, 2.11, 1.68, 0.37, 2.49, 1.05, 1.83, 0.74)   # after measuring starts


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def start(state: Path, port: int, args, log) -> subprocess.Popen:
    """The daemon; its log goes to a file (a pipe nobody reads would block it once full)."""
    env = dict(os.environ, CRAWLERD_CONFIG=os.devnull)
    return subprocess.Popen(
        [sys.executable, "-m", "crawler", "--sim", "--sim-speed", str(args.speed), "--sim-profile", args.profile,
         "--no-multicast", "--listen", f"tcp/127.0.0.1:{port}", "--state-dir", str(state)],
        stdout=subprocess.PIPE, stderr=log, text=True, env=env, cwd=ROOT)


def rss_mb(pid: int) -> float:
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    except OSError:
        pass
    return float("nan")


def wait_for(predicate, timeout_s: float) -> bool:
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        if predicate():
            return True
        time.sleep(0.02)
    return predicate()


def kill_loop(args, state, port, dist, log) -> list[float]:
    """Kill -9 the daemon `args.kills` times; the distance each kill lost (m)."""
    losses = []
    for k in range(args.kills):
        dist.clear()
        proc = start(state, port, args, log)
        if not wait_for(lambda: len(dist) > 10, 120):
            raise SystemExit(f"kill {k + 1}: the daemon published nothing; see {log.name}")
        time.sleep(KILL_DELAYS_S[k % len(KILL_DELAYS_S)])
        last = dist[-1]["distance_m"]
        proc.kill()
        proc.communicate()
        saved = json.loads((state / "checkpoint.json").read_text())["distance_m"]
        losses.append(last - saved)
        print(f"kill {k + 1}: last received {last:.4f} m, checkpoint {saved:.4f} m, lost "
              f"{1000 * (last - saved):+.1f} mm", file=sys.stderr)
    return losses


def soak(args, state, port, status, log) -> tuple[dict, list[float]]:
    """Run the daemon for `args.minutes`, then SIGTERM; its summary and the memory samples."""
    proc = start(state, port, args, log)
    t_end, rss = time.monotonic() + args.minutes * 60, []
    while time.monotonic() < t_end and proc.poll() is None:
        time.sleep(5.0)
        rss.append(rss_mb(proc.pid))
        if status:
            s = status[-1]
            print(f"{s['uptime_s']:7.0f} s  fps {s['fps']:6.1f}  loop max {s['loop_ms']['max']:6.2f} ms  "
                  f"p99 {s['loop_ms']['p99']:5.2f} ms  rss {rss[-1]:6.1f} MB  sim error "
                  f"{1000 * (s['distance_m'] - s.get('sim_true_distance_m', s['distance_m'])):+.1f} mm",
                  file=sys.stderr)
    if proc.poll() is not None:
        raise SystemExit(f"the daemon ended early (exit {proc.returncode}); see {log.name}")
    proc.send_signal(signal.SIGTERM)
    out, _ = proc.communicate(timeout=60)
    return json.loads(out.strip().splitlines()[-1]), rss


def cpu_split(args) -> dict:
    """The daemon in-process for args.cpu_frames frames: each iteration's wall and thread CPU time (ms)."""
    import numpy as np

    from crawler import settings
    from crawler.service import Mode, RunOptions, Service
    from crawler.sim import SimOptions

    st = settings.load(None, [f"state.directory={json.dumps(tempfile.mkdtemp(prefix='soak-cpu-'))}",
                              "zenoh.multicast=false", f'zenoh.listen=["tcp/127.0.0.1:{free_port()}"]'])
    options = RunOptions(mode=Mode.SIM, max_frames=args.cpu_frames, publish=True,
                         sim=SimOptions(speed_m_s=args.speed, profile=args.profile))
    wall, cpu = [], []
    with Service(st, options) as svc:
        step = svc.daemon._step

        def timed(frame):
            t0, c0 = time.perf_counter(), time.thread_time()
            step(frame)
            wall.append(1000 * (time.perf_counter() - t0))
            cpu.append(1000 * (time.thread_time() - c0))

        svc.daemon._step = timed
        svc.run()
    wall, cpu = np.array(wall), np.array(cpu)
    worst = int(np.argmax(wall))
    return {"frames": len(wall), "wall_ms": {"max": round(wall.max(), 2), "p99": round(np.percentile(wall, 99), 2)},
            "cpu_ms": {"max": round(cpu.max(), 2), "p99": round(np.percentile(cpu, 99), 2)},
            "worst_wall_iteration_cpu_ms": round(cpu[worst], 2),
            "load_avg_1min": round(os.getloadavg()[0], 2), "cpus": os.cpu_count()}


def main(argv=None):
    import zenoh

    from crawler.link import make_zenoh_config

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--minutes", type=float, default=10.0)
    ap.add_argument("--speed", type=float, default=0.4)
    ap.add_argument("--profile", default="stopgo")
    ap.add_argument("--kills", type=int, default=0, help="SIGKILL and restart the daemon this many times")
    ap.add_argument("--cpu-frames", type=int, default=0, metavar="N",
                    help="instead: N frames in-process, each iteration's wall against its CPU time")
    args = ap.parse_args(argv)
    if args.cpu_frames:
        print(json.dumps(cpu_split(args)))
        return
    port, work = free_port(), Path(tempfile.mkdtemp(prefix="soak-"))
    status, dist = [], []
    op = zenoh.open(make_zenoh_config("peer", connect=[f"tcp/127.0.0.1:{port}"], multicast=False))
    op.declare_subscriber("crawler/crawler1/status", lambda s: status.append(json.loads(s.payload.to_string())))
    op.declare_subscriber("crawler/crawler1/distance", lambda s: dist.append(json.loads(s.payload.to_string())))
    load_before = os.getloadavg()
    try:
        with open(work / "crawlerd.log", "w") as log:
            losses = kill_loop(args, work / "killed", port, dist, log)
            # a state of its own: a resumed simulator counts the distance it travelled while we were down
            summary, rss = soak(args, work / "soak", port, status, log)
    finally:
        op.close()
    true = summary.get("sim_true_distance_m")
    lost_mm = [round(1000 * x, 1) for x in losses]
    print(json.dumps({
        "minutes": args.minutes, "speed_m_s": args.speed, "profile": args.profile,
        "frames": summary["frames"], "fps": summary["fps_processed"], "loop_ms": summary["loop_ms"],
        "rss_mb_first_last_max": [round(rss[0], 1), round(rss[-1], 1), round(max(rss), 1)] if rss else None,
        "distance_m": summary["distance_m"], "sim_true_distance_m": true,
        "sim_error_mm": None if true is None else round(1000 * (summary["distance_m"] - true), 1),
        "kills": len(losses), "lost_per_kill_mm": lost_mm,
        "lost_per_kill_mean_mm": round(sum(lost_mm) / len(lost_mm), 1) if lost_mm else None,
        "lost_per_kill_max_mm": max(lost_mm) if lost_mm else None,
        "bound_mm": round(1000 * args.speed * 0.1, 1),        # one 10 Hz checkpoint interval of motion
        "load_avg_1min_before_after": [round(load_before[0], 2), round(os.getloadavg()[0], 2)],
        "cpus": os.cpu_count()}))


if __name__ == "__main__":
    main()
