"""[odometry] workers = N: real forked tracking processes and shared memory give workers = 1's distances."""

import logging
import os
import signal

import numpy as np
import pytest

from crawler.daemon import measure_serially
from crawler.errors import BadConfig
from crawler.measurement import build_odometer, recording_camera, thesis_roi
from crawler.settings import load
from crawler.video import VideoReplay
from crawler.workers import TrackerPool

RUN = dict(tilt_deg=24, speed_m_s=0.3, duration_s=2.0)


def _replay(run, settings, workers=1, depth=None, kill_after=None):
    """Per-frame distances of a recording, measured in this process or with a pool."""
    cam = recording_camera(settings.camera)
    src = VideoReplay(run["h264"], cam, default_roi=thesis_roi(cam.width, cam.height))
    with src:
        odo = build_odometer(settings, cam, src.default_roi)
        if workers == 1:
            return [e.distance_m for _, e in measure_serially(odo, src.frames())], None
        with TrackerPool(odo, (cam.height, cam.width), workers, depth) as pool:
            out = []
            for frame, est in pool.measure(src.frames()):
                out.append(est.distance_m)
                if len(out) == kill_after:
                    os.kill(pool.pids[0], signal.SIGKILL)
            return out, dict(pool.counts, pids=pool.pids)


@pytest.fixture
def run24(render_run):
    return render_run("tilt24", **RUN)


def test_workers_in_lockstep_give_the_same_distances_bit_for_bit(run24):
    s = load(None, ["mount.tilt_deg=24"], {})
    alone, _ = _replay(run24, s)
    pooled, counts = _replay(run24, s, workers=3, depth=1)
    assert pooled == alone                      # the same floats: the same tracks, from the other processes
    assert counts["tracked_by_workers"] >= len(alone) - 2 and counts["stopped"] == 0


def test_the_pipeline_keeps_the_distance_within_micrometres_and_the_accuracy(run24):
    s = load(None, ["mount.tilt_deg=24"], {})
    alone, _ = _replay(run24, s)
    pooled, counts = _replay(run24, s, workers=4)
    assert len(pooled) == len(alone) == run24["truth"]["frames"]
    assert np.max(np.abs(np.array(pooled) - alone)) < 5e-6
    truth = run24["truth"]
    assert abs(pooled[-1] - truth["true_distance_m"]) / truth["path_length_m"] < 0.003
    # every renewed keyframe sends the frames in flight again; the workers tracked nearly every frame
    assert counts["resent"] > 0 and counts["tracked_by_workers"] >= len(alone) - 5
    assert all(not _alive(pid) for pid in counts["pids"])     # none outlives the pool


def test_a_killed_worker_leaves_the_run_measuring_on_the_others(run24, caplog):
    s = load(None, ["mount.tilt_deg=24"], {})
    alone, _ = _replay(run24, s)
    with caplog.at_level(logging.ERROR, logger="crawler.workers"):
        pooled, counts = _replay(run24, s, workers=3, kill_after=10)
    assert len(pooled) == len(alone) and np.max(np.abs(np.array(pooled) - alone)) < 5e-6
    assert counts["stopped"] == 1 and "tracking worker 1 stopped" in caplog.text


def test_crawlerd_replay_with_four_workers_reports_them(run24, crawlerd):
    rc1, one, _ = crawlerd("--replay", run24["h264"], "--tilt", 24)
    rc4, four, _ = crawlerd("--replay", run24["h264"], "--tilt", 24, "--workers", 4)
    assert rc1 == rc4 == 0 and "workers" not in one
    assert four["frames"] == one["frames"] and four["distance_m"] == pytest.approx(one["distance_m"], abs=5e-6)
    w = four["workers"]
    assert w["processes"] == 3 and w["depth"] == 4 and w["stopped"] == 0
    assert w["tracked_by_workers"] >= four["frames"] - 5


def test_bad_worker_counts_are_refused_with_the_key(crawlerd, run24):
    with pytest.raises(BadConfig, match=r"\[odometry\] workers.*between 1 and 16"):
        load(None, ["odometry.workers=0"], {})
    with pytest.raises(SystemExit):
        crawlerd("--replay", run24["h264"], "--workers", "0")
    with pytest.raises(ValueError, match="workers >= 2"):
        TrackerPool(None, (480, 640), 1)


def _alive(pid: int) -> bool:
    """A running (not reaped, not zombie) process."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[-1].split()[0] != "Z"
    except FileNotFoundError:
        return False


def test_flat_fielded_keyframes_are_tracked_flattened_by_the_workers_too(render_run, monkeypatch):
    # a wet wall under the LED's highlight at 40 deg: most keyframes are tracked flattened
    # (crawler/flow.py, static_pull); the workers are sent the flattened keyframe and its flag
    from crawler import odometry

    run = render_run("wet40", tilt_deg=40, speed_m_s=0.1, duration_s=2.0, wet_patches=((0.0, 1.0),),
                     lighting=True, seed=5)
    flats = []
    new_keyframe = odometry.Odometer._new_keyframe

    def counted(self, *a, **kw):
        made = new_keyframe(self, *a, **kw)
        flats.extend([self._kf.flat] if made else [])
        return made

    monkeypatch.setattr(odometry.Odometer, "_new_keyframe", counted)
    s = load(None, ["mount.tilt_deg=40"], {})
    alone, _ = _replay(run, s)
    pooled, counts = _replay(run, s, workers=3, depth=1)
    assert sum(flats) >= 3
    assert pooled == alone and counts["tracked_by_workers"] >= 40


def test_the_pool_hands_on_each_frame_s_quantiser_and_i_frame_flag(run24):
    """A pooled replay dropped the frames' QP (so sigma had no compression term) and would drop the
    I-frames the stand watch must not compare across (crawler/stands.py)."""
    s = load(None, ["mount.tilt_deg=24"], {})
    cam = recording_camera(s.camera)
    with VideoReplay(run24["h264"], cam, default_roi=thesis_roi(cam.width, cam.height)) as src:
        direct = [(f.index, f.intra) for f in src.frames()]
    with VideoReplay(run24["h264"], cam, default_roi=thesis_roi(cam.width, cam.height)) as src:
        odo = build_odometer(s, cam, src.default_roi)
        told = []                                       # the odometer's stand watch hears of each I-frame
        odo._dense.stands.recoded = lambda: told.append(odo.frame)
        with TrackerPool(odo, (cam.height, cam.width), 2) as pool:
            pooled = [(f.index, f.intra, f.qp) for f, _ in pool.measure(src.frames())]
    assert [p[:2] for p in pooled] == direct
    assert told == [k for k, intra in direct if intra]
    assert direct[0][1] and sum(intra for _, intra in direct) < len(direct) / 10     # I-frames are few
    assert all(qp is not None and qp > 0 for *_, qp in pooled)


def test_a_paced_replay_that_skips_an_i_frame_flags_the_next_frame_it_hands_on(run24):
    """A realtime replay drops frames the loop was too late for; the stand watch must still hear that
    the picture was coded anew (crawler/video.py)."""
    cam = recording_camera(load(None, ["mount.tilt_deg=24"], {}).camera)
    with VideoReplay(run24["h264"], cam) as src:
        flagged = [f.index for f in src.frames() if f.intra]

    class SkipIFrames:                                   # a loop late exactly for the I-frames
        def due(self, t_s):
            return round(t_s * 30) not in flagged

        def asked(self):
            pass

    with VideoReplay(run24["h264"], cam) as src:
        src.pacer = SkipIFrames()
        handed = [(f.index, f.intra) for f in src.frames()]
    assert [k for k, intra in handed if intra] == [k + 1 for k in flagged]
