"""crawler-monitor: pure parts (fleet state, view, record, plot), then the real thing on loopback Zenoh.

The network tests emulate two daemons with crawler.link.ZenohLink (the daemon's own publishers, token
and queryable), each listening on its own loopback port, and run the monitor's main() against them.
"""

import json
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

from conftest import free_port, wait_for
from crawler.monitor import main
from crawler.monitor.cli import build_parser, with_default_command
from crawler.monitor.fleet import FleetState
from crawler.monitor.plot import line_color, nice_ticks, plot_records
from crawler.monitor.record import COLUMNS, RecordError, RecordWriter, read_records
from crawler.monitor.view import render

ROOT = Path(__file__).resolve().parents[1]


def run_main(capsys, *argv):
    rc = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return rc, out, err


def colour_pixels(img, bgr) -> int:
    return int(np.count_nonzero(np.all(img == np.array(bgr, np.uint8), axis=2)))


# -- pure parts -------------------------------------------------------------------------------------

def est(seq, d, tracking=True, v=0.2):
    return {"seq": seq, "t_s": seq / 30, "distance_m": d, "speed_m_s": v if tracking else None,
            "quality": 0.9 if tracking else 0.0, "tracking": tracking, "tracks": 40, "inliers": 36}


def test_fleet_state_marks_silent_lost_and_back():
    f = FleetState(silent_after_s=2.0)
    kinds = lambda events: [(e.name, e.kind) for e in events]
    assert kinds(f.liveliness("a", True, now=0.0)) == [("a", "new")]
    assert kinds(f.ingest("a", "distance", est(1, 0.1), now=0.1)) == []
    assert kinds(f.ingest("b", "distance", est(1, 0.5), now=0.1)) == [("b", "new")]
    f.ingest("a", "status", {"fps": 29.5, "led_level": 0.6, "source": "sim", "last_error": None}, now=0.2)
    a = f.crawlers["a"]
    assert (a.distance_m, a.speed_m_s, a.quality, a.fps, a.led_level, a.tracking) == (0.1, 0.2, 0.9, 29.5, 0.6, True)

    assert kinds(f.ingest("a", "distance", est(2, 0.1, tracking=False), now=1.0)) == [("a", "lost")]
    assert a.speed_m_s is None and a.lost_since == 1.0
    assert kinds(f.ingest("a", "distance", est(3, 0.1, tracking=False), now=1.1)) == []      # once, not per frame
    assert kinds(f.ingest("a", "distance", est(4, 0.12), now=1.5)) == [("a", "tracking")]

    assert f.tick(now=2.0) == []
    assert kinds(f.tick(now=2.2)) == [("b", "silent")]                       # 2.1 s without a message
    assert "no message for 2.1 s" in f.crawlers["b"].silent
    assert kinds(f.ingest("b", "distance", est(2, 0.6), now=2.3)) == [("b", "back")]

    assert kinds(f.liveliness("a", False, now=2.4)) == [("a", "silent")]
    assert a.silent == "liveliness token gone"
    assert kinds(f.ingest("a", "status", {"fps": 0.0}, now=2.45)) == []      # the daemon's last words
    assert a.silent
    assert kinds(f.liveliness("a", True, now=3.0)) == [("a", "back")]
    assert kinds(f.liveliness("c", True, now=3.0)) == [("c", "new")]
    assert kinds(f.tick(now=5.1)) == [("a", "silent"), ("b", "silent"), ("c", "silent")]
    assert "token but no message" in f.crawlers["c"].silent


