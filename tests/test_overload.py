"""A loop that cannot keep up behaves as on a camera: the newest frame is measured, late ones are dropped
(numbered gaps, the status's drop rate), never queued, and the distance stays right across them."""

import json
import time

import pytest
from gpiozero.pins.mock import MockFactory, MockPWMPin

from crawler import settings
from crawler.daemon import Daemon
from crawler.measurement import build_odometer, recording_camera, thesis_roi
from crawler.ports import Output
from crawler.service import Hardware, Mode, RunOptions, Service
from crawler.sim import SimOptions, make_world
from crawler.video import Pacer, VideoReplay
from crawler.workers import measuring
from hw_sim import read_ground_truth


class SlowLoop(Output):
    """A test port: an output that takes `seconds` per frame (a slow disk, a busy core)."""

    def __init__(self, seconds: float, sleep=time.sleep, clock=time.monotonic):
        self.seconds, self.sleep, self.clock = seconds, sleep, clock
        self.seen = []              # (wall time, frame index, frame time) of every measured frame

    def write(self, frame, estimate, run):
        assert estimate.frame == frame.index     # published as the source numbers it: drops leave gaps
        self.seen.append((self.clock(), frame.index, frame.t_s))
        self.sleep(self.seconds)


def test_the_pacer_hands_over_the_newest_frame_never_an_early_one():
    now = [0.0]

    def sleep(s):
        now[0] += s

    pacer, handed = Pacer(clock=lambda: now[0], sleep=sleep), []
    for k in range(100):                         # 100 fps; the loop needs 2.5 frame intervals
        t = k / 100
        if pacer.due(t):
            assert now[0] >= t - 1e-12           # never before its time
            handed.append(k)
            now[0] += 0.025
            pacer.asked()
    gaps = {b - a for a, b in zip(handed, handed[1:])}
    assert handed[0] == 0 and gaps <= {2, 3} and 35 <= len(handed) <= 42


@pytest.mark.parametrize("workers", [1, 3])
def test_a_replay_at_twice_what_the_loop_can_do_drops_half_and_keeps_the_distance(render_run, workers):
    """Real time on a manual clock: the loop takes two frame intervals per frame (and a little, off the
    frames' grid) whatever this machine's load, so about every other frame is dropped."""
    run = render_run("fps60", tilt_deg=24, speed_m_s=0.3, fps=60.0, duration_s=2.0)     # 121 frames
    s = settings.load(None, ["mount.tilt_deg=24"], {})
    cam = recording_camera(s.camera)
    now = [1000.0]

    def sleep(seconds):
        now[0] += seconds

    slow = SlowLoop(2.02 / 60, sleep=sleep, clock=lambda: now[0])   # half of the recording's 60 fps
    source = VideoReplay(run["h264"], cam, realtime=True, default_roi=thesis_roi(cam.width, cam.height))
    source.pacer = Pacer(clock=lambda: now[0], sleep=sleep)
    with source:
        odo = build_odometer(s, cam, source.default_roi)
        with measuring(odo, (cam.height, cam.width), workers) as measure:
            daemon = Daemon(source, odo, name="t", outputs=[slow], measure=measure)
            stats = daemon.run()
            status, summary = daemon.status(), daemon.summary()
    seen = [i for _, i, _ in slow.seen]
    gaps = [b - a for a, b in zip(seen[3:], seen[4:])]
    assert set(gaps) <= {2, 3} and gaps.count(2) > 0.9 * len(gaps) and seen[-1] >= 117   # the newest each time
    assert stats.frames + stats.dropped == seen[-1] + 1 and stats.dropped == source.frames_dropped - (120 - seen[-1])
    assert status["dropped_frames"] == summary["dropped_frames"] == stats.dropped
    assert abs(status["drop_rate"] - 0.5) < 0.05 and abs(summary["drop_rate"] - 0.5) < 0.05
    assert any("dropped" in w for w in source.warnings)
    # the odometry measured across the gaps against its keyframe: the distance of the last frame seen
    true = read_ground_truth(run["csv"])["distance_m"][seen[-1]]
    assert stats.tracked == stats.frames
    assert abs(daemon.distance_m - true) / run["truth"]["path_length_m"] < 0.003, (daemon.distance_m, true)


@pytest.mark.parametrize("workers", [1, 3])
def test_a_slow_loop_on_the_simulated_camera_drops_frames_and_keeps_wall_time(tmp_path, workers):
    s = settings.load(None, ["camera.fps=100", f"state.directory={json.dumps(str(tmp_path))}", "mount.tilt_deg=10",
                             f"odometry.workers={workers}"])
    options = RunOptions(mode=Mode.SIM, max_frames=50, publish=False, sim=SimOptions(speed_m_s=0.3))
    world = make_world(s, options.sim)
    slow = SlowLoop(0.025)                       # 2.5 frame intervals of the 100 fps camera
    with Service(s, options, Hardware(pin_factory=MockFactory(pin_class=MockPWMPin), world=world)) as svc:
        svc.daemon.outputs.append(slow)
        stats = svc.run()
        status = svc.daemon.status()
    assert stats.error is None and stats.frames == 50
    assert ("workers" in status) == (workers > 1)
    seen = slow.seen
    gaps = [b[1] - a[1] for a, b in zip(seen, seen[1:])]
    assert min(gaps) >= 1 and sum(g > 1 for g in gaps) > len(gaps) / 2       # frames the camera dropped
    assert stats.dropped == sum(gaps) - len(gaps) == status["dropped_frames"] and status["drop_rate"] > 0.4
    # the world went on at wall-clock pace: sensor time advanced as the wall clock did between the first
    # and last frame measured (a camera that waited for the loop would show half of it or less)
    sensor_s, wall_s = seen[-1][2] - seen[0][2], seen[-1][0] - seen[0][0]
    assert 0.85 < sensor_s / wall_s < 1.05
    assert status["distance_m"] == pytest.approx(status["sim_true_distance_m"], rel=0.02)
