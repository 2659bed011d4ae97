"""crawler-monitor: pure parts (fleet state, view, keys, arguments), then the real thing on loopback Zenoh.

The network tests emulate daemons with tests/fake_crawlerd.py (real zenoh sessions speaking the
protocol of issue 15: commands on crawler/<name>/cmd/<verb>, status on request), each listening on its
own loopback port, and run the monitor's main() against them. One test runs crawlerd --sim itself.
Records, MCAP, plots, reports and Foxglove are in test_monitor_outputs.py.
"""

import io
import json
import os
import pty
import re
import signal
import subprocess
import sys
import termios
import threading
import time
from pathlib import Path

import pytest

from conftest import free_port, wait_for
from fake_crawlerd import FakeCrawler
from crawler.monitor import main
from crawler.monitor.cli import build_parser
from crawler.monitor.commands import mark_args, preset_args
from crawler.monitor.fleet import FleetState, footage_text
from crawler.monitor.keys import Keyboard, Mark, MarkPrompt, Quit, parse_mark
from crawler.monitor.net import open_session
from crawler.monitor.record import COLUMNS, read_records
from crawler.monitor.view import plain_line, render, render_text
from crawler.monitor.watch import Watch

ROOT = Path(__file__).resolve().parents[1]


def run_main(capsys, *argv):
    rc = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return rc, out, err


# -- pure parts -------------------------------------------------------------------------------------

def est(seq, d, tracking=True, v=0.2, **extra):
    return dict({"seq": seq, "t_s": seq / 30, "distance_m": d, "speed_m_s": v if tracking else None,
                 "quality": 0.9 if tracking else 0.0, "tracking": tracking, "tracks": 40, "inliers": 36}, **extra)


def kinds(events):
    return [(e.name, e.kind) for e in events]


def test_fleet_state_marks_silent_lost_and_back():
    f = FleetState(silent_after_s=2.0)
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


def test_fleet_state_bridged_slip_footage_and_observations_of_a_run():
    f = FleetState()
    f.ingest("a", "distance", est(1, 1.0, sigma_m=0.004, source="vision", footage_m=13.4, unit="ft",
                                  direction="upstream", footage="44.0 ft", run_id="r1"), now=0.0)
    a = f.crawlers["a"]
    assert (a.sigma_m, a.basis, a.footage, a.unit, a.direction, a.run_id) == (0.004, "vision", "44.0 ft", "ft",
                                                                             "upstream", "r1")
    events = f.ingest("a", "distance", est(2, 1.1, tracking=False, v=None, bridged=True, source="model"), now=0.1)
    assert kinds(events) == [("a", "lost"), ("a", "bridged")] and "motion model from 1.100 m" in events[1].detail
    wheel = FleetState()
    wheel.ingest("w", "distance", est(1, 1.0, source="fused"), now=0.0)
    events = wheel.ingest("w", "distance", est(2, 1.1, tracking=False, bridged=True, source="wheel"), now=0.1)
    assert "carried by the wheel from 1.100 m" in events[-1].detail
    assert kinds(f.ingest("a", "distance", est(3, 1.2, tracking=False, bridged=True), now=0.2)) == []
    assert kinds(f.ingest("a", "distance", est(4, 1.3, slip=True, source="fused"), now=0.3)) == [
        ("a", "tracking"), ("a", "slip")]
    assert a.bridged is False and a.slip is True and a.basis == "fused"

    obs = {"id": 1, "run_id": "r1", "code": "FL", "clock": 3, "kind": "start", "distance_m": 1.3,
           "footage_m": 13.7, "unit": "ft", "note": "crack"}
    assert kinds(f.ingest("a", "observations", obs, now=0.4)) == [("a", "mark")]
    assert f.crawlers["a"].observations[1]["code"] == "FL"
    assert f.observation("a", dict(obs)) is False                            # the same one from a reply
    f.ingest("a", "status", {"run_id": "r1", "observations": 3}, now=0.5)
    assert a.missing_observations()                                          # the laptop joined late
    f.ingest("a", "status", {"run_id": "r2", "observations": 0}, now=0.6)   # reset: a new run
    assert a.observations == {} and not a.missing_observations()
    assert footage_text(12.4, "m") == "12.4 m" and footage_text(12.4, "ft") == "40.7 ft"
    assert footage_text(-0.04, "m") == "-0.0 m" and footage_text(None, "ft") == "-"