def test_renderer_shows_every_column_and_the_loud_marks():
    f = FleetState()
    f.liveliness("crawler1", True, 0.0)
    f.ingest("crawler1", "distance", est(7, 12.3456, v=0.2012), 2.5)
    f.ingest("crawler1", "status", {"fps": 29.97, "led_level": 0.6, "source": "sim", "distance_m": 12.3,
                                    "sim_true_distance_m": 12.2945}, 2.5)
    f.ingest("crawler2", "distance", est(9, 3.21, tracking=False), 2.8)
    f.ingest("crawler2", "status", {"fps": 30.0, "led_level": 0.4, "source": "camera",
                                    "last_error": "camera: frame timeout"}, 2.8)
    f.ingest("crawler3", "distance", est(3, 1.0), 0.0)
    f.tick(3.0)
    text = render(f, 3.0, key="crawler/*")
    lines = text.splitlines()
    assert lines[0].startswith("crawler-monitor  crawler/*  3 crawlers") and "!! 1 silent, 1 lost" in lines[0]
    header = lines[2].split()
    assert header[:3] == ["NAME", "DIST", "m"] and "SIM ERR mm".split()[0] in header and header[-1] == "STATE"
    rows = {ln.split()[0]: ln for ln in lines[3:6]}
    assert rows["crawler1"].split() == ["crawler1", "12.3456", "0.201", "0.90", "36/40", "30.0", "0.60", "0.5",
                                        "sim", "5.5", "ok"]    # SIM ERR mm: 12.3 - 12.2945 m, both of the status
    assert rows["crawler2"].split()[:10] == ["crawler2", "3.2100", "-", "0.00", "36/40", "30.0", "0.40", "0.2",
                                             "camera", "-"]
    assert rows["crawler2"].endswith("!! LOST 0.2 s")
    assert rows["crawler3"].endswith("!! SILENT: no message for 3.0 s")
    assert "crawler2: last error: camera: frame timeout" in text
    assert "\x1b[" not in text
    coloured = render(f, 3.0, color=True)
    assert "\x1b[1;37;41m!! SILENT" in coloured and "\x1b[1;30;43m!! LOST" in coloured
    assert "waiting for crawlers on crawler/x" in render(FleetState(), 0.0, key="crawler/x")


@pytest.mark.parametrize("suffix", [".csv", ".jsonl"])
def test_record_writes_flushed_lines_and_reads_them_back(tmp_path, suffix):
    path = tmp_path / f"run{suffix}"
    w = RecordWriter(path)
    w.write(1000.0, "c1", "alive", {"alive": True})
    w.write(1000.5, "c1", "distance", dict(est(1, 0.25), frame=4, lateral_m=0.001))
    w.write(1000.6, "c1", "distance", est(2, 0.25, tracking=False))
    lines = path.read_text().splitlines()          # on disk before close: flushed per line
    assert len(lines) == (4 if suffix == ".csv" else 3)
    w.write(1001.0, "c1", "event", {"event": "lost", "detail": "tracking lost at 0.250 m"})
    w.write(1001.5, "c1", "status", {"fps": 30.0, "led_level": 0.5, "camera": {"fps": 30}, "last_error": None})
    w.close()
    if suffix == ".csv":
        assert lines[0] == ",".join(COLUMNS)
    rows = read_records(path)
    assert [r["topic"] for r in rows] == ["alive", "distance", "distance", "event", "status"]
    assert rows[0]["alive"] is True and rows[0]["t_unix"] == 1000.0
    assert rows[1]["distance_m"] == 0.25 and rows[1]["speed_m_s"] == 0.2 and rows[1]["tracking"] is True
    assert rows[1]["frame"] == 4 and rows[1]["quality"] == 0.9
    assert rows[2]["tracking"] is False and rows[2].get("speed_m_s") is None
    assert rows[3]["event"] == "lost" and rows[4]["led_level"] == 0.5

    RecordWriter(path).close()                      # appends, does not wipe
    assert len(read_records(path)) == 5
    with path.open("a") as f:                       # a crash mid-line: the rest is still readable
        f.write('{"t_unix": 1002' if suffix == ".jsonl" else "2026-01-01T00:00:00.000,1002")
    assert len(read_records(path)) == 5
    bad = tmp_path / f"bad{suffix}"
    bad.write_text("hello,world\n1,2\n" if suffix == ".csv" else '{"t_unix": 1}\nnot json\n{"x": 1}\n')
    with pytest.raises(RecordError, match="bad" + suffix.replace(".", r"\.") + ":1"):
        read_records(bad)
    with pytest.raises(RecordError, match=".csv or .jsonl"):
        RecordWriter(tmp_path / "run.txt")


