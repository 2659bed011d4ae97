"""Issue 14: a camera turned while the crawler stands is a turn, not travel (crawler/camturn.py)."""

import math
from dataclasses import replace

import numpy as np
import pytest

from crawler import settings as S
from crawler.camturn import CameraTurn, TurnParams, solve_turn, turned_before
from crawler.geometry import make_projection
from crawler.measurement import recording_camera, thesis_roi


def _turned_view(tilt_deg=24.0, turn_deg=3.0, travel_m=0.004, n=30, seed=1):
    """Features seen by the keyframe at tilt_deg, and where the camera sees them after it drove
    travel_m and turned turn_deg: (projection at a tilt, keyframe tilt, normalised points then and now)."""
    mount = S.MountSettings(tilt_deg=tilt_deg).mount()
    cam = recording_camera(S.CameraSettings())
    x, y, w, h = thesis_roi(cam.width, cam.height)
    rng = np.random.default_rng(seed)
    px = np.column_stack([rng.uniform(x + 20, x + w - 20, n), rng.uniform(y + 20, y + h - 20, n)])

    def at(tilt):
        return make_projection("cylinder", replace(mount, tilt_rad=tilt))

    xy_k = cam.normalise(px)
    wall = at(mount.tilt_rad).to_wall(xy_k)
    now = wall - np.array([0.0, travel_m])                 # the car drove on: the wall moved back
    xy_c = at(mount.tilt_rad + math.radians(turn_deg)).to_image(now)
    return at, mount.tilt_rad, xy_k, xy_c


@pytest.mark.parametrize("tilt_deg,turn_deg,travel_mm", [(24.0, 3.0, 0.0), (24.0, -1.5, 6.0), (40.0, -4.0, 2.0),
                                                         (0.0, 2.0, 10.0)])
def test_a_turn_and_the_travel_with_it_are_solved_exactly(tilt_deg, turn_deg, travel_mm):
    """Travel shifts every feature alike on the wall, a turn by what each row sees: the turn that
    makes them agree is the camera's, and their common shift the travel, from a guess of nothing."""
    at, kf_tilt, xy_k, xy_c = _turned_view(tilt_deg, turn_deg, travel_mm / 1000.0)
    delta, d, keep = solve_turn(at, kf_tilt, xy_k, xy_c, 0.0, math.radians(0.25))
    assert math.degrees(delta) == pytest.approx(turn_deg, abs=1e-3)
    assert keep.all()
    assert np.mean(d[:, 1]) * 1000 == pytest.approx(travel_mm, abs=0.01)
    # read as travel at one tilt, the turn would have been millimetres of it
    plain = at(kf_tilt).to_wall(xy_k) - at(kf_tilt).to_wall(xy_c)
    assert abs(np.mean(plain[:, 1]) * 1000 - travel_mm) > 2.0


def test_a_stray_track_is_left_out_of_the_turn():
    """A track that found the wrong texture lands anywhere: left in, it pulled a 0.3 s turn 0.5 deg
    short (t-stand-turn-fast: +2 mm and the tilt after it off)."""
    at, kf_tilt, xy_k, xy_c = _turned_view(24.0, 3.3, 0.0)
    xy_c = xy_c.copy()
    xy_c[3] += (0.0, 0.04)
    delta, d, keep = solve_turn(at, kf_tilt, xy_k, xy_c, 0.0, math.radians(0.25))
    assert math.degrees(delta) == pytest.approx(3.3, abs=1e-3)
    assert not keep[3] and keep.sum() == len(keep) - 1
    assert abs(np.mean(d[:, 1])) < 1e-5


