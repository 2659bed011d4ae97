"""A long `crawlerd --sim` run: worst frame-loop iteration, memory, error against the simulator.

    python benchmarks/soak.py [--minutes 10] [--speed 0.4] [--profile stopgo] [--kills 0]

Starts the real daemon as a subprocess on loopback Zenoh, listens to its status once a second
(loop latency, fps, sim error) and samples its memory, then stops it with SIGTERM and prints the
summary's loop figures. With --kills N it also kills the daemon N times with SIGKILL (restarting it
each time) and reports the distance each kill lost: the last published distance before the kill
against the checkpoint the next run resumed from. Not a test: it prints figures
(docs/reliability.md, docs/performance.md).
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


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def start(state: Path, port: int, args) -> subprocess.Popen:
    env = dict(os.environ, CRAWLERD_CONFIG=os.devnull)
    return subprocess.Popen(
        [sys.executable, "-m", "crawler", "--sim", "--sim-speed", str(args.speed), "--sim-profile", args.profile,
         "--no-multicast", "--listen", f"tcp/127.0.0.1:{port}", "--state-dir", str(state)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env, cwd=ROOT)


def rss_mb(pid: int) -> float:
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    except OSError:
        pass
    return float("nan")


def main(argv=None):
    import zenoh

    from crawler.link import make_zenoh_config

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--minutes", type=float, default=10.0)
    ap.add_argument("--speed", type=float, default=0.4)
    ap.add_argument("--profile", default="stopgo")
    ap.add_argument("--kills", type=int, default=0, help="SIGKILL and restart the daemon this many times")
    args = ap.parse_args(argv)
    port, state = free_port(), Path(tempfile.mkdtemp()) / "state"
    status, dist = [], []
    op = zenoh.open(make_zenoh_config("peer", connect=[f"tcp/127.0.0.1:{port}"], multicast=False))
    op.declare_subscriber("crawler/crawler1/status", lambda s: status.append(json.loads(s.payload.to_string())))
    op.declare_subscriber("crawler/crawler1/distance", lambda s: dist.append(json.loads(s.payload.to_string())))
    losses = []
    try:
        for k in range(args.kills):
            proc = start(state, port, args)
            time.sleep(4.0 + k % 3)
            last = dist[-1]["distance_m"] if dist else None
            proc.kill()
            proc.communicate()
            saved = json.loads((state / "checkpoint.json").read_text())["distance_m"]
            if last is not None:
                losses.append(last - saved)
            print(f"kill {k + 1}: last published {last:.4f} m, checkpoint {saved:.4f} m", file=sys.stderr)
        proc = start(state, port, args)
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
        proc.send_signal(signal.SIGTERM)
        out, err = proc.communicate(timeout=60)
    finally:
        op.close()
    summary = json.loads(out.strip().splitlines()[-1])
    true = summary.get("sim_true_distance_m")
    print(json.dumps({"minutes": args.minutes, "frames": summary["frames"], "fps": summary["fps_processed"],
                      "loop_ms": summary["loop_ms"], "rss_mb_first_last": [rss[0], rss[-1]] if rss else None,
                      "distance_m": summary["distance_m"], "sim_true_distance_m": true,
                      "kills": len(losses), "lost_per_kill_mm": [round(1000 * x, 1) for x in losses],
                      "lost_per_kill_mean_mm": round(1000 * sum(losses) / len(losses), 1) if losses else None}))


if __name__ == "__main__":
    main()
