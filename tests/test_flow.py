"""LK on patches: the same tracks as LK on the whole images, at a fraction of the Pi's cost."""

import cv2
import numpy as np
import pytest

from crawler import flow
from crawler.flow import FlowParams

SHIFT = np.float32([0.37, 6.62])      # the wall's motion between the two frames (px)


@pytest.fixture(scope="module")
def pair():
    rng = np.random.default_rng(3)
    tex = cv2.GaussianBlur((rng.random((400, 400)) * 255).astype(np.float32), (0, 0), 1.5)
    tex = cv2.normalize(tex, None, 0, 255, cv2.NORM_MINMAX)
    a = tex[80:320, 80:320].astype(np.uint8)
    m = np.float32([[1, 0, SHIFT[0] - 80], [0, 1, SHIFT[1] - 80]])
    b = cv2.warpAffine(tex, m, (240, 240), flags=cv2.INTER_CUBIC).astype(np.uint8)
    pts = flow.detect(a, FlowParams(), border_px=30)
    return a, b, pts


def test_patches_give_what_lk_on_the_whole_images_gives(pair):
    a, b, pts = pair
    guess = pts + SHIFT + np.random.default_rng(1).uniform(-1, 1, pts.shape).astype(np.float32)
    params = FlowParams()
    p1, ok, rt = flow.track(a, b, pts, guess, params)
    w1, wok, wrt = flow._track_whole(a, b, pts, guess, FlowParams(levels=0))
    assert (flow._track_patches(a, b, pts, guess, params.patch_px, params)[3]).all()  # all on patch
    assert len(pts) == 30 and ok.all() and wok.all()
    assert np.abs(p1 - w1).max() < 2e-3 and np.abs(rt - wrt).max() < 2e-3
    assert np.abs(p1 - pts - SHIFT).max() < 0.1


@pytest.mark.parametrize("off_px", [7.0, 25.0])
def test_features_that_leave_their_patch_get_the_pyramid_on_the_whole_images(pair, off_px):
    a, b, pts = pair
    guess = pts + SHIFT + np.float32([0, off_px])
    params = FlowParams(levels=3)
    p1, ok, _ = flow.track(a, b, pts, guess, params)
    left = ~flow._track_patches(a, b, pts, guess, params.patch_px, params)[3]
    w1, wok, _ = flow._track_whole(a, b, pts[left], guess[left], params)
    assert left.sum() >= 5
    assert (p1[left] == w1).all() and (ok[left] == wok).all()
    # the consensus of what is ok is the true motion (a far-off guess may settle some on a wrong spot)
    assert np.abs(np.median(p1[ok] - pts[ok], axis=0) - SHIFT).max() < 0.05


def test_a_feature_whose_window_leaves_the_image_is_not_ok(pair):
    a, b, pts = pair
    near = np.float32([[120, 4.5], [120, 233.5], [3.0, 120], [120, 120]])
    p1, ok, _ = flow.track(a, b, near - SHIFT, near, FlowParams())
    assert ok.tolist() == [False, False, False, True]


@pytest.mark.parametrize("contiguous", [True, False])
def test_patches_are_the_image_blocks_stacked(contiguous):
    img = np.arange(300 * 320, dtype=np.uint32).reshape(300, 320).astype(np.uint8)
    roi = img[10:250, 20:260]
    if contiguous:
        roi = roi.copy()
    corners = np.array([[0, 0], [221, 3], [17, 221], [100, 50]], np.intp)
    got = flow.patches(roi, corners, 19)
    want = np.concatenate([roi[y:y + 19, x:x + 19] for x, y in corners])
    assert got.shape == (4 * 19, 19) and (got == want).all()


