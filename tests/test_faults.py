"""Faults a hostile but realistic user found (issue 10), reproduced as that user met them.

Real `python -m crawler` processes on real files: a disk that fills mid-run is a real write failure
(RLIMIT_FSIZE in the child: Python ignores SIGXFSZ, so the write fails with EFBIG, as on a full disk),
devices and /proc are the real ones, a damaged recording is a real H.264 stream with bytes flipped.
The Zenoh and LED checks run in-process on real sessions and gpiozero's own mock pins.
docs/reliability.md lists every fault of the issue with the test that shows it.
"""

import json
import os
import re
import resource
import subprocess
import sys
import threading
import time
from fractions import Fraction
from pathlib import Path

import numpy as np
import pytest

from conftest import wait_for

ROOT = Path(__file__).resolve().parents[1]
SHORT = dict(tilt_deg=0, speed_m_s=0.2, duration_s=2.0)      # the session's shared 61-frame recording


def crawlerd(*args, file_limit=None, timeout=120):
    """Run crawlerd as a user would; (exit code, summary or None, stderr). `file_limit` caps the size
    of any file the process writes (bytes), like a disk with that much room left."""
    def limit():
        resource.setrlimit(resource.RLIMIT_FSIZE, (file_limit, file_limit))

    p = subprocess.run([sys.executable, "-m", "crawler", *map(str, args)], cwd=ROOT, capture_output=True,
                       text=True, timeout=timeout, env=dict(os.environ, CRAWLERD_CONFIG=os.devnull),
                       preexec_fn=limit if file_limit else None)
    lines = [ln for ln in p.stdout.splitlines() if ln.startswith("{")]
    return p.returncode, (json.loads(lines[-1]) if lines else None), p.stderr


def one_error_line(err: str, *words) -> bool:
    """Exactly one line on stderr, crawlerd's error line, holding every word; no traceback."""
    lines = err.splitlines()
    return len(lines) == 1 and lines[0].startswith("crawlerd: error: ") and all(w in lines[0] for w in words)


def decodable_frames(path) -> int:
    """Frames a tolerant player gets out of a (possibly cut-off) video."""
    import av

    n = 0
    with av.open(str(path)) as c:
        for packet in c.demux(video=0):
            try:
                n += len(packet.decode())
            except av.error.FFmpegError:
                pass
    return n


# -- outputs ------------------------------------------------------------------------------------------

def test_an_output_that_cannot_be_written_is_refused_before_the_first_frame(render_run, tmp_path):
    run = render_run("tilt0", **SHORT)
    log = tmp_path / "run.jsonl"
    for flag, path, why in [("--log", "/dev/full", "it is a device"),
                            ("--log", "/proc/self/status", "Invalid argument"),
                            ("--annotate", "/proc/crawlerd.mp4", "No such file or directory"),
                            ("--annotate", "/proc/self/status", "Invalid argument"),
                            ("--annotate", tmp_path / "no-such-folder" / "out.mp4", "does not exist")]:
        extra = ["--log", log] if flag == "--annotate" else []
        rc, summary, err = crawlerd("--replay", run["h264"], *extra, flag, path)
        assert rc == 2 and summary is None, (path, err)
        assert one_error_line(err, f"'{path}'", why), err
        if extra:                            # the log beside it: opened, and not one frame measured
            assert log.read_text() == "", path


