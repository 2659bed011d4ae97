import json
import time

import pytest

from hw_sim import SimConfig, write_run


@pytest.fixture(scope="session")
def render_run(tmp_path_factory):
    """Render a hw_sim run once per session: render_run(name, **SimConfig fields) -> paths dict."""
    cache = {}
    root = tmp_path_factory.mktemp("runs")

    def render(name, **kw):
        key = (name, tuple(sorted(kw.items())))
        if key not in cache:
            cache[key] = write_run(SimConfig(**kw), root, name)
            cache[key]["truth"] = json.loads(cache[key]["json"].read_text())
        return cache[key]

    return render


@pytest.fixture
def crawlerd(capsys):
    """Run crawlerd's main() in-process: crawlerd(*argv) -> (exit code, summary dict or None, stderr)."""
    from crawler.cli import main

    def run(*argv):
        rc = main([str(a) for a in argv])
        out, err = capsys.readouterr()
        lines = [ln for ln in out.splitlines() if ln.startswith("{")]
        return rc, (json.loads(lines[-1]) if lines else None), err

    return run


@pytest.fixture(scope="session")
def texture():
    """A flat random wall for exactly known synthetic motion (test_odometry.view)."""
    import cv2
    import numpy as np

    rng = np.random.default_rng(7)
    tex = cv2.GaussianBlur((rng.random((6000, 640)) * 255).astype(np.float32), (0, 0), 1.3)
    return cv2.normalize(tex, None, 0, 255, cv2.NORM_MINMAX).astype(np.uint8)


def sim_daemon(*args):
    """`crawlerd --sim --no-publish ARGS` as a real process (no user config)."""
    import os
    import subprocess
    import sys
    from pathlib import Path

    env = dict(os.environ, CRAWLERD_CONFIG=os.devnull)
    return subprocess.Popen([sys.executable, "-m", "crawler", "--sim", "--no-publish", *map(str, args)],
                            cwd=Path(__file__).resolve().parents[1], env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def stop_after(proc, seconds: float):
    """SIGTERM after `seconds`: (the summary line, stderr); the daemon must exit 0."""
    import signal

    time.sleep(seconds)
    proc.send_signal(signal.SIGTERM)
    out, err = proc.communicate(timeout=60)
    assert proc.returncode == 0, err
    return json.loads(out.strip().splitlines()[-1]), err


def free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture
def zenoh_pair():
    """Endpoints for a listening daemon and a connecting operator on loopback, multicast off."""
    port = free_port()
    return {"listen": [f"tcp/127.0.0.1:{port}"], "connect": [f"tcp/127.0.0.1:{port}"]}


@pytest.fixture
def operator(zenoh_pair):
    """A second Zenoh session that connects to the daemon's endpoint; closed after the test."""
    import zenoh

    from crawler.link import make_zenoh_config

    session = zenoh.open(make_zenoh_config("peer", connect=zenoh_pair["connect"], multicast=False))
    try:
        yield session
    finally:
        session.close()


def wait_for(predicate, timeout=10.0, interval=0.05):
    import time

    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if predicate():
            return True
        time.sleep(interval)
    return predicate()
