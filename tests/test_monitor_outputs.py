"""crawler-monitor's outputs: records (CSV, JSONL, MCAP read back with mcap's own reader), the plot
(matplotlib), the report (HTML, CSV) and the live Foxglove server (a real WebSocket client)."""

import base64
import csv
import io
import json
import re
import struct
import sys
import threading
import time

import cv2
import numpy as np
import pytest

from conftest import free_port, wait_for
from fake_crawlerd import FakeCrawler
from crawler.monitor import main
from crawler.monitor.cli import build_parser
from crawler.monitor.net import open_session
from crawler.monitor.plot import plot_figure, series_from_records
from crawler.monitor.record import RecordError, open_record, read_records
from crawler.monitor.report import observation_rows, video_time
from crawler.monitor.schemas import BY_TOPIC
from crawler.monitor.watch import Watch


def est(seq, d, tracking=True, v=0.2, **extra):
    return dict({"seq": seq, "t_s": seq / 30, "distance_m": d, "speed_m_s": v if tracking else None,
                 "quality": 0.9 if tracking else 0.0, "tracking": tracking, "tracks": 40, "inliers": 36}, **extra)


OBS = {"id": 1, "run_id": "r1", "t_unix": 999.5, "t_s": 0.4, "distance_m": 0.25, "footage_m": 12.65,
       "unit": "ft", "code": "FL", "clock": 3, "kind": "start", "note": "crack, at the joint"}


def write_sample(path):
    w = open_record(path)
    w.write(1000.0, "c1", "alive", {"alive": True})
    w.write(1000.5, "c1", "distance", est(1, 0.25, frame=4, lateral_m=0.001, sigma_m=0.003, bridged=False,
                                          slip=False, source="vision", footage_m=12.65, unit="ft",
                                          direction="upstream", footage="41.5 ft", run_id="r1"))
    w.write(1000.6, "c1", "distance", est(2, 0.25, tracking=False, bridged=True, source="model"))
    return w


@pytest.mark.parametrize("suffix", [".csv", ".jsonl", ".mcap"])
def test_every_record_format_writes_flushed_messages_and_reads_them_back(tmp_path, suffix):
    path = tmp_path / f"run{suffix}"
    w = write_sample(path)
    written = path.stat().st_size                   # on disk before close: flushed per message
    assert written > (0 if suffix == ".mcap" else 100)
    w.write(1001.0, "c1", "event", {"event": "lost", "detail": "tracking lost at 0.250 m"})
    w.write(1001.2, "c1", "observations", OBS)
    w.write(1001.5, "c1", "status", {"fps": 30.0, "led_level": 0.5, "camera": {"fps": 30}, "last_error": None,
                                     "observations": 1})
    assert path.stat().st_size > written
    w.close()
    rows = read_records(path)
    assert [r["topic"] for r in rows] == ["alive", "distance", "distance", "event", "observations", "status"]
    assert rows[0]["alive"] is True and rows[0]["t_unix"] == 1000.0
    d = rows[1]
    assert (d["distance_m"], d["sigma_m"], d["speed_m_s"], d["tracking"], d["bridged"], d["source"]) == (
        0.25, 0.003, 0.2, True, False, "vision")
    assert (d["footage_m"], d["unit"], d["direction"], d["footage"], d["frame"]) == (12.65, "ft", "upstream",
                                                                                   "41.5 ft", 4)
    assert rows[2]["tracking"] is False and rows[2]["bridged"] is True and rows[2].get("speed_m_s") is None
    o = rows[4]
    assert (o["code"], o["kind"], o["note"], o["unit"], o["observed_t_unix"], o["t_unix"]) == (
        "FL", "start", "crack, at the joint", "ft", 999.5, 1001.2)
    assert int(o["clock"]) == 3 and str(o["id"]) == "1" and o["distance_m"] == 0.25
    assert rows[5]["led_level"] == 0.5 and rows[5]["observations"] == 1
    if suffix != ".mcap":
        open_record(path).close()                   # CSV and JSONL are appended to, never wiped
        assert len(read_records(path)) == 6
    else:
        with pytest.raises(RecordError, match="cannot be appended to"):
            open_record(path)