def synthetic_records(n=300):
    rows = []
    for i in range(n):
        for k, name in enumerate(("alpha", "beta")):
            tracking = not (name == "beta" and 100 <= i < 140)
            rows.append(dict(est(i, (0.1 + 0.1 * k) * i / 30, tracking, v=0.1 + 0.1 * k),
                             t_unix=5000 + i / 30, name=name, topic="distance"))
    rows.append({"t_unix": 5000 + 200 / 30, "name": "alpha", "topic": "event", "event": "silent", "detail": ""})
    return rows


def test_plot_draws_two_panels_one_line_per_crawler_and_shades_lost_tracking():
    img = plot_records(synthetic_records(), size=(1000, 700))
    assert img.shape == (700, 1000, 3) and img.dtype == np.uint8
    for i in range(2):
        assert colour_pixels(img, line_color(i)) > 500, f"line {i} missing"
    assert colour_pixels(img, line_color(2)) == 0
    # the lost stretch of beta (t 3.33..4.67 s) is tinted with its colour, a tracked moment is white
    beta = np.array(line_color(1), float)
    col_lost = img[150:250, int(80 + (1000 - 104) * 4.0 / 10)].astype(float)
    col_ok = img[150:250, int(80 + (1000 - 104) * 8.6 / 10)].astype(float)
    assert np.median(np.linalg.norm(col_lost - beta, axis=1)) < np.median(np.linalg.norm(col_ok - beta, axis=1))
    assert nice_ticks(0, 9.97) == [0, 2, 4, 6, 8] and nice_ticks(-0.03, 0.32) == [0.0, 0.1, 0.2, 0.3]


# -- arguments --------------------------------------------------------------------------------------

def test_the_default_command_is_watch():
    p = build_parser()
    assert with_default_command([], p) == ["watch"]
    assert with_default_command(["--name", "status", "--record", "x.csv"], p)[0] == "watch"
    assert with_default_command(["--connect", "tcp/h:1", "reset", "c1"], p) == ["--connect", "tcp/h:1", "reset", "c1"]
    args = p.parse_args(with_default_command(["--no-multicast", "led", "c1", "0.5", "--connect", "tcp/h:1"], p))
    assert (args.command, args.name, args.level, args.connect, args.no_multicast, args.timeout) == (
        "led", "c1", 0.5, ["tcp/h:1"], True, 3.0)
    args = p.parse_args(with_default_command(["--record", "r.jsonl"], p))
    assert (args.command, args.name, args.record, args.zenoh_mode, args.connect) == ("watch", "*", "r.jsonl", None, [])


@pytest.mark.parametrize("argv, message", [
    (["led", "c1", "1.5"], "LEVEL: 1.5 is outside 0..1"),
    (["led", "c1", "bright"], "LEVEL: 'bright' is not a number"),
    (["led", "c1"], "LEVEL"),
    (["reset", "c*"], "crawler name 'c*'"),
    (["reset", "*"], "crawler name '*'"),
    (["plot", "{tmp}/missing.csv"], "no such record file"),
    (["plot", "{tmp}/garbage.csv"], "garbage.csv:1: not a crawler-monitor CSV"),
    (["plot", "{tmp}/garbage.jsonl"], "garbage.jsonl:1: not a JSON line"),
    (["plot", "{tmp}/empty.csv"], "nothing to plot in {tmp}/empty.csv: the record is empty"),
    (["plot", "{tmp}/alive.jsonl"], "alive.jsonl: the record has no distance messages"),
    (["plot", "{tmp}/empty.csv", "-o", "{tmp}/x.jpg"], "the plot is a .png"),
    (["--record", "{tmp}/run.txt"], "suffix must be .csv or .jsonl"),
    (["--duration", "-1"], "--duration: '-1' must be more than 0 s"),
    (["--name", "a/b"], "crawler name 'a/b'"),
    (["--connect", "not-an-endpoint", "--duration", "1"], "not-an-endpoint"),
    (["--zenoh-config", "{tmp}/nope.json5", "status", "c1"], "no such file"),
    (["frobnicate"], "invalid choice: 'frobnicate'"),
])
def test_bad_arguments_are_one_line_and_exit_2(tmp_path, capsys, argv, message):
    (tmp_path / "garbage.csv").write_text("\x00\x01 what\n")
    (tmp_path / "garbage.jsonl").write_text("{{{\n")
    (tmp_path / "empty.csv").write_text(",".join(COLUMNS) + "\n")
    (tmp_path / "alive.jsonl").write_text('{"t_unix": 1.0, "name": "c1", "topic": "alive", "data": {"alive": true}}\n')
    message = message.format(tmp=tmp_path)
    rc, out, err = run_main(capsys, *(a.format(tmp=tmp_path) for a in argv))
    assert rc == 2, err
    assert err.count("\n") == 1 and err.startswith("crawler-monitor: error: ") and message in err, err
    assert "Traceback" not in err and out == ""