def test_the_live_table_shows_every_column_and_the_loud_marks():
    f = FleetState()
    f.liveliness("crawler1", True, 0.0)
    f.ingest("crawler1", "distance", est(7, 12.3456, v=0.2012, sigma_m=0.0123, source="vision", footage="40.5 ft",
                                         footage_m=12.3456, unit="ft", direction="downstream", run_id="r"), 2.5)
    f.ingest("crawler1", "status", {"fps": 29.97, "led_level": 0.6, "source": "sim", "distance_m": 12.3,
                                    "sim_true_distance_m": 12.2945, "run_id": "r", "observations": 1}, 2.5)
    f.ingest("crawler1", "observations", {"id": 1, "run_id": "r", "code": "FL", "clock": 3, "kind": "point",
                                          "distance_m": 12.0, "footage_m": 12.0, "unit": "ft"}, 2.5)
    f.ingest("crawler2", "distance", est(9, 3.21, tracking=False, bridged=True, source="model", sigma_m=0.2), 2.8)
    f.ingest("crawler2", "status", {"fps": 30.0, "led_level": 0.4, "source": "camera",
                                    "last_error": "camera: frame timeout"}, 2.8)
    f.ingest("crawler3", "distance", est(3, 1.0, slip=True, source="fused"), 0.0)
    f.ingest("crawler4", "distance", est(3, 2.0, slip=True, source="fused", unmeasured_s=4.2), 2.9)
    f.tick(3.0)
    text = render_text(render(f, 3.0, key="crawler/*", prompt="mark crawler1: > FL_"), width=220)
    lines = text.splitlines()
    assert lines[0].startswith("crawler-monitor  crawler/*  4 crawlers") and "!! 1 silent, 1 lost" in lines[0]
    at = next(i for i, ln in enumerate(lines) if ln.lstrip().startswith("NAME"))
    for column in ("DISTANCE m", "FOOTAGE", "SPEED m/s", "SOURCE", "OBS", "SIM ERR mm", "STATE"):
        assert column in lines[at]
    rows = {ln.split()[0]: ln for ln in lines[at + 2:at + 6]}                  # under the header's rule
    assert sorted(rows) == ["crawler1", "crawler2", "crawler3", "crawler4"]
    assert rows["crawler1"].split() == ["crawler1", "12.3456", "±0.012", "40.5", "ft", "DS", "0.201", "0.90",
                                        "36/40", "30.0", "0.60", "0.5", "vision/sim", "1", "5.5", "ok"]
    assert rows["crawler2"].split()[:5] == ["crawler2", "3.2100", "±0.200", "-", "-"]
    assert rows["crawler2"].rstrip().endswith("!! LOST 0.2 s, BRIDGED") and " model " in rows["crawler2"]
    assert rows["crawler3"].rstrip().endswith("!! SILENT: no message for 3.0 s")
    assert rows["crawler4"].rstrip().endswith("!! SLIP, 4.2 s UNMEASURED (restart)") and " fused " in rows["crawler4"]
    assert "crawler2: last error: camera: frame timeout" in text
    assert "crawler1 #1 FL @3 39.4 ft" in text                                # the observations under the table
    assert "mark crawler1: > FL_" in text
    assert "\x1b[" not in text
    coloured = render_text(render(f, 3.0), width=220, color=True)
    assert "\x1b[1;37;41m!! SILENT" in coloured and "\x1b[1;30;43m!! LOST" in coloured
    narrow = render_text(render(f, 3.0, width=80), width=80)
    assert "QUAL" not in narrow and "TRACKS" not in narrow and "…" not in narrow.split("observations:")[0]
    assert "waiting for crawlers on crawler/x" in render_text(render(FleetState(), 0.0, key="crawler/x"))