def test_a_disk_that_fills_mid_run_ends_it_with_the_file_named_and_the_summary(render_run, tmp_path):
    run = render_run("tilt0", **SHORT)
    log = tmp_path / "run.jsonl"
    rc, s, err = crawlerd("--replay", run["h264"], "--log", log, file_limit=8000)
    assert rc == 1 and one_error_line(err, f"cannot write log '{log}'", "File too large")
    assert s["error"] == err.splitlines()[0].removeprefix("crawlerd: error: ")
    assert 5 < s["frames"] < run["truth"]["frames"]                     # it stopped there
    assert log.stat().st_size == 8000                                    # all it could take, on disk
    whole = log.read_text().splitlines()[:-1]                            # the last line is cut off
    assert [json.loads(line)["frame"] for line in whole] == list(range(s["frames"] - 1))

    # where the annotated video's 1 s fragments start, from a run with room enough
    video = tmp_path / "run.mp4"
    assert crawlerd("--replay", run["h264"], "--annotate", video)[0] == 0
    data = video.read_bytes()
    fragments = [m.start() - 4 for m in re.finditer(b"moof", data)]
    assert len(fragments) == 3                                   # frames 0-29, 30-59, 60

    rc, s, err = crawlerd("--replay", run["h264"], "--annotate", video, file_limit=fragments[1] // 2)
    assert rc == 1 and one_error_line(err, f"cannot write annotated video '{video}'", "File too large")
    assert s["frames"] < run["truth"]["frames"] and s["error"].startswith("cannot write annotated video")
    assert video.stat().st_size == fragments[1] // 2 and decodable_frames(video) >= 5   # plays up to the break

    # the last fragment is written as the file is closed: a failure there is reported too
    rc, s, err = crawlerd("--replay", run["h264"], "--annotate", video, file_limit=(fragments[2] + len(data)) // 2)
    assert rc == 1 and one_error_line(err, f"cannot finish annotated video '{video}'", "File too large")
    assert s["frames"] == run["truth"]["frames"] and decodable_frames(video) == 60      # two whole seconds


# -- inputs -------------------------------------------------------------------------------------------

def flip_bytes(src: Path, dst: Path, share: float, seed: int = 1) -> Path:
    data = np.frombuffer(src.read_bytes(), np.uint8).copy()
    rng = np.random.default_rng(seed)
    at = rng.choice(len(data), int(len(data) * share), replace=False)
    data[at] ^= rng.integers(1, 256, len(at), dtype=np.uint8)
    dst.write_bytes(data.tobytes())
    return dst


def packets(path: Path) -> int:
    import av

    with av.open(str(path)) as c:
        return sum(1 for p in c.demux(video=0) if p.size)


def damaged_copy(src: Path, dst: Path, frames: int, split: bool) -> Path:
    """1 % of the bytes flipped, with the first seed whose damage keeps the frame count (split=False)
    or splits a frame in two (split=True): which seed does which depends on the encoder's bytes."""
    for seed in range(1, 40):
        if (packets(flip_bytes(src, dst, 0.01, seed)) > frames) == split:
            return dst
    raise AssertionError(f"no seed {'splits' if split else 'keeps'} the frames of {src}")


def test_a_damaged_stream_is_counted_and_reported_in_every_timing_mode(render_run, tmp_path):
    run = render_run("tilt0", **SHORT)
    n = run["truth"]["frames"]
    flipped = damaged_copy(run["h264"], tmp_path / "flipped.h264", n, split=False)
    for timing in (["--fps", 30], ["--pts", run["pts"]]):
        rc, s, err = crawlerd("--replay", flipped, *timing)
        damage = [w for w in s.get("warnings", []) if "frames are damaged" in w]
        assert len(damage) == 1 and f"crawlerd: warning: {damage[0]}" in err, (timing, err)
        damaged = int(damage[0].split()[0])
        assert damaged > 30, damage                          # most of them: each holds ~200 flipped bytes
        assert s["tracking_share"] < 0.5 and any("tracking was lost in" in w for w in s["warnings"])
    # flipped bytes that split a frame in two: the pts file no longer fits, and the error says what will
    split = damaged_copy(run["h264"], tmp_path / "split.h264", n, split=True)
    rc, s, err = crawlerd("--replay", split, "--pts", run["pts"])
    assert rc == 2 and one_error_line(err, f"has {packets(split)} frames but", f"only {n} timestamps",
                                      "replay it with --fps N")
    rc, s, err = crawlerd("--replay", run["h264"], "--fps", 30)     # the intact stream: nothing to say
    assert rc == 0 and "warnings" not in s and err == ""


def write_h264(path: Path, frames, fps=30) -> Path:
    import av

    with av.open(str(path), "w", format="h264") as c:
        stream = c.add_stream("libx264", rate=Fraction(fps))
        stream.width, stream.height, stream.pix_fmt = 960, 720, "yuv420p"
        for i, grey in enumerate(frames):
            yuv = np.full((720 * 3 // 2, 960), 128, np.uint8)
            yuv[:720] = grey
            frame = av.VideoFrame.from_ndarray(yuv, format="yuv420p")
            frame.pts = i
            for packet in stream.encode(frame):
                c.mux(packet)
        for packet in stream.encode():
            c.mux(packet)
    return path


def test_implausible_rates_still_images_and_blank_videos_are_refused(render_run, tmp_path):
    import cv2

    run = render_run("tilt0", **SHORT)
    for rate in ("1e9", "0", "nan", "-30"):
        rc, s, err = crawlerd("--replay", run["h264"], "--fps", rate)
        assert rc == 2 and s is None and f"'{rate}' must be a frame rate between 0.1 and 1000 fps" in err

    import av

    with av.open(str(run["h264"])) as c:                    # a frame of the recording, as a picture
        wall = next(c.decode(video=0)).to_ndarray(format="gray")
    for ext, kind in ((".png", "png_pipe"), (".jpg", "jpeg_pipe")):
        still = tmp_path / f"still{ext}.h264"                # a picture saved under a video's name
        still.write_bytes(cv2.imencode(ext, wall)[1].tobytes())
        rc, s, err = crawlerd("--replay", still, "--fps", 30)
        assert rc == 2 and s is None and one_error_line(err, f"is a still image ({kind}), not a video")

    for name, grey in (("black", 0), ("uniform", 128)):
        video = write_h264(tmp_path / f"{name}.h264", [np.full((720, 960), grey, np.uint8)] * 30)
        rc, s, err = crawlerd("--replay", video, "--fps", 30)
        assert rc == 1 and s["frames"] == 30 and s["distance_m"] == 0.0
        assert one_error_line(err, "tracking was never acquired in 30 frames"), err
        assert s["error"].startswith("tracking was never acquired")

    one = write_h264(tmp_path / "one.h264", [wall])          # a recording cut after its first frame
    rc, s, err = crawlerd("--replay", one, "--fps", 30)
    assert rc == 1 and s["frames"] == 1 and one_error_line(err, "only one frame could be read"), err


# -- state --------------------------------------------------------------------------------------------

@pytest.mark.parametrize("text,why,lost", [
    ('{"distance_m": Infinity, "run_id": "abc123def456", "frames": 9}', "inf is not a finite", "its distance"),
    ('{"distance_m": 1e400, "run_id": "abc123def456", "frames": 9}', "inf is not a finite", "(1e400 m)"),
    ('{"distance_m": 12.34, "run_id": "abc123def456", "fra', "Unterminated string", "(12.34 m)"),
    ('{"distance_m": 3.5, "run_id": "../../etc", "frames": 9}', "is not a run id", "(3.5 m)"),
    ('{"distance_m": true, "run_id": "abc123def456", "frames": 9}', "True is not a finite", "its distance"),
    ('{"distance_m": 1' + '0' * 400 + ', "run_id": "abc123def456", "frames": 9}', "is not a finite", "0 m)"),  # no float
])
def test_a_checkpoint_that_is_not_valid_is_set_aside_naming_the_distance_lost(tmp_path, caplog, text, why, lost):
    from crawler.checkpoint import Checkpoint

    (tmp_path / "checkpoint.json").write_text(text)
    store = Checkpoint(tmp_path)
    assert store.load() is None
    aside = list(tmp_path.glob("checkpoint.corrupt-*.json"))
    assert len(aside) == 1 and aside[0].read_text() == text and not (tmp_path / "checkpoint.json").exists()
    assert why in store.problem and f"{lost} is lost" in store.problem and aside[0].name in store.problem
    assert store.problem in caplog.text


def test_a_stalled_disk_never_stalls_the_frame_loop(tmp_path):
    """An SD card that stalls: the loop hands states over and goes on; the newest lands once it wakes."""
    from crawler.checkpoint import Checkpoint, CheckpointOutput

    class StalledCard(Checkpoint):
        def __init__(self, directory):
            super().__init__(directory)
            self.awake = threading.Event()

        def save(self, state):
            self.awake.wait(10)
            super().save(state)

    class Run:
        distance_m = 0.0

        def state(self):
            return {"distance_m": self.distance_m, "run_id": "0123abcd", "frames": 0}

    store, run, now = StalledCard(tmp_path), Run(), [0.0]
    out = CheckpointOutput(store, every_s=0.1, clock=lambda: now[0])
    worst = 0.0
    for i in range(100):                      # 12 s of frames, the disk asleep all along
        run.distance_m, now[0] = i * 0.01, i / 8        # 8 fps: every frame handed over
        t0 = time.perf_counter()
        out.write(None, None, run)
        worst = max(worst, time.perf_counter() - t0)
    assert worst < 0.005, worst
    store.awake.set()
    assert wait_for(lambda: (Checkpoint(tmp_path).load() or {}).get("distance_m") == pytest.approx(0.99))
    out.close()


# -- network and pins ---------------------------------------------------------------------------------

def test_a_session_whose_declaration_fails_is_closed_and_frees_its_port(zenoh_pair, monkeypatch):
    import zenoh

    from crawler.link import ZenohLink, make_zenoh_config

    real_open = zenoh.open

    class RefusesQueryables:
        """A real, listening session on which declaring a queryable fails (as a refusing router would)."""

        def __init__(self, session):
            self._session = session

        def __getattr__(self, name):
            return getattr(self._session, name)

        def declare_queryable(self, *args, **kwargs):
            raise zenoh.ZError("declaration refused")

    monkeypatch.setattr(zenoh, "open", lambda conf: RefusesQueryables(real_open(conf)))
    conf = lambda: make_zenoh_config("peer", listen=zenoh_pair["listen"], multicast=False)   # noqa: E731
    link = ZenohLink("c1", conf(), None, retry_s=600)
    try:
        link.open()
        assert not link.connected and "declaration refused" in link.last_error
        monkeypatch.undo()
        real_open(conf()).close()            # the port is free again: the failed session was closed
    finally:
        link.close()


def strict_json(text: str):
    """json.loads refusing NaN/Infinity, as every JSON parser but Python's does."""
    def refuse(word):
        raise ValueError(f"{word} is not JSON")
    return json.loads(text, parse_constant=refuse)


def test_every_command_to_a_running_daemon_ends_at_once_and_every_payload_is_strict_json(tmp_path):
    """Refused or run, a query on cmd/<verb> ends with its one reply well inside the asker's timeout (the
    old control key held refused queries open 3-30 s), and all that is published is JSON."""
    import signal

    import zenoh

    from conftest import free_port
    from crawler.zenoh_config import make_zenoh_config

    port = free_port()
    proc = subprocess.Popen([sys.executable, "-m", "crawler", "--sim", "--no-multicast", "--listen",
                             f"tcp/127.0.0.1:{port}", "--state-dir", str(tmp_path / "state")], cwd=ROOT,
                            env=dict(os.environ, CRAWLERD_CONFIG=os.devnull), stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    samples = []
    op = zenoh.open(make_zenoh_config("peer", connect=[f"tcp/127.0.0.1:{port}"], multicast=False))
    op.declare_subscriber("crawler/crawler1/**", lambda s: samples.append((str(s.key_expr), str(s.encoding),
                                                                           s.payload.to_string())))

    def ask(selector, payload=None):
        t0 = time.monotonic()
        replies = [("ok", r.ok.payload.to_string()) if r.ok is not None else ("err", r.err.payload.to_string())
                   for r in op.get(selector, payload=payload, timeout=5.0)]
        return replies, time.monotonic() - t0

    try:
        assert wait_for(lambda: ask("crawler/crawler1/status")[0], timeout=60), (
            proc.stderr.read() if proc.poll() is not None else "no status")
        for selector, payload, words in [
                ("cmd/explode", None, "unknown command 'explode'"),
                ("cmd/led?level=2", None, "between 0 and 1"),
                ("cmd/led?level=abc", None, "must be a number"),
                ("cmd/led?level=NaN", None, "between 0 and 1"),
                ("cmd/led", json.dumps({"level": True}), "not true/false"),
                ("cmd/led", "{not json", "is not JSON"),
                ("cmd/led?level=0.4", None, None), ("status", None, None)]:
            replies, took = ask(f"crawler/crawler1/{selector}", payload)
            assert len(replies) == 1 and took < 1.0, (selector, replies, took)
            kind, body = replies[0][0], strict_json(replies[0][1])
            if words is None:
                assert kind == "ok" and body["ok"] is True, (selector, body)
            else:
                assert kind == "err" and words in body["error"], (selector, body)
        assert strict_json(ask("crawler/crawler1/status")[0][0][1])["led_level"] == 0.4
        assert wait_for(lambda: any(key.endswith("/status") for key, _, _ in samples), timeout=10)   # 1 Hz
    finally:
        proc.send_signal(signal.SIGTERM)
        proc.communicate(timeout=30)
        op.close()
    assert proc.returncode == 0
    keys = {key.rsplit("/", 1)[-1] for key, _, _ in samples}
    assert {"distance", "speed", "status"} <= keys
    assert {enc for _, enc, _ in samples} == {"application/json"}
    for _, _, text in samples:
        strict_json(text)


class LgpioError(Exception):
    """What lgpio raises (lgpio.error, a plain Exception): not one of gpiozero's errors."""


def test_an_lgpio_error_names_the_pin_and_releases_the_others():
    from gpiozero.pins.mock import MockFactory, MockPWMPin

    from crawler.errors import CrawlerError
    from crawler.leds import Leds

    class LgpioPin(MockPWMPin):
        """gpiozero's mock pin, failing where lgpio fails: a claimed pin, a PWM rate out of range."""

        def __init__(self, factory, info):
            if info.name == "GPIO13":
                raise LgpioError("GPIO busy")
            super().__init__(factory, info)

        def _set_frequency(self, value):
            if value is not None and not 0.1 <= value <= 10000:
                raise LgpioError("bad PWM frequency")
            super()._set_frequency(value)

    pins = MockFactory(pin_class=LgpioPin)
    try:
        with pytest.raises(CrawlerError, match=r"LED pin 13 cannot be driven \(LgpioError: GPIO busy\)"):
            Leds([12, 13], pin_factory=pins)
        assert pins.pin(12).state == 0 and pins.pin(12).frequency is None      # released again
        with pytest.raises(CrawlerError, match=r"LED pin 12 cannot be driven \(LgpioError: bad PWM frequency\)"
                                               r".*frequency_hz"):
            Leds([12], frequency_hz=20000, pin_factory=pins)
    finally:
        pins.reset()


# -- on the Pi ----------------------------------------------------------------------------------------

def test_a_plain_pip_install_leaves_numpy_opencv_and_pyav_to_apt():
    """PyPI has no armv7 wheels of these: a dependency on them makes pip on the Pi build OpenCV and
    numpy 2 from source over apt's. Only the `pc` extra may ask for them (the real install is
    checked on a Debian bookworm root by tests/packaging/bookworm_install_check.sh)."""
    import tomllib

    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    names = lambda reqs: {re.split(r"[<>=!~\[; ]", r, maxsplit=1)[0].lower() for r in reqs}   # noqa: E731
    apt_built = {"numpy", "opencv-python", "opencv-python-headless", "opencv-contrib-python", "av"}
    assert not names(project["dependencies"]) & apt_built
    assert {"numpy", "opencv-python-headless", "av"} <= names(project["optional-dependencies"]["pc"])