# -- on the network ---------------------------------------------------------------------------------

class Direct:
    """The daemon's command queue, answered at once (no frame loop here)."""

    def __init__(self, handle):
        self.handle = handle

    def submit(self, request, timeout_s=None):
        return self.handle(request)


class FakeDaemons:
    """Two crawlers, each a ZenohLink listening on its own loopback port; `handled` logs commands."""

    def __init__(self):
        from crawler.link import ZenohLink, make_zenoh_config

        self.handled = []
        self.ports = [free_port(), free_port()]
        self.links = {}
        for name, port in zip(("c1", "c2"), self.ports):
            conf = make_zenoh_config("peer", listen=[f"tcp/127.0.0.1:{port}"], multicast=False)
            self.links[name] = ZenohLink(name, conf, commands=Direct(self._handler(name))).open()
        self.flags = ["--no-multicast"] + [f"--connect=tcp/127.0.0.1:{p}" for p in self.ports]
        self.published = {"c1": [], "c2": []}
        self._stop = threading.Event()
        self._thread = None

    def _handler(self, name):
        def handle(request):
            self.handled.append((name, request))
            cmd = request["cmd"]
            if cmd == "reset":
                return {"cmd": "reset", "distance_m": 0.0, "run_id": f"{name}-run2"}
            if cmd == "led":
                if name == "c2":
                    raise RuntimeError("crawler busy: no answer within 2 s (is the camera delivering frames?)")
                return {"cmd": "led", "level": float(request["level"])}
            if cmd == "status":
                return {"name": name, "source": "sim", "fps": 30.0, "led_level": 0.5}
            raise ValueError(f"unknown cmd {cmd!r}; use reset, led or status")
        return handle

    def publish(self, name, frame, tracking=True):
        k = 1 if name == "c1" else 2
        e = {"name": name, "frame": frame, "t_s": frame / 50, "distance_m": round(0.01 * k * frame, 6),
             "speed_m_s": 0.5 * k if tracking else None, "quality": 0.9 if tracking else 0.0,
             "tracking": tracking, "tracks": 40, "inliers": 36 if tracking else 0, "lateral_m": 0.0}
        link = self.links[name]
        link.publish_estimate(e)
        self.published[name].append(dict(e, seq=link.seq))
        if frame % 10 == 0:
            link.publish_status({"name": name, "source": "sim", "fps": 50.0, "frames": frame,
                                 "led_level": 0.5, "last_error": None})

    def start(self, script):
        """Publish both at 50 Hz in a thread; script(elapsed) -> (c1 tracking, c2 still running)."""
        def loop():
            frame = 0
            while not self._stop.is_set():
                frame += 1
                c1_tracking, c2_on = script()
                self.publish("c1", frame, c1_tracking)
                if c2_on:
                    self.publish("c2", frame)
                elif self.links["c2"].connected:
                    self.links["c2"].close()           # its token goes: the monitor must say SILENT
                time.sleep(0.02)
        self._thread = threading.Thread(target=loop, daemon=True)
        self._thread.start()

    def close(self):
        self._stop.set()
        if self._thread:
            self._thread.join(5)
        for link in self.links.values():
            link.close()


@pytest.fixture
def daemons():
    d = FakeDaemons()
    try:
        yield d
    finally:
        d.close()