def test_no_feature_on_or_beside_a_highlight_but_bright_grains_are_kept(pair):
    a = pair[0].copy()
    a[100:140, 60:110] = 255                        # a specular highlight: a saturated blob
    pts = flow.detect(a, FlowParams(max_features=200), border_px=10)
    near = (pts[:, 0] > 60 - 6) & (pts[:, 0] < 110 + 6) & (pts[:, 1] > 100 - 6) & (pts[:, 1] < 140 + 6)
    assert len(pts) > 50 and not near.any()
    grains = pair[0].copy()
    grains[::17, ::13] = 255                        # clipped bright grains of a lit wall: no mask
    plain = flow.detect(pair[0], FlowParams(max_features=200), border_px=10)
    kept = flow.detect(grains, FlowParams(max_features=200), border_px=10)
    assert len(kept) >= 0.9 * len(plain)


def faint_under_a_lobe(pair, contrast=0.08, peak=100.0, sigma=45.0):
    """The pair's wall at a wet wall's contrast under an LED highlight fixed in the image (not
    saturated), and the highlight alone."""
    yy, xx = np.mgrid[0:240, 0:240]
    lobe = peak * np.exp(-((xx - 120.0) ** 2 + (yy - 60.0) ** 2) / (2 * sigma * sigma))
    wet = [np.clip(100 + contrast * (img.astype(np.float32) - 128) + lobe, 0, 255).astype(np.uint8)
           for img in pair[:2]]
    return wet, lobe


def test_flattened_frames_move_as_the_wall_without_the_shading_that_stays_put(pair):
    (a, b), _ = faint_under_a_lobe(pair)
    params = FlowParams()
    pts = flow.detect(a, params, border_px=30)
    guess = pts + SHIFT
    p_raw, ok_raw, _ = flow.track(a, b, pts, guess, params)
    fa, fb = flow.flatten(a, params), flow.flatten(b, params)
    p_flat, ok_flat, _ = flow.track(fa, fb, pts, guess, params)
    raw = np.median((p_raw - pts)[ok_raw, 1])
    flat = np.median((p_flat - pts)[ok_flat, 1])
    assert raw < SHIFT[1] - 0.3                      # LK on the frames: pulled toward no motion
    assert ok_flat.sum() >= 20 and abs(flat - SHIFT[1]) < 0.05


def test_static_pull_sees_the_leds_shading_not_the_walls_own_nor_a_copy(pair):
    params = FlowParams()
    (a, b), lobe = faint_under_a_lobe(pair)
    pts = flow.detect(a, params, border_px=30)
    assert flow.static_pull(b, a, pts, params) > 3 * params.flat_pull         # the highlight stays put
    assert flow.static_pull(b, b.copy(), pts, params) < 0.1 * params.flat_pull   # a copy: nothing moved
    assert flow.static_pull(b, None, pts, params) == 0.0                         # nothing to compare with
    # a lit wall whose own coarse shading is as strong as that highlight, moving with it as far as
    # between two keyframes
    rng = np.random.default_rng(4)
    tex = cv2.GaussianBlur((rng.random((400, 400)) * 255).astype(np.float32), (0, 0), 1.5)
    blobs = cv2.GaussianBlur(rng.normal(0, 1, (400, 400)).astype(np.float32), (0, 0), 30)
    wall = 0.6 * tex + 40 * blobs / blobs.std()
    before, now = wall[140:380, 80:320], wall[80:320, 80:320]
    lit = [np.clip(img, 0, 255).astype(np.uint8) for img in (before, now)]
    pts = flow.detect(lit[1], params, border_px=30)
    assert flow.static_pull(lit[1], lit[0], pts, params) < 0.5 * params.flat_pull


def test_a_flattened_frame_finds_a_highlight_in_the_frame_as_it_came(pair):
    a = pair[0].copy()
    a[100:140, 60:110] = 255
    params = FlowParams(max_features=200)
    pts = flow.detect(flow.flatten(a, params), params, border_px=10, raw=a)
    near = (pts[:, 0] > 60 - 6) & (pts[:, 0] < 110 + 6) & (pts[:, 1] > 100 - 6) & (pts[:, 1] < 140 + 6)
    assert len(pts) > 50 and not near.any()