def test_the_mcap_record_has_a_schema_per_topic_and_reads_back_with_mcap(tmp_path):
    from mcap.reader import make_reader

    path = tmp_path / "run.mcap"
    w = write_sample(path)
    w.write(1000.7, "c2", "speed", {"t_s": 0.1, "speed_m_s": 0.3, "seq": 1})
    w.write(1000.8, "c1", "observations", OBS)
    w.write(1000.9, "c2", "event", {"event": "silent", "detail": "liveliness token gone"})
    w.close()
    with path.open("rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        messages = list(reader.iter_messages())
    assert summary.statistics.message_count == 6
    topics = {c.topic: c for c in summary.channels.values()}
    assert set(topics) == {"crawler/c1/alive", "crawler/c1/distance", "crawler/c2/speed",
                           "crawler/c1/observations", "crawler/c2/event"}
    for topic, channel in topics.items():
        schema = summary.schemas[channel.schema_id]
        kind = topic.split("/")[2]
        assert channel.message_encoding == "json" and schema.encoding == "jsonschema"
        assert json.loads(schema.data) == BY_TOPIC[kind] and schema.name == BY_TOPIC[kind]["title"]
        assert channel.metadata == {"crawler": topic.split("/")[1]}
    first = {}
    for schema, channel, message in messages:
        first.setdefault(channel.topic, (json.loads(message.data), message.log_time))
    assert first["crawler/c1/distance"][0]["footage"] == "41.5 ft"
    assert first["crawler/c1/distance"][1] == 1000_500_000_000
    assert first["crawler/c1/observations"][0] == OBS


def test_an_mcap_record_cut_short_by_a_crash_keeps_every_whole_message(tmp_path):
    path = tmp_path / "crash.mcap"
    w = write_sample(path)                          # never closed: no summary, no footer
    data = path.read_bytes()
    (tmp_path / "cut.mcap").write_bytes(data[:-7])  # and the last message half written
    assert [r["seq"] for r in read_records(path) if r["topic"] == "distance"] == [1, 2]
    assert [r["seq"] for r in read_records(tmp_path / "cut.mcap") if r["topic"] == "distance"] == [1]
    w.close()
    damaged = bytearray(path.read_bytes())
    damaged[60:70] = b"\xff" * 10                   # a finished file that does not read is an error
    (tmp_path / "bad.mcap").write_bytes(bytes(damaged))
    with pytest.raises(RecordError, match="damaged MCAP record"):
        read_records(tmp_path / "bad.mcap")


def synthetic_records(n=300):
    """alpha and beta at 0.1 and 0.2 m/s; beta lost 3.3..4.0 s (held) and bridged 4.0..4.7 s; marks."""
    rows = []
    for i in range(n):
        for k, name in enumerate(("alpha", "beta")):
            lost, bridged = name == "beta" and 100 <= i < 120, name == "beta" and 120 <= i < 140
            rows.append(dict(est(i, (0.1 + 0.1 * k) * i / 30, not (lost or bridged), v=0.1 + 0.1 * k,
                                 sigma_m=0.002 + 0.001 * i / 30, bridged=bridged),
                             t_unix=5000 + i / 30, name=name, topic="distance"))
    rows.append({"t_unix": 5000 + 200 / 30, "name": "alpha", "topic": "event", "event": "silent", "detail": ""})
    for obs_id, (t_s, kind) in enumerate(((2.0, "start"), (6.0, "finish"), (8.0, "point")), 1):
        o = {"id": obs_id, "run_id": "r", "t_unix": 4000.0, "t_s": t_s, "distance_m": 0.1 * t_s,
             "footage_m": 0.1 * t_s, "unit": "m", "code": "FL" if kind != "point" else "CL", "kind": kind}
        rows.append(dict(o, t_unix=5009.9, observed_t_unix=4000.0, name="alpha", topic="observations"))
        rows.append(dict(o, t_unix=5009.95, observed_t_unix=4000.0, name="alpha", topic="observations"))  # twice
    return rows


def test_the_plot_has_lines_sigma_band_shaded_stretches_and_observation_markers(tmp_path):
    records = synthetic_records()
    _, series = series_from_records(records)
    beta = series["beta"]
    assert [tuple(round(x, 2) for x in s) for s in beta.lost_spans()] == [(3.33, 4.0)]
    assert [tuple(round(x, 2) for x in s) for s in beta.bridged_spans()] == [(4.0, 4.67)]
    # observations placed by sensor time among the distance rows: no clock offset can shift them
    assert [(round(t, 3), code, kind) for t, _, code, kind in series["alpha"].observations] == [
        (2.0, "FL", "start"), (6.0, "FL", "finish"), (8.0, "CL", "point")]

    fig = plot_figure(records, (1000, 700), "test")
    ax_d, ax_v = fig.axes
    gids = [a.get_gid() for a in ax_d.get_children() if a.get_gid()]
    assert gids.count("distance:alpha") == 1 and gids.count("distance:beta") == 1
    assert "sigma:alpha" in gids and gids.count("observation:alpha") == 3 and "silent:alpha" in gids
    assert gids.count("lost:beta") == 1 and gids.count("bridged:beta") == 1
    band = next(a for a in ax_d.get_children() if a.get_gid() == "sigma:alpha")
    lo, hi = band.get_paths()[0].vertices[:, 1].min(), band.get_paths()[0].vertices[:, 1].max()
    assert lo == pytest.approx(-0.004, abs=1e-3) and hi == pytest.approx(0.1 * 299 / 30 + 2 * 0.012, abs=1e-3)
    labels = [t.get_text() for t in ax_d.get_legend().get_texts()]
    assert labels == ["alpha", "beta", "±2σ", "bridged (wheel or motion model)", "tracking lost (held)", "went silent",
                      "observation (▶ start, ◀ finish)"]
    speed = next(a for a in ax_v.get_lines() if a.get_gid() == "speed:beta")
    assert np.isnan(speed.get_ydata()[110]) and speed.get_ydata()[50] == pytest.approx(0.2)

    png = tmp_path / "p.png"
    assert main(["plot", "--size", "1000x700", str(_jsonl(tmp_path, records)), "-o", str(png)]) == 0
    img = cv2.imread(str(png))
    assert img.shape == (700, 1000, 3)
    # the bridged stretch (4.0..4.7 s of 10 s) is tinted orange: #f5a623 at alpha 0.25 over white
    orange = 255 - 0.25 * (255 - np.array([0x23, 0xa6, 0xf5]))          # BGR
    tinted = np.all(np.abs(img.astype(float) - orange) < 8, axis=2)
    cols = np.flatnonzero(tinted.sum(axis=0) > 100)                     # columns tinted in both panels
    assert 30 < len(cols) < 100 and cols.max() - cols.min() < 100


def _jsonl(tmp_path, records):
    path = tmp_path / "synthetic.jsonl"
    with path.open("w") as f:
        for r in records:
            data = {k: v for k, v in r.items() if k not in ("t_unix", "name", "topic")}
            if "observed_t_unix" in data:
                data["t_unix"] = data.pop("observed_t_unix")
            f.write(json.dumps({"t_unix": r["t_unix"], "name": r["name"], "topic": r["topic"], "data": data}) + "\n")
    return path


def test_the_report_pairs_continuous_defects_and_embeds_the_plot(tmp_path, capsys):
    records = synthetic_records()
    records.append({"t_unix": 5009.0, "name": "beta", "topic": "distance", "seq": 99, "t_s": 9.0, "distance_m": 1.8,
                    "direction": "upstream"})
    records.append({"t_unix": 5010.0, "name": "beta", "topic": "observations", "id": 1, "run_id": "b",
                    "observed_t_unix": 4100.0, "t_s": 9.0, "distance_m": 1.8, "footage_m": 1.8, "unit": "ft",
                    "code": "DAE", "kind": "start", "clock": 6.0, "note": "<deposit> & more"})
    rows = observation_rows(records)
    assert [(r["crawler"], r["code"], r["kind"], r["continuous"]) for r in rows] == [
        ("alpha", "FL", "start", "C1 start"), ("alpha", "FL", "finish", "C1 finish"), ("alpha", "CL", "point", ""),
        ("beta", "DAE", "start", "C2 start")]
    assert rows[0]["remarks"] == "continuous to 0.6 m (0.4 m long)"
    assert rows[1]["remarks"] == "continuous from 0.2 m (0.4 m long)"
    assert rows[3]["remarks"] == "<deposit> & more; no finish recorded"
    assert (rows[3]["footage"], rows[3]["clock"], rows[3]["video_time"]) == ("5.9 ft", "6", "0:00:09.0")
    assert video_time(3723.46) == "1:02:03.5" and video_time(59.96) == "0:01:00.0"

    path = _jsonl(tmp_path, records)
    rc = main(["report", str(path), "-o", str(tmp_path / "r.html"), "--title", "DN300 Main St"])
    out, err = capsys.readouterr()
    assert rc == 0, err
    assert out.strip().endswith("4 observation(s) of 2 crawler(s), 1 continuous defect(s) paired")
    page = (tmp_path / "r.html").read_text()
    assert "<h1>DN300 Main St</h1>" in page and page.count("<tr>") == 5
    assert "Survey direction: " in page and "beta: upstream" in page
    assert "&lt;deposit&gt; &amp; more" in page and "<deposit>" not in page
    png = base64.b64decode(re.search(r"base64,([A-Za-z0-9+/=]+)", page).group(1))
    img = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR)
    assert img.shape == (700, 1100, 3)

    assert main(["report", str(path), "-o", str(tmp_path / "r.csv")]) == 0
    table = list(csv.DictReader((tmp_path / "r.csv").open()))
    assert [r["code"] for r in table] == ["FL", "FL", "CL", "DAE"] and table[1]["continuous"] == "C1 finish"
    assert list(table[0]) == ["crawler", "run_id", "id", "distance_m", "footage", "unit", "video_time_s",
                              "video_time", "time", "code", "clock", "kind", "continuous", "remarks"]