def test_plain_lines_name_the_new_fields():
    line = plain_line(0.0, "c1", "distance", est(1, 0.5, sigma_m=0.002, bridged=False, source="vision",
                                                 footage="1.6 ft"))
    assert " c1 distance seq=1 " in line and "sigma_m=0.002" in line and "source=vision" in line
    assert "footage='1.6 ft'" in line and "bridged=false" in line
    obs = plain_line(0.0, "c1", "observations", {"id": 2, "code": "BAB", "clock": 12, "kind": "start",
                                                 "note": "at the joint", "distance_m": 3.5})
    assert obs.endswith("c1 observations id=2 distance_m=3.5 code=BAB clock=12 kind=start note='at the joint'")


def test_the_mark_prompt_turns_keys_into_a_checked_mark():
    assert parse_mark("FL @3 start crack at the joint") == {"code": "FL", "clock": 3, "kind": "start",
                                                             "note": "crack at the joint"}
    assert parse_mark("BAB f") == {"code": "BAB", "kind": "finish"}
    assert parse_mark("TFA 12 o'clock") == {"code": "TFA", "kind": "point", "note": "12 o'clock"}
    for bad, message in (("", "type a code"), ("FL @13", "outside 1..12"), ("F/L", "observation code")):
        with pytest.raises(ValueError, match=message):
            parse_mark(bad)

    p = MarkPrompt()
    assert p.feed("x", []) == [] and p.feed("m", []) == [] and "no crawler" in p.line()
    assert p.feed("m", ["c1", "c2"]) == [] and p.active and p.target == "c1"
    assert p.feed("\tFL @3 start\x7fx\x7f\x7frt cr", ["c1", "c2"]) == []
    assert p.target == "c2" and p.buffer == "FL @3 start cr" and p.line().startswith("mark c2> FL @3 start cr_")
    assert p.feed("ack\r", ["c1", "c2"]) == [Mark("c2", {"code": "FL", "clock": 3, "kind": "start",
                                                        "note": "crack"})]
    assert not p.active and p.line() == ""
    assert p.feed("mFL @0\r", ["c1", "c2"]) == [] and p.active and "outside 1..12" in p.line()
    assert p.feed("\x1bq", ["c1"]) == [Quit()] and not p.active                # Esc cancels, q quits
    assert mark_args("FL") == {"code": "FL", "kind": "point"}
    assert preset_args(40.0, "ft") == {"distance_m": 12.192} and preset_args(12.4, None) == {"distance": 12.4}


def test_the_keyboard_reads_a_real_terminal_and_nothing_else():
    master, slave = pty.openpty()
    try:
        before = termios.tcgetattr(slave)
        with Keyboard(slave) as keys:
            assert keys.enabled
            attrs = termios.tcgetattr(slave)
            assert not attrs[3] & termios.ICANON and not attrs[3] & termios.ECHO and attrs[3] & termios.ISIG
            assert keys.read() == ""                                           # nothing typed: no wait
            os.write(master, b"mFL\r")
            got = ""
            end = time.monotonic() + 2
            while "\n" not in got and time.monotonic() < end:
                got += keys.read()
            assert got == "mFL\n"                                           # the tty maps Enter to \n
        assert termios.tcgetattr(slave) == before                               # the terminal restored
    finally:
        os.close(master)
        os.close(slave)
    r, w = os.pipe()
    try:
        os.write(w, b"q")
        with Keyboard(r) as keys:                                               # a pipe is no keyboard
            assert not keys.enabled and keys.read() == ""
    finally:
        os.close(r)
        os.close(w)


# -- arguments --------------------------------------------------------------------------------------

