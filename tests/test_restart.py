"""A restart is a gap: measured across against the saved frame when the wall is still in view, else
declared with its length. Unit tests on synthetic motion, then crawlerd --sim as a real process."""

import json
import time

import numpy as np
import pytest

from conftest import sim_daemon, stop_after
from crawler.checkpoint import Checkpoint, CheckpointOutput
from crawler.odometry import Odometer
from crawler.geometry import make_projection
from crawler.restart import RestartGap
from test_odometry import CAM, M_PER_PX, MOUNT, ROI, view

def reference_after(texture, moved_px):
    odo = Odometer(CAM, make_projection("pixel", MOUNT), ROI)
    for i in range(10):
        odo.update(view(texture, 3.0 * i), i / 30)
    img, d, lat = odo.reference
    return (img.copy(), d, lat), 27 * M_PER_PX


def test_a_restart_that_still_sees_the_saved_wall_is_measured_across(texture):
    ref, at_m = reference_after(texture, 27)
    assert ref[1] == pytest.approx(at_m, abs=2e-5)
    gap = RestartGap(down_s=5.0, checkpoint_m=ref[1] + 0.001, reference=ref)
    odo = Odometer(CAM, make_projection("pixel", MOUNT), ROI)
    assert gap.begin(odo, 100.0)
    est = odo.update(view(texture, 27.0 + 60.0), 100.0)         # moved 60 px while down
    assert gap.observe(est) == 0.0 and gap.state == "measured"
    assert gap.measured_m == pytest.approx(60 * M_PER_PX, abs=3e-5)
    assert odo.distance == pytest.approx(87 * M_PER_PX, abs=3e-5) and gap.unmeasured_s == 0.0


def test_a_restart_far_from_the_saved_wall_is_declared_unknown_and_counts_on_from_the_checkpoint(texture):
    ref, _ = reference_after(texture, 27)
    gap = RestartGap(down_s=4.0, checkpoint_m=ref[1] + 0.05, reference=ref)
    odo = Odometer(CAM, make_projection("pixel", MOUNT), ROI)
    gap.begin(odo, 50.0)
    shift = 0.0
    for i in range(20):                                          # 2000 px on: no overlap
        est = odo.update(view(texture, 2000.0 + 3 * i), 50.0 + i / 30)
        shift += gap.observe(est)
        if not gap.open:
            break
    assert gap.state == "unknown" and gap.unmeasured_s == 4.0
    assert shift == pytest.approx(0.05)                          # the published distance goes on from 0.05 m later
    assert not est.continuous


def test_with_a_wheel_the_unseen_restart_is_the_wheels_and_nothing_is_unmeasured(texture):
    gap = RestartGap(down_s=3.0, checkpoint_m=1.0, reference=None, wheel=True)
    odo = Odometer(CAM, make_projection("pixel", MOUNT), ROI)
    assert not gap.begin(odo, 0.0)
    assert gap.state == "wheel" and gap.unmeasured_s == 0.0 and odo.distance == 1.0


def test_the_reference_is_saved_beside_the_checkpoint_and_refused_for_another_roi(tmp_path, texture):
    ref, _ = reference_after(texture, 27)

    class Run:
        def state(self):
            return {"distance_m": 1.0, "frames": 1, "run_id": "abcdef12"}

        def reference(self):
            return 7, ref[0], {"distance_m": 0.5, "lateral_m": 0.0, "roi": list(ROI)}

    store = Checkpoint(tmp_path)
    out = CheckpointOutput(store, every_s=10.0)
    out.stop(Run())
    data = store.load()
    assert data["reference"] == {"distance_m": 0.5, "lateral_m": 0.0, "roi": list(ROI)}
    np.testing.assert_array_equal(store.load_reference(data["reference"], ROI), ref[0])
    assert store.load_reference(data["reference"], (0, 0, 100, 100)) is None
    store.reference_path.write_bytes(b"not an array")
    assert store.load_reference(data["reference"], ROI) is None


@pytest.mark.parametrize("speed, measured", [(0.004, True), (0.2, False)])
def test_crawlerd_restarted_measures_or_declares_the_time_it_was_down(tmp_path, speed, measured):
    def crawlerd(log):
        return sim_daemon("--sim-speed", speed, "--state-dir", tmp_path / "state", "--log", tmp_path / log)

    stop_after(crawlerd("a.jsonl"), 3.0)
    time.sleep(1.0)                                              # the crawler moves on while nobody watches
    summary, err = stop_after(crawlerd("b.jsonl"), 3.0)
    rows = [json.loads(line) for line in (tmp_path / "b.jsonl").read_text().splitlines()]
    true = summary["sim_true_distance_m"]
    if measured:
        assert "measured across" in err
        assert abs(summary["distance_m"] - true) < 1e-3              # nothing lost over the restart
        assert all(r["unmeasured_s"] == 0.0 for r in rows)
    else:
        assert "its distance is unknown" in err
        down = rows[-1]["unmeasured_s"]
        first = next(i for i, r in enumerate(rows) if r["tracking"])      # where the camera finds the wall
        assert 1.0 < down < 10.0 and all(r["unmeasured_s"] == down for r in rows[first:])
        assert true - summary["distance_m"] > 0.8 * speed * down     # the gap's distance is missing, and said so