# -- Foxglove --------------------------------------------------------------------------------------

def _foxglove_messages(ws, until, timeout=15.0):
    """Read the WebSocket until until(text_messages, binary_messages) holds."""
    texts, binaries = [], []
    end = time.monotonic() + timeout
    while not until(texts, binaries):
        assert time.monotonic() < end, f"no such message from the server: {texts[-3:]}"
        try:
            msg = ws.recv(timeout=max(0.05, end - time.monotonic()))
        except TimeoutError:
            continue
        (binaries if isinstance(msg, bytes) else texts).append(msg if isinstance(msg, bytes) else json.loads(msg))
    return texts, binaries


def _subscribe(ws, sub_id, channel_id, tries=3):
    """Subscribe, and read until three messages came. The SDK's server can answer a subscribe to a
    channel it advertised a moment ago "Unknown channel ID" (seen once in ~10 runs): ask again."""
    for _ in range(tries):
        ws.send(json.dumps({"op": "subscribe", "subscriptions": [{"id": sub_id, "channelId": channel_id}]}))
        texts, binaries = _foxglove_messages(ws, lambda t, b: len(b) >= 3 or any(
            "Unknown channel" in x.get("message", "") for x in t))
        if len(binaries) >= 3:
            return binaries
        time.sleep(0.2)
    raise AssertionError(f"the server refused subscribe {sub_id} to channel {channel_id}: {texts[-3:]}")