def test_watch_records_two_crawlers_marks_silent_and_lost_and_plots(daemons, tmp_path, capsys):
    record = tmp_path / "run.csv"
    both_since = []

    def script():
        """After the monitor has both crawlers: c1 loses tracking 0.2..0.6 s, c2 stops at 1.0 s."""
        if not both_since:
            text = record.read_text() if record.exists() else ""
            if ",c1,distance," in text and ",c2,distance," in text:
                both_since.append(time.monotonic())
            return True, True
        phase = time.monotonic() - both_since[0]
        return not 0.2 <= phase < 0.6, phase < 1.0

    daemons.start(script)
    t0 = time.monotonic()
    rc, out, err = run_main(capsys, "watch", *daemons.flags, "--record", record, "--duration", 2.5)
    assert rc == 0, err
    assert 2.4 < time.monotonic() - t0 < 6
    assert both_since, "the monitor never received both crawlers"
    assert "recorded" in err and str(record) in err

    rows = read_records(record)
    for name in ("c1", "c2"):
        got = [r for r in rows if r["name"] == name and r["topic"] == "distance"]
        sent = {p["seq"]: p for p in daemons.published[name]}
        assert len(got) > 20, name
        seqs = [int(r["seq"]) for r in got]
        assert seqs == list(range(seqs[0], seqs[-1] + 1)), f"{name}: lost messages on loopback"
        for r in got:                               # every value as published
            p = sent[int(r["seq"])]
            for key in ("frame", "t_s", "distance_m", "speed_m_s", "quality", "tracking", "tracks", "inliers"):
                assert r.get(key) == p[key], (name, key, r, p)
        speeds = [r for r in rows if r["name"] == name and r["topic"] == "speed"]
        assert len(speeds) >= len(got) - 2
        assert any(r["topic"] == "status" and r["fps"] == 50.0 for r in rows if r["name"] == name)

    events = [(r["name"], r["event"], r.get("detail", "")) for r in rows if r["topic"] == "event"]
    assert ("c2", "silent", "liveliness token gone") in events
    assert not any(n == "c1" and e == "silent" for n, e, _ in events)
    assert any(n == "c1" and e == "lost" for n, e, _ in events)
    assert any(n == "c1" and e == "tracking" for n, e, _ in events)
    assert {"name": "c2", "alive": False} in [{k: r[k] for k in ("name", "alive")} for r in rows if r["topic"] == "alive"]
    lost_rows = [r for r in rows if r["name"] == "c1" and r["topic"] == "distance" and not r["tracking"]]
    assert lost_rows and all("speed_m_s" not in r and r["quality"] == 0.0 for r in lost_rows)

    # stdout is not a terminal here: one plain line per update, and the loud marks
    lines = out.splitlines()
    assert any(" c1 distance seq=" in ln and "distance_m=" in ln for ln in lines)
    assert any(ln.endswith("c2 SILENT liveliness token gone") for ln in lines)
    assert any(" c1 LOST tracking lost at " in ln for ln in lines)
    assert "\x1b[" not in out

    png = tmp_path / "run.png"
    rc, out, err = run_main(capsys, "plot", record, "-o", png)
    assert rc == 0, err
    assert "2 crawler(s) c1, c2" in out
    img = cv2.imread(str(png))
    assert img is not None and img.shape == (800, 1200, 3)
    assert colour_pixels(img, line_color(0)) > 300 and colour_pixels(img, line_color(1)) > 300


def test_control_commands_round_trip(daemons, capsys):
    net = daemons.flags
    rc, out, err = run_main(capsys, "reset", "c1", *net)
    assert rc == 0, err
    assert json.loads(out) == {"ok": True, "cmd": "reset", "distance_m": 0.0, "run_id": "c1-run2"}
    rc, out, err = run_main(capsys, *net, "led", "c1", "0.4")
    assert rc == 0 and json.loads(out) == {"ok": True, "cmd": "led", "level": 0.4}
    rc, out, err = run_main(capsys, "status", "c2", *net)
    assert rc == 0 and json.loads(out)["name"] == "c2"
    rc, out, err = run_main(capsys, "status", "*", *net)
    assert rc == 0 and sorted(json.loads(ln)["name"] for ln in out.splitlines()) == ["c1", "c2"]
    assert ("c1", {"cmd": "led", "level": "0.4"}) in daemons.handled

    rc, out, err = run_main(capsys, "led", "c2", "0.3", *net)          # the daemon says no
    assert rc == 1 and out == ""
    assert err == ("crawler-monitor: error: crawler c2 refused led: crawler busy: no answer within 2 s "
                   "(is the camera delivering frames?)\n")

    t0 = time.monotonic()
    rc, out, err = run_main(capsys, "reset", "c9", "--timeout", "0.5", *net)   # nobody there
    assert rc == 1 and out == "" and 0.4 < time.monotonic() - t0 < 3
    assert err.startswith("crawler-monitor: error: no crawler named 'c9' answered reset within 0.5 s")
    assert err.count("\n") == 1