def test_the_default_command_is_watch():
    p = build_parser()

    def parse(argv):
        args = p.parse_args(argv)
        args.command = args.command or "watch"
        return args

    assert parse([]).command == "watch"
    args = parse(["--name", "status", "--record", "x.csv"])
    assert (args.command, args.name, args.record) == ("watch", "status", "x.csv")
    assert parse(["--foxglove", "--foxglove-port", "9000"]).foxglove_port == 9000
    args = parse(["--connect", "tcp/h:1", "reset", "c1"])
    assert (args.command, args.name, args.connect) == ("reset", "c1", ["tcp/h:1"])
    args = parse(["--no-multicast", "led", "c1", "0.5", "--connect", "tcp/h:1"])
    assert (args.command, args.name, args.level, args.connect, args.no_multicast, args.timeout) == (
        "led", "c1", 0.5, ["tcp/h:1"], True, 3.0)
    args = parse(["--record", "r.jsonl", "--foxglove"])
    assert (args.command, args.name, args.record, args.foxglove, args.foxglove_port) == ("watch", "*", "r.jsonl",
                                                                                         True, 8765)
    args = parse(["--record", "r.jsonl", "watch", "--plain"])         # before and after the command
    assert (args.command, args.record, args.plain) == ("watch", "r.jsonl", True)
    args = p.parse_args(["mark", "c1", "FL", "--clock", "3", "--finish", "--note", "a; b = c"])
    assert (args.code, args.clock, args.start, args.finish, args.note) == ("FL", 3, False, True, "a; b = c")
    args = p.parse_args(["preset", "c1", "-3.5", "--unit", "ft"])
    assert (args.distance, args.unit) == (-3.5, "ft")


@pytest.mark.parametrize("argv, message", [
    (["led", "c1", "1.5"], "LEVEL: 1.5 is outside 0..1"),
    (["led", "c1", "bright"], "LEVEL: 'bright' is not a number"),
    (["led", "c1"], "LEVEL"),
    (["reset", "c*"], "crawler name 'c*'"),
    (["reset", "*"], "crawler name '*'"),
    (["mark", "*", "FL"], "crawler name '*'"),
    (["zero", "a/b"], "crawler name 'a/b'"),
    (["preset", "c1", "12,40"], "DISTANCE: '12,40' is not a distance"),
    (["preset", "c1", "nan"], "DISTANCE: 'nan' is not a plausible distance"),
    (["preset", "c1", "1", "--unit", "yd"], "invalid choice: 'yd'"),
    (["units", "c1", "mm"], "invalid choice: 'mm'"),
    (["direction", "c1", "sideways"], "invalid choice: 'sideways'"),
    (["mark", "c1", "F L"], "observation code 'F L'"),
    (["mark", "c1", "FL", "--clock", "0"], "clock 0 is outside 1..12"),
    (["mark", "c1", "FL", "--start", "--finish"], "not allowed with argument --start"),
    (["mark", "c1", "FL", "--note", "x" * 201], "at most 200 characters"),
    (["plot", "{tmp}/missing.csv"], "no such record file"),
    (["plot", "{tmp}/garbage.csv"], "garbage.csv:1: not a crawler-monitor CSV"),
    (["plot", "{tmp}/garbage.jsonl"], "garbage.jsonl:1: not a JSON line"),
    (["plot", "{tmp}/garbage.mcap"], "garbage.mcap: not an MCAP file"),
    (["plot", "{tmp}/empty.csv"], "nothing to plot: the record is empty"),
    (["plot", "{tmp}/alive.jsonl"], "nothing to plot: the record has no distance messages"),
    (["plot", "{tmp}/empty.csv", "-o", "{tmp}/x.jpg"], "the output is .png, .svg, .pdf"),
    (["plot", "{tmp}/empty.csv", "-o", "{tmp}/nope/x.png"], "no folder"),
    (["report", "{tmp}/empty.csv", "-o", "{tmp}/x.pdf"], "the output is .html, .csv"),
    (["--record", "{tmp}/run.txt"], "suffix must be .csv, .jsonl or .mcap"),
    (["--record", "{tmp}/old.mcap"], "an MCAP file cannot be appended to"),
    (["--duration", "-1"], "--duration: '-1' must be more than 0 s"),
    (["--foxglove-port", "http"], "'http' is not a TCP port"),
    (["--name", "a/b"], "crawler name 'a/b'"),
    (["--connect", "not-an-endpoint", "--duration", "1"], "not-an-endpoint"),
    (["--zenoh-config", "{tmp}/nope.json5", "status", "c1"], "no such file"),
    (["frobnicate"], "invalid choice: 'frobnicate'"),
])
def test_bad_arguments_are_one_line_and_exit_2(tmp_path, capsys, argv, message):
    (tmp_path / "garbage.csv").write_text("\x00\x01 what\n")
    (tmp_path / "garbage.jsonl").write_text("{{{\n")
    (tmp_path / "garbage.mcap").write_bytes(b"PK\x03\x04 a zip file")
    (tmp_path / "old.mcap").write_bytes(b"\x89MCAP0\r\n")
    (tmp_path / "empty.csv").write_text(",".join(COLUMNS) + "\n")
    (tmp_path / "alive.jsonl").write_text('{"t_unix": 1.0, "name": "c1", "topic": "alive", "data": {"alive": true}}\n')
    message = message.format(tmp=tmp_path)
    rc, out, err = run_main(capsys, *(a.format(tmp=tmp_path) for a in argv))
    assert rc == 2, err
    assert err.count("\n") == 1 and err.startswith("crawler-monitor: error: ") and message in err, err
    assert "Traceback" not in err and out == ""


