"""The Zenoh link on real loopback sessions: topics, liveliness, control, and a network that is not there."""

import json
import threading
import time

import numpy as np
import pytest

from conftest import wait_for
from crawler.commands import CommandQueue, CommandRefused, number
from crawler.link import ZenohLink, ZenohOutput, make_zenoh_config
from crawler.errors import BadConfig


def query(session, selector, payload=None, timeout=3.0):
    out = []
    for reply in session.get(selector, payload=payload, timeout=timeout):
        if reply.ok is not None:
            out.append(("ok", json.loads(reply.ok.payload.to_string())))
        else:
            out.append(("err", json.loads(reply.err.payload.to_string())))
    return out


class Loop:
    """Stands in for the frame loop: drains the command queue every 10 ms."""

    def __init__(self, commands):
        self.commands, self.handled, self._stop = commands, [], threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self):
        while not self._stop.wait(0.01):
            self.commands.drain(self.handle)

    def handle(self, req):
        self.handled.append(req)
        if req["cmd"] == "boom":
            raise CommandRefused("unknown command 'boom'")
        return {"cmd": req["cmd"], **({"level": number(req, "level", 0, 1)} if req["cmd"] == "led" else {})}

    def stop(self):
        self._stop.set()


@pytest.fixture
def link(zenoh_pair):
    commands = CommandQueue()
    lk = ZenohLink("c1", make_zenoh_config("peer", listen=zenoh_pair["listen"], multicast=False), commands)
    lk.open()
    lk.loop = Loop(commands)
    try:
        yield lk
    finally:
        lk.loop.stop()
        lk.close()


def test_topics_liveliness_status_and_commands(link, operator):
    got, alive, encodings = [], [], []

    def on_distance(s):
        got.append(json.loads(s.payload.to_string()))
        encodings.append(str(s.encoding))

    operator.declare_subscriber("crawler/*/distance", on_distance)
    operator.liveliness().declare_subscriber("crawler/*/alive", lambda s: alive.append(str(s.kind)), history=True)
    assert wait_for(lambda: alive == ["SampleKind.PUT"])
    assert wait_for(lambda: query(operator, "crawler/c1/status", timeout=0.5) != [])
    for i in range(5):
        link.publish_estimate({"t_s": i / 30, "distance_m": 0.01 * i, "speed_m_s": float("nan"), "quality": 1.0,
                               "tracking": True})
        if i == 0:
            wait_for(lambda: got, timeout=3)
    assert wait_for(lambda: got and got[-1]["seq"] == 5)
    assert len(got) >= 4 and got[-1]["distance_m"] == pytest.approx(0.04)
    assert got[-1]["speed_m_s"] is None                   # NaN is not JSON: published as null
    assert set(encodings) == {"application/json"}

    assert query(operator, "crawler/c1/status") == [("ok", {"cmd": "status", "ok": True})]
    assert query(operator, "crawler/c1/cmd/reset") == [("ok", {"cmd": "reset", "ok": True})]
    assert query(operator, "crawler/c1/cmd/led?level=0.5") == [("ok", {"cmd": "led", "level": 0.5, "ok": True})]
    assert query(operator, "crawler/c1/cmd/led", payload=json.dumps({"level": 0.25})) == [
        ("ok", {"cmd": "led", "level": 0.25, "ok": True})]
    for selector, payload, words in [
            ("crawler/c1/cmd/boom", None, "unknown command"),
            ("crawler/c1/cmd/led", json.dumps({"level": True}), "not true/false"),
            ("crawler/c1/cmd/led?level=abc", None, "must be a number"),
            ("crawler/c1/cmd/led?level=NaN", None, "between 0 and 1"),
            ("crawler/c1/cmd/led?level=2", None, "between 0 and 1"),
            ("crawler/c1/cmd/led", "{not json", "not JSON"),
            ("crawler/c1/cmd/led", "[1, 2]", "JSON object")]:
        kind, body = query(operator, selector, payload=payload)[0]
        assert kind == "err" and words in body["error"], (selector, body)
    link.close()
    assert wait_for(lambda: alive[-1:] == ["SampleKind.DELETE"])


def test_every_query_ends_with_its_reply_at_once(link, operator):
    """Refused or answered, the asker's get() returns well before its timeout (3 s here)."""
    assert wait_for(lambda: query(operator, "crawler/c1/status", timeout=0.5) != [])
    slowest = 0.0
    for selector in ["crawler/c1/cmd/boom", "crawler/c1/cmd/led?level=2", "crawler/c1/cmd/led?level=0.4",
                     "crawler/c1/status", "crawler/c1/cmd/reset"] * 4:
        t0 = time.monotonic()
        replies = query(operator, selector, timeout=3.0)
        slowest = max(slowest, time.monotonic() - t0)
        assert len(replies) == 1, selector
    assert slowest < 0.25, slowest          # ~one loop period; never the 3 s timeout