def test_a_closed_step_holds_a_turn_only_when_its_features_say_so():
    """The steps closed just before a turn is found are solved again only where the turn shows."""
    p = TurnParams()
    at, kf_tilt, xy_k, xy_c = _turned_view(24.0, 0.6, 0.015)
    solved = turned_before(at, kf_tilt, xy_k, xy_c, p)
    assert solved is not None and math.degrees(solved[0]) == pytest.approx(0.6, abs=1e-3)
    at, kf_tilt, xy_k, xy_c = _turned_view(24.0, 0.0, 0.015)
    noisy = xy_c + np.random.default_rng(2).normal(0, 2e-4, xy_c.shape)   # ~0.2 px of tracking noise
    assert turned_before(at, kf_tilt, xy_k, noisy, p) is None


def test_a_turn_begins_once_frames_in_a_row_turned_the_camera_1_5_degrees_one_way():
    """A turn: frames in a row whose flow is mostly a turn (it explains the step: the car stands),
    one way, over keyframes. A creeping car's pitch jitter explains its step too, but turns back
    (a photographed wall at 40 deg, 4 cm/s: 0.5 deg, then back); a moving car's jitter explains a
    tenth of its step; a pitch unsure of itself neither counts nor breaks the run."""
    deg = math.radians
    turn = CameraTurn()
    # 5 deg/s at a stand, keyframes of 3 frames: 0.17 deg a frame
    reads = [(kf, deg(0.17 * (i + 1))) for kf in range(4) for i in range(3)]
    begun = [turn.offer(kf, p, deg(0.02), 1.02) for kf, p in reads]
    assert begun.index(True) == 8                           # 1.53 deg in the ninth frame
    jitter = CameraTurn()
    wobble = [0.2, 0.4, 0.5, 0.3, -0.1, -0.4, -0.5, 0.1, 0.4, 0.5, 0.2]
    assert not any(jitter.offer(k, deg(p), deg(0.03), 0.9 if p > 0 else 1.1) for k, p in enumerate(wobble))
    moving = CameraTurn()
    assert not any(moving.offer(k // 3, deg(0.6 * (k % 3 + 1)), deg(0.05), 0.12) for k in range(20))
    unsure = CameraTurn()
    assert [unsure.offer(0, p, s, 1.0) for p, s in ((deg(1.0), deg(0.05)), (deg(1.2), deg(0.5)),
                                                    (deg(1.6), deg(0.05)))] == [False, False, True]
    level = CameraTurn()                                    # at 0 deg a pitch is hardest to tell: one
    assert not level.offer(0, deg(2.3), deg(0.42), 1.5)    # frame read 2.3 deg at 5 sigma, no turn
    lost = CameraTurn()
    lost.offer(0, deg(1.0), deg(0.05), 1.0)
    lost.forget()                                           # lost frames: the run starts again
    assert not lost.offer(1, deg(1.0), deg(0.05), 1.0)


def test_a_turn_ends_when_the_tilt_stands_still_or_the_car_drives():
    at, kf_tilt, xy_k, xy_c = _turned_view(24.0, 0.0, 0.0)
    p = TurnParams()
    t = np.arange(40) / 30.0

    def run(tilts, travel_mm=0.0):
        turn = CameraTurn(p)
        turn.start(kf_tilt, kf_tilt, 0.0, 0.0, 1.0 / 30.0)
        over = []
        for ti, tilt in zip(t[1:], tilts[1:]):
            view = _turned_view(24.0, tilt, travel_mm / 1000.0)
            turn.frame(at, view[2], view[3], ti)           # every frame against the first keyframe
            over.append(turn.still(ti))
        return turn, over

    turning, over = run(5.0 * t)                             # 5 deg/s all along: never over
    assert not any(over) and math.degrees(turning.tilt - kf_tilt) == pytest.approx(5.0 * t[-1], abs=0.01)
    held, over = run(np.minimum(5.0 * t, 2.0))              # held at 2 deg from 0.4 s: over ~0.4 s later
    first = over.index(True) + 1
    assert 0.75 < t[first] < 1.0 and all(over[first - 1:])
    jitter = 0.3 * np.sin(2 * np.pi * 3.0 * t)              # a car's jitter about a still tilt: over
    assert run(2.0 + jitter)[1][-1]
    _, over = run(np.full(len(t), 0.05) + 5.0 * t, travel_mm=8.0)   # a car driving while it turns: not
    assert not any(over[:10])
    _, over = run(2.0 + 0.3 * t, travel_mm=100.0)           # a car that drove on, the turn a tenth: over
    assert over[-1] and not over[10]
    assert turning.end() == pytest.approx(p.sigma_share * abs(turning.tilt - turning.began))


def test_a_camera_turned_at_a_stand_is_not_read_as_travel(render_run, crawlerd, tmp_path):
    """The crawler stops, the operator turns the camera 24 -> 32 deg in a second, and it drives on.
    Before session 21 the turn read as travel: +4.6 % (38 mm on 0.84 m), the tilt found again
    only once it drove. Now the turn is followed while it happens, and the tilt is right after it."""
    from test_pose import replay

    run = render_run("stand-turn", tilt_deg=24, tilt_schedule=((2.4, 24.0), (3.4, 32.0)), speed_m_s=0.3,
                     profile="stopgo", stopgo_period_s=4.0, stopgo_dwell_s=2.0, duration_s=6.0, seed=86)
    s, rows, truth = replay(crawlerd, run, tmp_path, "--tilt", "auto")
    path = run["truth"]["path_length_m"]
    assert 100 * abs(s["distance_m"] - run["truth"]["true_distance_m"]) / path < 0.4
    assert abs(s["pose"]["tilt_deg"] - 32.0) < 0.3 and s["pose"]["tilt_turning"] is False
    assert s["pose"]["tilt_steps"] >= 1
    at_stand = [r for r in rows if 3.6 < r["t_s"] < 3.9 and r.get("tilt_deg") is not None]
    assert at_stand and all(abs(r["tilt_deg"] - 32.0) < 1.0 for r in at_stand)   # followed while standing


def test_a_rolling_shutter_s_rows_turned_further_are_taken_out_of_the_turn():
    """With a rolling shutter the rows read later were turned further (33 deg/s, rows over 10 ms:
    0.3 deg across the frame). Left in, that skew reads as a smaller turn and as travel; the
    tracks' exposure times (as AutoTilt.follow_turn gives them) take it out."""
    from crawler.posefield import JacobianField

    mount = S.MountSettings(tilt_deg=24.0).mount()
    cam = recording_camera(S.CameraSettings())
    roi = thesis_roi(cam.width, cam.height)
    x, y, w, h = roi
    rng = np.random.default_rng(4)
    px = np.column_stack([rng.uniform(x + 20, x + w - 20, 40), rng.uniform(y + 20, y + h - 20, 40)])

    def at(tilt):
        return make_projection("cylinder", replace(mount, tilt_rad=tilt))

    xy_k = cam.normalise(px)
    wall = at(mount.tilt_rad).to_wall(xy_k)
    rate, turn = math.radians(33.0), math.radians(3.0)
    row_t = 0.010 * (px[:, 1] - y) / h                    # each feature's exposure after the window's first row
    xy_c = np.vstack([at(mount.tilt_rad + turn + rate * t).to_image(wall[i:i + 1]) for i, t in enumerate(row_t)])
    shift = -JacobianField(cam, at(mount.tilt_rad), roi).at(xy_c)[:, 0:2] * (rate * row_t)[:, None]
    plain = solve_turn(at, mount.tilt_rad, xy_k, xy_c, 0.0, math.radians(0.25))
    timed = solve_turn(at, mount.tilt_rad, xy_k, xy_c, 0.0, math.radians(0.25), shift)
    assert abs(math.degrees(timed[0]) - 3.0) < 0.02 and abs(np.mean(timed[1][:, 1])) < 1e-4
    assert abs(math.degrees(plain[0]) - 3.0) > 0.05 and abs(np.mean(plain[1][:, 1])) > 3e-4