# -- on the network ---------------------------------------------------------------------------------

class Fleet:
    """Two emulated daemons, c1 and c2, publishing at 50 Hz from a thread once started."""

    def __init__(self):
        self.c1 = FakeCrawler("c1", free_port(), speed_m_s=0.5)
        self.c2 = FakeCrawler("c2", free_port(), speed_m_s=1.0, refuse=("led",))
        self.flags = ["--no-multicast"] + [f"--connect=tcp/127.0.0.1:{c.port}" for c in (self.c1, self.c2)]
        self._stop = threading.Event()
        self._thread = None
        self.c2_open = True

    def start(self, script=lambda: ({}, True)):
        """script() -> (c1's publish flags, c2 still running), asked before every frame."""
        def loop():
            while not self._stop.is_set():
                flags, c2_on = script()
                self.c1.publish(**flags)
                if c2_on:
                    self.c2.publish()
                elif self.c2_open:
                    self.c2_open = False
                    self.c2.close()                  # its token goes: the monitor must say SILENT
                time.sleep(0.02)
        self._thread = threading.Thread(target=loop, daemon=True)
        self._thread.start()

    def close(self):
        self._stop.set()
        if self._thread:
            self._thread.join(5)
        self.c1.close()
        if self.c2_open:
            self.c2.close()


@pytest.fixture
def fleet():
    f = Fleet()
    try:
        yield f
    finally:
        f.close()


