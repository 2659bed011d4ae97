"""The drive's rates, read from whole ramps the frames showed (crawler/drive.py)."""

import numpy as np
import pytest

from crawler.drive import DriveWatch, ramp_rate
from crawler.gapmodel import BridgeParams

FPS = 30.0


def stop_and_go(up, down, v=0.3, stand_s=1.0, cruise_s=2.0, creep=(0.0, 0.0)):
    """The true distance of a crawler that stands, sets off at `up` to v, cruises, brakes at `down`
    to a stand, and stands. creep (s, m/s): before the start it creeps that long at that speed."""
    go, ramp_up, ramp_down = stand_s + creep[0], v / up, v / down
    cruising, braking = go + ramp_up, go + ramp_up + cruise_s
    crept = creep[0] * creep[1]

    def truth(t):
        if t < go:
            return max(0.0, t - stand_s) * creep[1]
        return crept + rest(t)

    def rest(t):
        if t < cruising:
            return 0.5 * up * (t - go) ** 2
        d = 0.5 * v * ramp_up + v * (min(t, braking) - cruising)
        if t < braking:
            return d
        s = min(t - braking, ramp_down)
        return d + v * s - 0.5 * down * s * s

    return truth, braking + ramp_down + stand_s


def watch(truth, end_s, noise_m=0.001, blind=(), seed=1, dropped=()):
    """Feed a DriveWatch what the odometer would say: the distance with noise, and its speed as a
    least-squares slope over the last 0.25 s; blind (t0, t1): frames not measured; dropped: frames
    that never came."""
    rng = np.random.default_rng(seed)
    w = DriveWatch(BridgeParams())
    ts = np.arange(0.0, end_s, 1 / FPS)
    ds = np.array([truth(t) for t in ts]) + rng.normal(0.0, noise_m, len(ts))
    k = round(0.25 * FPS)
    for i, t in enumerate(ts):
        if any(a <= t < b for a, b in blind):
            w.lost()
            continue
        if any(a <= t < b for a, b in dropped):
            continue
        lo = max(0, i - k)
        v = float(np.polyfit(ts[lo:i + 1], ds[lo:i + 1], 1)[0]) if i - lo >= 2 else None
        w.update(float(t), float(ds[i]), v, True)
    return w


@pytest.mark.parametrize("up,down", [(0.6, 0.6), (0.4, 0.8), (0.3, 2.0)])
def test_the_rates_a_drive_set_off_and_braked_at_are_read_from_the_distances(up, down):
    """A start and a brake seen whole, distances with 1 mm of noise: each rate within 12 %."""
    truth, end = stop_and_go(up, down)
    start, brake = watch(truth, end).rates()
    assert start == pytest.approx(up, rel=0.12)
    assert brake == pytest.approx(down, rel=0.12)


def test_a_ramp_not_measured_whole_teaches_no_rate():
    """Blind for 0.2 s in the middle of the start, and over the brake's end: neither is read (a ramp's
    rate is its distances' shape, and half a ramp fits any rate); the cruise is still followed."""
    truth, end = stop_and_go(0.6, 0.6)
    w = watch(truth, end, blind=[(1.2, 1.4), (3.9, 4.2)])
    assert w.rates() == (None, None)
    assert w.cruise[1] == pytest.approx(0.3, rel=0.07)          # (held within 5 % into the brake)


def test_ramp_rate_on_exact_distances_and_where_it_cannot_tell():
    """Exact distances of a start at 0.5 m/s^2 to 0.4 m/s: the rate to 2 %. A cruise too slow to
    read, or a step quicker than the range allows (a frame's jump): no rate."""
    p = BridgeParams()
    t = np.arange(0.0, 3.0, 1 / FPS)
    go, a, v = 1.0, 0.5, 0.4
    d = np.where(t < go, 0.0, np.where(t < go + v / a, 0.5 * a * (t - go) ** 2, v * (t - go) - v * v / (2 * a)))
    line = -v * go - v * v / (2 * a)
    assert ramp_rate(t, d, 0.0, v, line, True, p) == pytest.approx(a, rel=0.02)
    assert ramp_rate(t, d * 0.1, 0.0, 0.04, line * 0.1, True, p) is None
    jump = np.where(t < go, 0.0, v * (t - go))
    assert ramp_rate(t, jump, 0.0, v, -v * go, True, p) is None


@pytest.mark.parametrize("stand_s,cruise_s", [(4.0, 2.0), (1.0, 3.5), (6.0, 8.0)])
def test_a_long_stand_or_cruise_next_to_a_ramp_does_not_hide_it(stand_s, cruise_s):
    """The fit takes a second of the stand and of the cruise next to the ramp: over all of a 4 s
    stand or a 3.5 s cruise the frames did not fit the window kept, and no rate was read (a review)."""
    truth, end = stop_and_go(0.6, 0.4, stand_s=stand_s, cruise_s=cruise_s)
    start, brake = watch(truth, end).rates()
    assert start == pytest.approx(0.6, rel=0.12) and brake == pytest.approx(0.4, rel=0.12)


