"""A compressed recording's systematic error in sigma (crawler/codec.py): the model, the chain, a replay."""

import json
import math

import pytest

from crawler.codec import CodecBias, keyframe_bias_px, qstep
from crawler.distance import DistanceChain
from crawler.estimate import Estimate


def test_the_bias_follows_the_quantiser_step_squared():
    assert qstep(28) == pytest.approx(2 * qstep(22))
    assert keyframe_bias_px(43) == pytest.approx(0.4)
    assert keyframe_bias_px(40) == pytest.approx(0.2)       # 2x per 3 QP
    assert keyframe_bias_px(25) < 0.01                      # CRF 18: nothing to speak of


def test_a_faint_wall_loses_more_to_the_quantiser():
    """A photographed brick wall at a third of its contrast (1.4-1.7 grey levels of fine texture)
    read 0.30 px short per keyframe at QP 33 and 0.12 px at 28: 7-10x what the model gives a wall
    with 4 or more; the bound grows as the square of the texture's shortfall."""
    assert keyframe_bias_px(33.45, 8.0) == keyframe_bias_px(33.45) == keyframe_bias_px(33.45, None)
    assert keyframe_bias_px(33.45, 1.41) == pytest.approx(keyframe_bias_px(33.45) * (4.0 / 1.41) ** 2)
    assert 0.30 < keyframe_bias_px(33.45, 1.41) < 0.45
    assert 0.06 < keyframe_bias_px(27.86, 1.53) < 0.12     # 1 sigma: 2 sigma holds the 0.12 px measured
    c = CodecBias(m_per_px=1e-3)
    for _ in range(30):
        c.update(33.0, False, 1.5)
    c.update(33.0, True, float("nan"))                     # a frame whose texture was not read
    assert c.texture_dn == pytest.approx(1.5) and c.sigma_m == pytest.approx(keyframe_bias_px(33.0, 1.5) * 1e-3)


def test_the_term_adds_up_linearly_over_closed_keyframes_and_only_with_a_qp():
    c = CodecBias(m_per_px=5e-4)
    assert c.update(None, True) == 0.0                      # raw frames: no quantiser, no term
    for _ in range(10):
        c.update(43.0, False)
    assert c.sigma_m == 0.0                                 # no keyframe closed yet
    for _ in range(4):
        c.update(43.0, True)
    assert c.sigma_m == pytest.approx(4 * 0.4 * 5e-4)       # systematic: 4x one, not 2x
    assert c.keyframes == 4


def test_an_i_frame_does_not_set_the_level_alone():
    c = CodecBias(m_per_px=1e-3)
    c.update(43.0, False)
    c.update(37.0, True)                                    # an I-frame, finer than the P-frames
    assert c.qp == pytest.approx(42.4)
    assert c.sigma_m > 0.8 * keyframe_bias_px(43.0) * 1e-3


def _est(frame, d, keyframe, tracking=True):
    return Estimate(frame=frame, t_s=frame / 30, distance_m=d, speed_m_s=0.3, lateral_m=0.0, roll_deg=None,
                    tracking=tracking, quality=1.0, tracks=30, inliers=30 if tracking else 0,
                    spread_mm=0.05, keyframe=keyframe)


def test_the_chain_publishes_it_in_sigma_and_keeps_it_for_a_restart():
    raw, coded = DistanceChain(), DistanceChain(codec=CodecBias(m_per_px=5e-4))
    for k in range(60):
        e = _est(k, 0.01 * k, keyframe=k % 6 == 0)
        a, b = raw.update(e), coded.update(e, qp=43.0)
    assert coded.codec.keyframes == 10
    assert b.sigma_m == pytest.approx(math.hypot(a.sigma_m, 10 * 0.4 * 5e-4))
    assert coded.state()["sigma_m"] == pytest.approx(math.hypot(raw.state()["sigma_m"], coded.codec.sigma_m))
    lost = coded.update(_est(60, 0.6, keyframe=True, tracking=False), qp=43.0)
    assert coded.codec.keyframes == 10 and math.isfinite(lost.sigma_m)   # a fresh start closes no baseline


def test_a_heavily_compressed_replay_reads_short_and_sigma_says_so(render_run, crawlerd, tmp_path):
    """At CRF 38 the tracks read short at every keyframe (crawler/codec.py); at CRF 18 the term is
    negligible."""
    from hw_sim import read_ground_truth

    out = {}
    for crf in (18, 38):
        run = render_run(f"crf{crf}", tilt_deg=40.0, speed_m_s=0.3, duration_s=3.0, texture="masonry", crf=crf)
        log = tmp_path / f"crf{crf}.jsonl"
        rc, s, _ = crawlerd("--replay", run["h264"], "--set", "mount.tilt_deg=40", "--log", log)
        assert rc == 0
        rows = [json.loads(line) for line in log.read_text().splitlines()]
        truth = read_ground_truth(run["csv"])["distance_m"]
        err = [r["distance_m"] - truth[r["frame"]] for r in rows]
        out[crf] = (err, [r["sigma_m"] for r in rows])
        assert s["codec"]["keyframes"] > 5 and (s["codec"]["mean_qp"] > 40 if crf == 38 else s["codec"]["mean_qp"] < 30)
    err38, sig38 = out[38]
    err18, sig18 = out[18]
    assert err38[-1] < -2e-3 < err18[-1]                   # CRF 38 reads short: 0.1 % of the path at least
    assert sum(abs(e) <= 2 * s for e, s in zip(err38, sig38)) >= 0.9 * len(err38)
    assert sig38[-1] > 1.5 * sig18[-1]                     # ...where without the term they are alike
    assert all(abs(e) <= 2 * s for e, s in zip(err18, sig18))