def test_watch_records_two_crawlers_marks_silent_lost_bridged(fleet, tmp_path, capsys):
    record = tmp_path / "run.csv"
    both_since = []

    def script():
        """Once the monitor has both: c1 loses tracking 0.2..0.4 s, is bridged 0.4..0.6 s; c2 stops at 1 s."""
        if not both_since:
            text = record.read_text() if record.exists() else ""
            if ",c1,distance," in text and ",c2,distance," in text:
                both_since.append(time.monotonic())
            return {}, True
        phase = time.monotonic() - both_since[0]
        return {"tracking": not 0.2 <= phase < 0.6, "bridged": 0.4 <= phase < 0.6}, phase < 1.0

    fleet.start(script)
    t0 = time.monotonic()
    rc, out, err = run_main(capsys, "watch", *fleet.flags, "--record", record, "--duration", 2.5)
    assert rc == 0, err
    assert 2.4 < time.monotonic() - t0 < 6
    assert both_since, "the monitor never received both crawlers"
    assert "recorded" in err and str(record) in err

    rows = read_records(record)
    for crawler in (fleet.c1, fleet.c2):
        got = [r for r in rows if r["name"] == crawler.name and r["topic"] == "distance"]
        sent = {p["seq"]: p for p in crawler.published}
        assert len(got) > 20, crawler.name
        seqs = [int(r["seq"]) for r in got]
        assert seqs == list(range(seqs[0], seqs[-1] + 1)), f"{crawler.name}: lost messages on loopback"
        for r in got:                               # every value as published
            p = sent[int(r["seq"])]
            for key in ("frame", "t_s", "distance_m", "sigma_m", "speed_m_s", "quality", "tracking", "bridged",
                        "slip", "source", "footage_m", "unit", "direction", "footage", "run_id"):
                assert r.get(key) == p[key], (crawler.name, key, r, p)
        assert any(r["topic"] == "status" and r["fps"] == 50.0 for r in rows if r["name"] == crawler.name)

    events = [(r["name"], r["event"], r.get("detail", "")) for r in rows if r["topic"] == "event"]
    assert ("c2", "silent", "liveliness token gone") in events
    assert not any(n == "c1" and e == "silent" for n, e, _ in events)
    for kind in ("lost", "bridged", "tracking"):
        assert any(n == "c1" and e == kind for n, e, _ in events), kind
    bridged = [r for r in rows if r["name"] == "c1" and r["topic"] == "distance" and r["bridged"]]
    held = [r for r in rows if r["name"] == "c1" and r["topic"] == "distance" and not r["tracking"]
            and not r["bridged"]]
    assert bridged and all(r["source"] == "model" for r in bridged)
    assert held and all("speed_m_s" not in r and r["quality"] == 0.0 for r in held)

    lines = out.splitlines()                        # not a terminal: one plain line per update
    assert any(" c1 distance seq=" in ln and "sigma_m=" in ln for ln in lines)
    assert any(ln.endswith("c2 SILENT liveliness token gone") for ln in lines)
    assert any(" c1 BRIDGED camera blind: distance carried by the motion model" in ln for ln in lines)
    assert "\x1b[" not in out


def test_every_command_round_trips_on_its_own_key(fleet, capsys):
    net = fleet.flags
    fleet.start()

    def ask(*argv):
        rc, out, err = run_main(capsys, *argv, *net)
        assert rc == 0, err
        return [json.loads(ln) for ln in out.splitlines()]

    assert ask("reset", "c1") == [{"ok": True, "cmd": "reset", "distance_m": 0.0, "run_id": "c1-run2"}]
    assert ask("led", "c1", "0.4") == [{"ok": True, "cmd": "led", "level": 0.4}]
    assert ask("zero", "c1")[0]["footage_m"] == 0.0
    assert ask("units", "c1", "ft")[0]["unit"] == "ft"
    reply = ask("preset", "c1", "40.0")[0]                         # in the crawler's unit: feet
    assert reply["footage"] == "40.0 ft" and reply["footage_m"] == pytest.approx(12.192)
    assert ask("preset", "c2", "12.4", "--unit", "m")[0]["footage_m"] == pytest.approx(12.4)
    assert ask("direction", "c1", "upstream")[0]["direction"] == "upstream"
    mark = ask("mark", "c1", "BAB", "--clock", "3", "--start", "--note", "crack; at = the joint")[0]
    obs = mark["observation"]
    assert (obs["code"], obs["clock"], obs["kind"], obs["note"], obs["unit"]) == (
        "BAB", 3, "start", "crack; at = the joint", "ft")
    assert obs["run_id"] == "c1-run2" and obs["distance_m"] > 0
    ask("mark", "c1", "BAB", "--finish")
    listed = ask("observations", "c1")[0]["observations"]
    assert [(o["id"], o["kind"]) for o in listed] == [(1, "start"), (2, "finish")]
    assert ask("status", "c2")[0]["name"] == "c2"
    assert sorted(s["name"] for s in ask("status", "*")) == ["c1", "c2"]              # one reply each
    assert sorted(len(r["observations"]) for r in ask("observations", "*")) == [0, 2]
    verbs = [verb for verb, _ in fleet.c1.handled]
    assert verbs == ["reset", "led", "zero", "units", "preset", "direction", "mark", "mark", "observations",
                     "status", "observations"]
    assert ("led", {"level": 0.4}) in fleet.c1.handled
    assert ("preset", {"distance_m": 12.4}) in fleet.c2.handled

    rc, out, err = run_main(capsys, "led", "c2", "0.3", *net)          # the daemon says no
    assert rc == 1 and out == ""
    assert err == ("crawler-monitor: error: crawler c2 refused led: crawler busy: no answer within 2 s "
                   "(is the camera delivering frames?)\n")
    t0 = time.monotonic()
    rc, out, err = run_main(capsys, "zero", "c9", "--timeout", "0.5", *net)   # nobody there
    assert rc == 1 and out == "" and 0.4 < time.monotonic() - t0 < 3
    assert err == ("crawler-monitor: error: no crawler named 'c9' answered zero within 0.5 s on "
                   "crawler/c9/cmd/zero (is crawlerd running, and can this laptop reach it? try --connect "
                   "tcp/IP:7447)\n")