@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGINT])
def test_a_signal_ends_the_watch_cleanly_and_keeps_the_record(daemons, tmp_path, signum):
    daemons.start(lambda: (True, True))
    record = tmp_path / "run.jsonl"
    proc = subprocess.Popen([sys.executable, "-m", "crawler.monitor", *daemons.flags, "--record", str(record)],
                            cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert wait_for(lambda: record.exists() and record.read_text().count('"distance"') > 5, timeout=15)
        proc.send_signal(signum)
        out, err = proc.communicate(timeout=10)      # a session left open would hang here
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, err
    assert "Traceback" not in err and "recorded" in err
    assert " c1 distance seq=" in out
    rows = read_records(record)
    assert {r["name"] for r in rows} == {"c1", "c2"}


def test_the_whole_loop_with_crawlerd_sim(tmp_path, capsys):
    """crawlerd --sim on loopback. The monitor records it until it stops (its token goes: SILENT) while,
    as an operator would, a second crawler-monitor process asks its status, resets it and sets its LED."""
    port = free_port()
    record = tmp_path / "sim.jsonl"
    net = ["--no-multicast", "--connect", f"tcp/127.0.0.1:{port}"]
    daemon = subprocess.Popen([sys.executable, "-m", "crawler", "--sim", "--no-multicast",
                               "--listen", f"tcp/127.0.0.1:{port}", "--max-frames", "240",
                               "--state-dir", str(tmp_path / "state")],
                              cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    replies = {}

    def operator():
        for argv in (["status", "crawler1", "--timeout", "10"], ["reset", "crawler1"], ["led", "crawler1", "0.3"]):
            p = subprocess.run([sys.executable, "-m", "crawler.monitor", *argv, *net], cwd=ROOT,
                               capture_output=True, text=True, timeout=30)
            replies[argv[0]] = (p.returncode, p.stdout, p.stderr)

    commands = threading.Thread(target=operator)
    try:
        commands.start()
        rc, out, err = run_main(capsys, *net, "--record", record, "--duration", 8)
        assert rc == 0, err
        commands.join(30)
        d_out, d_err = daemon.communicate(timeout=30)
    finally:
        if daemon.poll() is None:
            daemon.kill()
            daemon.communicate()
    assert daemon.returncode == 0, d_err
    for cmd, (code, stdout, stderr) in replies.items():
        assert code == 0, (cmd, stderr)
    status = json.loads(replies["status"][1])
    assert status["ok"] is True and status["name"] == "crawler1" and status["source"] == "sim"
    assert json.loads(replies["reset"][1])["distance_m"] == 0.0
    assert json.loads(replies["led"][1]) == {"ok": True, "cmd": "led", "level": 0.3}

    rows = read_records(record)
    dist = [r["distance_m"] for r in rows if r["topic"] == "distance" and r["name"] == "crawler1"]
    assert len(dist) > 30, d_err
    drops = [i for i in range(1, len(dist)) if dist[i] < dist[i - 1] - 0.01]
    assert len(drops) <= 1 and all(dist[i] < 0.05 for i in drops)      # forward, except at the reset
    stats = [r for r in rows if r["topic"] == "status"]
    assert stats and all(r["source"] == "sim" and r["sim_true_distance_m"] is not None for r in stats)
    assert any(r["topic"] == "event" and r["event"] == "silent" and r["detail"] == "liveliness token gone"
               for r in rows), "the daemon stopped but the monitor did not mark it silent"
    assert " crawler1 SILENT liveliness token gone" in out
    rc, out, err = run_main(capsys, "plot", record, "-o", tmp_path / "sim.png")
    assert rc == 0, err
    img = cv2.imread(str(tmp_path / "sim.png"))
    assert img is not None and colour_pixels(img, line_color(0)) > 300
