"""An inspection as the operator does it, with real processes: crawlerd --sim on loopback, crawler-monitor
recording MCAP, the footage counter zeroed, preset and switched to feet, coded observations marked, the
report written from the record, the ROS 2 topic decoded by an independent CDR implementation, and the
run's counter and observations still there after the daemon restarts."""

import csv
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from conftest import free_port, wait_for

ROOT = Path(__file__).resolve().parents[1]


def crawlerd(tmp_path, port, *extra):
    env = dict(os.environ, CRAWLERD_CONFIG=os.devnull)
    return subprocess.Popen([sys.executable, "-m", "crawler", "--sim", "--sim-speed", "0.3", "--no-multicast",
                             "--listen", f"tcp/127.0.0.1:{port}", "--state-dir", str(tmp_path / "state"),
                             "--set", "ros2.enabled=true", "--set", 'inspection.pipe_id="MH12-MH13"', *extra],
                            cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def monitor(port, *argv, timeout=30):
    net = [] if port is None else ["--no-multicast", "--connect", f"tcp/127.0.0.1:{port}"]
    p = subprocess.run([sys.executable, "-m", "crawler.monitor", *argv, *net], cwd=ROOT, capture_output=True,
                       text=True, timeout=timeout)
    assert p.returncode == 0, (argv, p.stderr)
    return p.stdout


def bracket(dist, mark):
    """The footage the daemon published just before and just after a mark: the mark's footage lies between,
    however long the monitor took to start (a fixed sleep would tie the test to the machine's load)."""
    before = dist[-1]["footage_m"]
    mark()
    n = len(dist)
    assert wait_for(lambda: len(dist) > n + 2, timeout=10)                  # past any message in flight
    return before - 1e-6, dist[-1]["footage_m"] + 1e-6


def test_zero_preset_marks_report_mcap_and_ros2_with_real_processes(tmp_path):
    import zenoh
    from mcap.reader import make_reader
    from rosbags.typesys import Stores, get_typestore

    from crawler.link import make_zenoh_config
    from crawler.ros2 import TYPE_HASHES

    port = free_port()
    daemon = crawlerd(tmp_path, port)
    dist, odom = [], []
    op = zenoh.open(make_zenoh_config("peer", connect=[f"tcp/127.0.0.1:{port}"], multicast=False))
    op.declare_subscriber("crawler/crawler1/distance", lambda s: dist.append(json.loads(s.payload.to_string())))
    op.declare_subscriber(f"0/crawler1/odom/nav_msgs::msg::dds_::Odometry_/{TYPE_HASHES['jazzy']}",
                          lambda s: odom.append(s.payload.to_bytes()))
    record = tmp_path / "run.mcap"
    watch = subprocess.Popen([sys.executable, "-m", "crawler.monitor", "watch", "--plain", "--record", str(record),
                              "--duration", "12", "--no-multicast", "--connect", f"tcp/127.0.0.1:{port}"],
                             cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert wait_for(lambda: len(dist) > 10, timeout=60)
        monitor(port, "zero", "crawler1")
        assert wait_for(lambda: dist[-1]["footage_m"] < 0.05 and dist[-1]["distance_m"] > 0.1, timeout=10)
        monitor(port, "units", "crawler1", "ft")
        reply = json.loads(monitor(port, "preset", "crawler1", "40"))
        assert reply["unit"] == "ft" and reply["footage"] == "40.0 ft"
        assert reply["footage_m"] == pytest.approx(40 * 0.3048, abs=0.01)
        monitor(port, "direction", "crawler1", "upstream")
        start = bracket(dist, lambda: monitor(port, "mark", "crawler1", "FL", "--clock", "3", "--start"))
        time.sleep(1.0)                                               # at least 0.3 m of crack
        finish = bracket(dist, lambda: monitor(port, "mark", "crawler1", "FL", "--finish", "--note", "at the joint"))
        monitor(port, "mark", "crawler1", "BAB", "--clock", "12")
        last = dist[-1]
        assert last["unit"] == "ft" and last["direction"] == "upstream" and last["footage"].endswith(" ft")
        assert last["footage_m"] > 40 * 0.3048                         # counts on from the preset
        obs = json.loads(monitor(port, "observations", "crawler1"))["observations"]
        assert [o["code"] for o in obs] == ["FL", "FL", "BAB"] and [o["kind"] for o in obs] == ["start", "finish",
                                                                                              "point"]
        assert start[0] <= obs[0]["footage_m"] <= start[1] and finish[0] <= obs[1]["footage_m"] <= finish[1]
        assert obs[1]["footage_m"] - obs[0]["footage_m"] > 0.25
        assert wait_for(lambda: len(odom) > 10, timeout=10)
        out, err = watch.communicate(timeout=60)
        assert watch.returncode == 0, err
    finally:
        op.close()
        if watch.poll() is None:
            watch.kill()
        daemon.send_signal(signal.SIGTERM)
        daemon.communicate(timeout=30)
    assert daemon.returncode == 0

    m = get_typestore(Stores.ROS2_JAZZY).deserialize_cdr(odom[-1], "nav_msgs/msg/Odometry")
    assert m.header.frame_id == "crawler1/pipe" and 0.1 < m.pose.pose.position.x < 10
    assert m.twist.twist.linear.x == pytest.approx(0.3, abs=0.05) and m.header.stamp.sec > 1.7e9

    with open(record, "rb") as f:
        channels = {c.topic: 0 for c in make_reader(f).get_summary().channels.values()}
    with open(record, "rb") as f:
        for _, channel, message in make_reader(f).iter_messages():
            channels[channel.topic] += 1
    assert channels["crawler/crawler1/observations"] == 3 and channels["crawler/crawler1/distance"] > 100
    monitor(None, "report", str(record), "-o", str(tmp_path / "report.csv"))
    rows = list(csv.DictReader((tmp_path / "report.csv").open()))
    assert [r["code"] for r in rows] == ["FL", "FL", "BAB"] and rows[2]["clock"] == "12"
    monitor(None, "report", str(record), "-o", str(tmp_path / "report.html"))
    html = (tmp_path / "report.html").read_text()
    assert "BAB" in html and "at the joint" in html and "data:image/png;base64," in html

    daemon = crawlerd(tmp_path, port)                      # restarted: the run's counter and marks are kept
    try:
        again = json.loads(monitor(port, "observations", "crawler1", "--timeout", "20"))
        assert [o["code"] for o in again["observations"]] == ["FL", "FL", "BAB"]
        status = json.loads(monitor(port, "status", "crawler1"))
        assert status["unit"] == "ft" and status["direction"] == "upstream" and status["observations"] == 3
    finally:
        daemon.send_signal(signal.SIGTERM)
        daemon.communicate(timeout=30)