def test_a_creep_between_the_stand_and_the_start_is_no_ramp_of_the_drive():
    """A stand, 1 s at 0.015 m/s, then a start at 0.6 m/s^2: fitted from the stand, the creep read
    as a start at 0.37 (a review). Further from the stand than the gentlest ramp takes, or fitting
    worse than twice the frames' scatter, it is no one ramp: not read, or read right."""
    truth, end = stop_and_go(0.6, 0.6, creep=(1.0, 0.015))
    start, _ = watch(truth, end).rates()
    assert start is None or start == pytest.approx(0.6, rel=0.12)


def test_frames_that_never_came_inside_a_ramp_teach_no_rate():
    """0.2 s of frames dropped in the start and in the brake (no blind frame said so): a hole in a
    ramp is a lost frame too (read across it, 7-10 % off: a review)."""
    truth, end = stop_and_go(0.6, 0.6)
    w = watch(truth, end, dropped=[(1.2, 1.4), (3.6, 3.8)])
    assert w.rates() == (None, None)


def test_an_operator_s_reset_keeps_what_the_drive_was_seen_to_do():
    """A reset restarts the count, not the crawler: the rates its drive was seen at stay."""
    from crawler.gaps import GapBridge
    from types import SimpleNamespace

    truth, end = stop_and_go(0.6, 0.6)
    bridge = GapBridge()
    for t in np.arange(0.0, end, 1 / FPS):
        v = (truth(t) - truth(t - 0.25)) / 0.25 if t >= 0.25 else None
        bridge.update(SimpleNamespace(t_s=t, distance_m=truth(t), tracking=True, continuous=True, keyframe=False,
                                      spread_mm=0.02, inliers=40, speed_m_s=v))
    seen = bridge.drive.rates()
    bridge.reset(0.0)
    assert seen[0] == pytest.approx(0.6, rel=0.05) and bridge.drive.rates() == seen


def _service_chain(resume):
    """crawlerd's own composition of the distance chain, resumed from a checkpoint's state."""
    from types import SimpleNamespace

    from crawler import settings
    from crawler.service import Service

    odometer = SimpleNamespace(m_per_px=1e-4, camera=SimpleNamespace(fy=500.0))
    return Service._chain(SimpleNamespace(settings=settings.load(None, []), odometer=odometer), resume)


def test_a_restarted_daemon_keeps_the_drive_s_rates_and_refuses_a_bad_one(caplog):
    """The checkpoint carries the rates (not the frames): a restart does not forget how this drive
    ramps. A saved rate that is no drive's (NaN, negative, text) is named in the log and the rates
    are learnt afresh; the rest of the checkpoint stands."""
    import json

    truth, end = stop_and_go(0.6, 0.4)
    chain = _service_chain(None)
    w = watch(truth, end)
    chain.bridge.drive.restore(w.to_dict())
    saved = json.loads(json.dumps(chain.state()))              # as the checkpoint writes it
    assert saved["drive"]["start_m_s2"] == pytest.approx(0.6, rel=0.12)
    assert _service_chain(saved).bridge.drive.rates() == chain.bridge.drive.rates()
    for bad in (float("nan"), -0.5, "fast", True, 5.5, 10 ** 400):    # (5.5: beyond 1.2 x a crawler's hardest)
        caplog.clear()
        resumed = _service_chain(dict(saved, drive={"start_m_s2": bad, "brake_m_s2": 0.4}))
        assert resumed.bridge.drive.rates() == (None, None)
        assert "start_m_s2" in caplog.text and "learnt afresh" in caplog.text
    caplog.clear()
    assert _service_chain(dict(saved, drive=0.5)).bridge.drive.rates() == (None, None)   # not a table
    assert "not a table of rates" in caplog.text


def test_a_low_frame_rate_is_no_hole_in_the_frames():
    """At 6 fps every interval is longer than across_s: taken for frames that never came, no ramp
    was ever read (a review). A hole is longer than one and a half frame periods too."""
    global FPS
    truth, end = stop_and_go(0.6, 0.4, stand_s=2.0, cruise_s=3.0)
    keep, FPS = FPS, 6.0
    try:
        start, brake = watch(truth, end, noise_m=0.0005).rates()
    finally:
        FPS = keep
    assert start == pytest.approx(0.6, rel=0.2) and brake == pytest.approx(0.4, rel=0.2)