class Tty(io.StringIO):
    """The live view's screen: a terminal as far as the monitor can tell."""

    def isatty(self):
        return True


def test_a_mark_typed_in_the_live_view_reaches_the_daemon_and_the_record(fleet, tmp_path, monkeypatch):
    monkeypatch.setenv("COLUMNS", "160")                 # the width rich gives the screen
    fleet.start()
    record = tmp_path / "run.jsonl"
    args = build_parser().parse_args(["watch", "--record", str(record), *fleet.flags, "--name", "c1"])
    master, slave = pty.openpty()
    screen = Tty()
    watch = Watch(args, out=screen, keyboard=Keyboard(slave))
    stop = threading.Event()

    def operator():
        assert wait_for(lambda: "c1" in watch.fleet.crawlers, timeout=15)
        os.write(master, b"mFL @3 start crack at the joint")
        time.sleep(0.6)                                   # the view redraws the prompt as it is typed
        os.write(master, b"\r")
        assert wait_for(lambda: watch.fleet.crawlers["c1"].observations, timeout=10)
        time.sleep(0.3)                                   # one more redraw with the observation
        os.write(master, b"q")

    typist = threading.Thread(target=operator)
    session = open_session(args)
    try:
        typist.start()
        t0 = time.monotonic()
        watch.run(session, stop=stop.is_set)
        assert time.monotonic() - t0 < 25, "q did not end the watch"
    finally:
        typist.join(10)
        session.close()
        watch.close()
        os.close(master)
        os.close(slave)
    assert ("mark", {"code": "FL", "clock": 3, "kind": "start", "note": "crack at the joint"}) in fleet.c1.handled
    observations = [r for r in read_records(record) if r["topic"] == "observations"]
    assert {(o["code"], o["clock"], o["kind"]) for o in observations} == {("FL", 3, "start")}
    raw = screen.getvalue()
    assert "\x1b[?25l" in raw and raw.rstrip().endswith("\x1b[?25h")      # cursor hidden, then back
    text = " ".join(re.sub(r"\x1b\[[0-9;?]*[A-Za-z]", "", raw).split())
    assert "mark c1> FL @3 start crack at the joint_" in text               # the prompt as it was typed
    assert "c1 #1 FL @3 start" in text and "m mark q quit" in text


def test_a_laptop_that_joins_late_gets_the_runs_observations(fleet, tmp_path, capsys):
    for _ in range(5):
        fleet.c1.publish()
    fleet.c1.mark({"code": "CL", "clock": 12})
    fleet.c1.mark({"code": "FL", "kind": "start", "note": "before the laptop"})
    fleet.start()
    record = tmp_path / "late.csv"
    rc, out, err = run_main(capsys, *fleet.flags, "--name", "c1", "--record", record, "--duration", 1.5)
    assert rc == 0, err
    got = [r for r in read_records(record) if r["topic"] == "observations"]
    assert [(r["id"], r["code"]) for r in got] == [("1", "CL"), ("2", "FL")]
    assert ("observations", {}) in fleet.c1.handled
    assert " c1 MARK #1 CL @12 " in out