def test_unopenable_session_keeps_measuring_and_retries(zenoh_pair):
    import socket

    host, port = zenoh_pair["listen"][0].split("/")[1].split(":")
    blocker = socket.socket()
    blocker.bind((host, int(port)))
    blocker.listen()
    lk = ZenohLink("c2", make_zenoh_config("peer", listen=zenoh_pair["listen"], multicast=False), retry_s=0.2)
    try:
        lk.open()
        assert not lk.connected and "zenoh" in lk.last_error
        lk.publish_estimate({"t_s": 0, "distance_m": 0, "speed_m_s": 0})    # a no-op, not an error
        blocker.close()
        assert wait_for(lambda: lk.connected, timeout=10)
        assert lk.last_error is None
    finally:
        blocker.close()
        lk.close()


def test_bad_zenoh_settings_name_the_value(tmp_path):
    with pytest.raises(BadConfig, match="not-an-endpoint"):
        make_zenoh_config("peer", listen=["not-an-endpoint"])
    with pytest.raises(BadConfig, match="no such file"):
        make_zenoh_config(config_file=str(tmp_path / "nope.json5"))
    bad = tmp_path / "bad.json5"
    bad.write_text("{ mode: ")
    with pytest.raises(BadConfig, match="not a valid zenoh config"):
        make_zenoh_config(config_file=str(bad))


def test_command_queue_hands_requests_to_the_loop_and_times_out():
    q = CommandQueue(timeout_s=2.0)
    result = {}
    t = threading.Thread(target=lambda: result.setdefault("r", q.submit({"cmd": "status"})))
    t.start()
    assert wait_for(lambda: q._items)
    q.drain(lambda req: {"answer": req["cmd"]})
    t.join(2)
    assert result["r"] == {"answer": "status"}
    slow = CommandQueue(timeout_s=0.1)
    with pytest.raises(TimeoutError, match="busy"):
        slow.submit({"cmd": "reset"})
    assert not slow._items                       # a request the caller gave up on never runs later


def test_publishing_resumes_when_the_operator_comes_back(link, zenoh_pair):
    import zenoh

    def operator_session():
        s = zenoh.open(make_zenoh_config("peer", connect=zenoh_pair["connect"], multicast=False))
        got = []
        s.declare_subscriber("crawler/c1/distance", lambda x: got.append(json.loads(x.payload.to_string())))
        return s, got

    def publish_until(got, timeout=10):
        def one():
            link.publish_estimate({"t_s": 0.0, "distance_m": 1.0, "speed_m_s": 0.1})
            return bool(got)
        return wait_for(one, timeout=timeout, interval=0.1)

    first, got1 = operator_session()
    assert publish_until(got1)
    first.close()                                   # the laptop's cable is pulled
    for _ in range(5):
        link.publish_estimate({"t_s": 0.1, "distance_m": 1.1, "speed_m_s": 0.1})   # into the void: no error
    assert link.last_error is None
    second, got2 = operator_session()               # plugged back in
    try:
        assert publish_until(got2)
        assert got2[-1]["seq"] > got1[-1]["seq"]
    finally:
        second.close()


def test_the_publish_rate_is_kept_on_a_schedule(link):
    # 60 fps with +-3 ms of jitter thinned to 30 Hz: every other frame, not every third
    now = [0.0]

    class Run:
        def describe(self, est):
            return est

        def status(self):
            return {"name": "c1"}

    out = ZenohOutput(link, publish_hz=30.0, status_hz=1.0, clock=lambda: now[0])
    rng = np.random.default_rng(0)
    start = link.seq
    for i in range(600):                              # 10 s
        now[0] = i / 60 + rng.uniform(-0.003, 0.003)
        out.write(None, {"t_s": now[0], "distance_m": 0.0, "speed_m_s": 0.0}, Run())
    assert 297 <= link.seq - start <= 301
    now[0] += 5.0                                     # a stalled camera: no burst after it
    for i in range(6):
        out.write(None, {"t_s": now[0], "distance_m": 0.0, "speed_m_s": 0.0}, Run())
        now[0] += 1 / 60
    assert link.seq - start <= 301 + 3