def _channels(texts):
    return {c["topic"]: c for t in texts if t.get("op") == "advertise" for c in t["channels"]}


def test_foxglove_serves_the_fleet_over_its_websocket_protocol(tmp_path):
    from websockets.sync.client import connect

    crawler = FakeCrawler("c1", free_port())
    port = free_port()
    args = build_parser().parse_args(["watch", "--plain", "--foxglove", "--foxglove-port", str(port),
                                      "--no-multicast", f"--connect=tcp/127.0.0.1:{crawler.port}"])
    watch = Watch(args, out=io.StringIO())
    stop, publishing = threading.Event(), threading.Event()
    session = open_session(args)
    loop = threading.Thread(target=lambda: watch.run(session, stop=stop.is_set))

    def publish():
        while not publishing.is_set():
            crawler.publish()
            time.sleep(0.02)
    pub = threading.Thread(target=publish, daemon=True)
    try:
        loop.start()
        pub.start()
        # as the Foxglove app connects: foxglove-sdk 0.30 speaks the protocol as `foxglove.sdk.v1`
        with connect(f"ws://127.0.0.1:{port}", subprotocols=["foxglove.sdk.v1", "foxglove.websocket.v1"]) as ws:
            assert ws.subprotocol in ("foxglove.sdk.v1", "foxglove.websocket.v1")
            texts, _ = _foxglove_messages(ws, lambda t, b: "crawler/c1/distance" in _channels(t))
            assert texts[0]["op"] == "serverInfo" and texts[0]["name"] == "crawler-monitor"
            channel = _channels(texts)["crawler/c1/distance"]
            assert (channel["encoding"], channel["schemaName"], channel["schemaEncoding"]) == (
                "json", "crawler.Distance", "jsonschema")
            assert json.loads(channel["schema"]) == BY_TOPIC["distance"]
            binaries = _subscribe(ws, 7, channel["id"])
        opcode, sub_id, t_ns = struct.unpack_from("<BIQ", binaries[0])
        assert (opcode, sub_id) == (1, 7) and abs(t_ns / 1e9 - time.time()) < 30
        payloads = [json.loads(b[13:]) for b in binaries]
        sent = {p["seq"]: p for p in crawler.published}
        assert all(p == sent[p["seq"]] for p in payloads)               # exactly as the daemon sent it
        assert [p["seq"] for p in payloads] == sorted(p["seq"] for p in payloads)
    finally:
        publishing.set()
        stop.set()
        loop.join(10)
        session.close()
        watch.close()
        crawler.close()
    assert wait_for(lambda: not _listening(port), timeout=5), "the Foxglove server still listens"