@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGINT])
def test_a_signal_ends_the_watch_cleanly_and_keeps_the_record(fleet, tmp_path, signum):
    fleet.start()
    record = tmp_path / "run.jsonl"
    proc = subprocess.Popen([sys.executable, "-m", "crawler.monitor", *fleet.flags, "--record", str(record)],
                            cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            stdin=subprocess.DEVNULL)
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


def _crawlerd_sim(tmp_path, port, frames):
    return subprocess.Popen([sys.executable, "-m", "crawler", "--sim", "--no-multicast",
                             "--listen", f"tcp/127.0.0.1:{port}", "--max-frames", str(frames),
                             "--state-dir", str(tmp_path / "state")],
                            cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def test_the_whole_loop_with_crawlerd_sim(tmp_path, capsys):
    """crawlerd --sim on loopback: the monitor records it until it stops (its token goes: SILENT)."""
    port = free_port()
    record = tmp_path / "sim.mcap"
    daemon = _crawlerd_sim(tmp_path, port, 180)
    try:
        rc, out, err = run_main(capsys, "--no-multicast", "--connect", f"tcp/127.0.0.1:{port}", "--record",
                                record, "--duration", 7)
        assert rc == 0, err
        d_out, d_err = daemon.communicate(timeout=30)
    finally:
        if daemon.poll() is None:
            daemon.kill()
            daemon.communicate()
    assert daemon.returncode == 0, d_err
    rows = read_records(record)
    dist = [r["distance_m"] for r in rows if r["topic"] == "distance" and r["name"] == "crawler1"]
    assert len(dist) > 30, d_err
    assert all(b >= a - 1e-9 for a, b in zip(dist, dist[1:]))             # forward all the way
    stats = [r for r in rows if r["topic"] == "status"]
    assert stats and all(r["source"] == "sim" and r["sim_true_distance_m"] is not None for r in stats)
    assert any(r["topic"] == "event" and r["event"] == "silent" and r["detail"] == "liveliness token gone"
               for r in rows), "the daemon stopped but the monitor did not mark it silent"
    assert " crawler1 SILENT liveliness token gone" in out
    rc, out, err = run_main(capsys, "plot", record, "-o", tmp_path / "sim.png")
    assert rc == 0 and "1 crawler(s) crawler1" in out, err


def test_commands_reach_crawlerd_sim(tmp_path, capsys):
    port = free_port()
    net = ["--no-multicast", "--connect", f"tcp/127.0.0.1:{port}"]
    daemon = _crawlerd_sim(tmp_path, port, 600)
    try:
        rc, out, err = run_main(capsys, "status", "crawler1", "--timeout", "6", *net)
        assert rc == 0 and json.loads(out)["name"] == "crawler1", err
        for argv in (["zero", "crawler1"], ["units", "crawler1", "ft"], ["preset", "crawler1", "40"],
                     ["mark", "crawler1", "FL", "--clock", "3"], ["led", "crawler1", "0.3"], ["reset", "crawler1"]):
            rc, out, err = run_main(capsys, *argv, *net)
            assert rc == 0 and json.loads(out)["ok"] is True, (argv, err)
    finally:
        daemon.kill()
        daemon.communicate()


def test_the_live_view_without_rich_says_how_to_install_it_before_zenoh_opens(monkeypatch):
    from crawler.monitor.deps import MissingExtra

    for name in [m for m in sys.modules if m == "rich" or m.startswith("rich.")]:
        monkeypatch.setitem(sys.modules, name, None)
    monkeypatch.setitem(sys.modules, "rich", None)
    args = build_parser().parse_args(["watch"])
    with pytest.raises(MissingExtra, match=r"the live view needs rich .*pip install 'crawlerd\[monitor\]'.*--plain"):
        Watch(args, out=Tty())
    Watch(build_parser().parse_args(["watch", "--plain"]), out=Tty()).close()      # plain needs no rich
