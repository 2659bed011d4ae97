"""The shipped secure Zenoh configuration on loopback: anyone reads, only the operator commands.

Certificates are made at test time with the shipped recipe (systemd/make-zenoh-certs.sh), the daemon
runs as a real `crawlerd --sim` process with systemd/zenoh-secure.json5 (paths and ports moved to the
test's), and three real sessions try it: an anonymous reader, the operator with its client
certificate, and the same anonymous peer trying to reset.
"""

import json
import os
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from conftest import free_port, wait_for

ROOT = Path(__file__).resolve().parents[1]
pytestmark = pytest.mark.skipif(shutil.which("openssl") is None, reason="openssl is needed to make certificates")


@pytest.fixture(scope="module")
def certs(tmp_path_factory):
    d = tmp_path_factory.mktemp("tls")
    subprocess.run(["bash", str(ROOT / "systemd" / "make-zenoh-certs.sh"), str(d), "localhost", "127.0.0.1"],
                   check=True, capture_output=True)
    return d


def daemon_config(tmp_path, certs, tcp, tls):
    text = (ROOT / "systemd" / "zenoh-secure.json5").read_text()
    text = text.replace("/etc/crawler/tls", str(certs)).replace("0.0.0.0:7447", f"127.0.0.1:{tcp}")
    text = text.replace("0.0.0.0:7448", f"127.0.0.1:{tls}")
    path = tmp_path / "zenoh-secure.json5"
    path.write_text(text)
    return path


def operator_session(certs, tls):
    import zenoh

    text = (ROOT / "systemd" / "zenoh-operator.json5").read_text()
    text = text.replace("/home/operator/crawler-tls", str(certs)).replace("192.168.1.20:7448", f"localhost:{tls}")
    return zenoh.open(zenoh.Config.from_json5(text))


def anonymous_session(tcp):
    import zenoh

    from crawler.zenoh_config import make_zenoh_config

    return zenoh.open(make_zenoh_config("peer", connect=[f"tcp/127.0.0.1:{tcp}"], multicast=False))


def ask(session, selector, timeout=3.0):
    return [("ok", json.loads(r.ok.payload.to_string())) if r.ok is not None
            else ("err", json.loads(r.err.payload.to_string())) for r in session.get(selector, timeout=timeout)]


def test_anyone_reads_only_the_operator_commands(tmp_path, certs):
    tcp, tls = free_port(), free_port()
    conf = daemon_config(tmp_path, certs, tcp, tls)
    env = dict(os.environ, CRAWLERD_CONFIG=os.devnull)
    proc = subprocess.Popen([sys.executable, "-m", "crawler", "--sim", "--zenoh-config", str(conf),
                             "--state-dir", str(tmp_path / "state")], cwd=ROOT, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    anon = operator = None
    try:
        anon = anonymous_session(tcp)
        dist = []
        anon.declare_subscriber("crawler/crawler1/distance", lambda s: dist.append(json.loads(s.payload.to_string())))
        assert wait_for(lambda: len(dist) > 5, timeout=60), proc.stderr.read() if proc.poll() is not None else ""
        assert wait_for(lambda: ask(anon, "crawler/crawler1/status", timeout=1.0) != [], timeout=10)
        status = ask(anon, "crawler/crawler1/status")[0][1]
        assert status["control"] == "authenticated"
        assert ask(anon, "crawler/crawler1/cmd/reset", timeout=1.0) == []      # refused: never reached it
        assert dist[-1]["distance_m"] > 0.02                                   # not zeroed
        operator = operator_session(certs, tls)
        assert wait_for(lambda: ask(operator, "crawler/crawler1/status", timeout=1.0) != [], timeout=10)
        kind, body = ask(operator, "crawler/crawler1/cmd/reset")[0]
        assert kind == "ok" and body["distance_m"] == 0.0
        assert ask(anon, "crawler/crawler1/status")[0][1]["run_id"] == body["run_id"]
    finally:
        for s in (anon, operator):
            if s is not None:
                s.close()
        proc.send_signal(signal.SIGTERM)
        out, err = proc.communicate(timeout=30)
    assert proc.returncode == 0, err
    assert "open to any peer" not in err                       # no warning: commands are authenticated


def test_open_commands_are_warned_about_and_in_the_status(tmp_path):
    import zenoh  # noqa: F401

    tcp = free_port()
    env = dict(os.environ, CRAWLERD_CONFIG=os.devnull)
    proc = subprocess.Popen([sys.executable, "-m", "crawler", "--sim", "--no-multicast", "--listen",
                             f"tcp/127.0.0.1:{tcp}", "--state-dir", str(tmp_path / "state")], cwd=ROOT, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    anon = anonymous_session(tcp)
    try:
        assert wait_for(lambda: ask(anon, "crawler/crawler1/status", timeout=1.0) != [], timeout=60)
        assert ask(anon, "crawler/crawler1/status")[0][1]["control"] == "open"
    finally:
        anon.close()
        proc.send_signal(signal.SIGTERM)
        out, err = proc.communicate(timeout=30)
    assert "commands (cmd/reset, cmd/led, cmd/zero, cmd/preset, cmd/units, cmd/direction, cmd/mark, cmd/observations) are open to any peer" in err


@pytest.mark.parametrize("mutate,words", [
    (lambda t: t.replace('rules: ["command_in", "command_out"]', 'rules: ["command_in", "nope"]'),
     "Rule 'nope' in policy #1 does not exist"),
    (lambda t: t.replace("crawler.key", "missing.key"), "listen_private_key"),
])
def test_a_config_zenoh_refuses_is_exit_2_at_start_and_in_check_config(tmp_path, certs, mutate, words):
    conf = daemon_config(tmp_path, certs, free_port(), free_port())
    conf.write_text(mutate(conf.read_text()))
    env = dict(os.environ, CRAWLERD_CONFIG=os.devnull)
    for extra in ([], ["--check-config"]):
        p = subprocess.run([sys.executable, "-m", "crawler", "--sim", "--zenoh-config", str(conf),
                            "--state-dir", str(tmp_path / "state"), "--max-frames", "5", *extra],
                           cwd=ROOT, env=env, capture_output=True, text=True, timeout=60)
        assert p.returncode == 2 and words in p.stderr and p.stderr.count("\n") == 1, (extra, p.stderr)