def _listening(port):
    import socket

    with socket.socket() as s:
        return s.connect_ex(("127.0.0.1", port)) == 0


@pytest.mark.parametrize("module, argv, needs", [
    ("matplotlib", ["plot", "{rec}"], "plot and report needs matplotlib"),
    ("matplotlib", ["report", "{rec}"], "plot and report needs matplotlib"),
    ("mcap", ["plot", "{tmp}/run.mcap"], "reading an MCAP record needs mcap"),
    ("mcap", ["--record", "{tmp}/new.mcap", "--duration", "1"], "an MCAP record needs mcap"),
    ("foxglove", ["--foxglove", "--duration", "1"], "--foxglove needs foxglove-sdk"),
])
def test_a_missing_monitor_package_says_how_to_install_it(tmp_path, capsys, monkeypatch, module, argv, needs):
    rec = _jsonl(tmp_path, synthetic_records(30))
    write_sample(tmp_path / "run.mcap").close()
    for name in [m for m in sys.modules if m == module or m.startswith(module + ".")]:
        monkeypatch.setitem(sys.modules, name, None)        # as if it were not installed
    monkeypatch.setitem(sys.modules, module, None)
    rc = main([a.format(rec=rec, tmp=tmp_path) for a in argv] + ["--no-multicast"] * (argv[0].startswith("-")))
    out, err = capsys.readouterr()
    assert rc == 1 and out == ""
    assert err.startswith(f"crawler-monitor: error: {needs}") and "pip install 'crawlerd[monitor]'" in err
    assert err.count("\n") == 1
