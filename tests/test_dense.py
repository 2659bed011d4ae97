"""The dense shift's pieces on exactly known motion: the sub-pixel read, the wall grid, OpenCV's
in-place window."""

import math

import cv2
import numpy as np
import pytest

from crawler.dense import DenseParams, DenseShift, refine
from crawler.densegrid import centre_jacobian, dense_conversion, window_jacobian
from crawler.flow import coarse_shift
from crawler.geometry import Camera, Mount, make_projection

N = 90


def shifted_pair(sig: float, shift: float, seed: int = 0):
    """Two N x N crops of one smooth random texture, the second moved shift rows up, exactly (by
    the Fourier shift theorem, on a tall periodic strip)."""
    rng = np.random.default_rng(seed)
    tall = cv2.GaussianBlur(rng.normal(0, 1, (1024, N)), (0, 0), sig)
    f = np.fft.fft(tall, axis=0)
    k = np.fft.fftfreq(tall.shape[0])[:, None]
    a = np.real(np.fft.ifft(f * np.exp(2j * np.pi * k * 300), axis=0))[:N]
    b = np.real(np.fft.ifft(f * np.exp(2j * np.pi * k * (300 + shift)), axis=0))[:N]
    return (a - a.mean()).astype(np.float32), (b - b.mean()).astype(np.float32)


@pytest.mark.parametrize("shift", [0.75, 2.5, 11.8])
def test_refine_reads_a_shift_to_a_fraction_of_a_percent_where_opencv_reads_percents(shift):
    window = cv2.createHanningWindow((N, N), cv2.CV_32F)
    opencv, ours = [], []
    for seed in range(4):
        a, b = shifted_pair(1.5, shift, seed)
        (du, dv), _ = cv2.phaseCorrelate(a.copy(), b.copy(), window)
        opencv.append(-dv / shift)
        ours.append(-refine(a, b, (du, dv))[1] / shift)
    assert np.mean(ours) == pytest.approx(1.0, abs=0.005)
    if shift < 3:                      # a centroid of the peak locks towards whole pixels
        assert abs(np.mean(opencv) - 1.0) > 0.03


def test_the_phase_correlations_leave_their_inputs_as_they_were():
    # OpenCV windows its inputs in place when their size suits its DFT: a reference kept over a gap
    # would be windowed again at every frame of it
    a, b = shifted_pair(1.5, 2.0)
    a0, b0 = a.copy(), b.copy()
    coarse_shift(a, b, cv2.createHanningWindow((N, N), cv2.CV_32F), 4.0)
    assert np.array_equal(a, a0) and np.array_equal(b, b0)
    dense = DenseShift((4 * N, 4 * N))
    frames = [cv2.resize(np.clip(120 + 20 * s, 0, 255).astype(np.uint8), (4 * N, 4 * N)) for s in (a, b) * 6]
    kept = [f.copy() for f in frames]
    for i, f in enumerate(frames):
        dense.shift(f, i / 30)
    assert all(np.array_equal(f, k) for f, k in zip(frames, kept))


def wall_frames(tilt_deg: float, step_m: float, n: int):
    """A pipe wall seen by a camera tilted forward, moved step_m along the pipe per frame: each
    pixel samples a smooth texture at its own wall point (the exact projection), with a little
    sensor noise. Returns (camera, projection, roi, frames)."""
    cam = Camera.from_fov(640, 480, 37.16, 53.50)
    projection = make_projection("cylinder", Mount(0.15, 0.2256, math.radians(tilt_deg)))
    roi = (200, 120, 240, 240)
    x, y, w, h = roi
    u, v = np.meshgrid(np.arange(x, x + w, dtype=float), np.arange(y, y + h, dtype=float))
    wall = projection.to_wall(cam.normalise(np.column_stack([u.ravel(), v.ravel()])))
    rng = np.random.default_rng(1)
    texture = cv2.GaussianBlur(rng.normal(0, 1, (3000, 1000)).astype(np.float32), (0, 0), 3.0)
    texture *= 30 / texture.std()
    mm = 2000.0                                           # texture pixels per metre: 0.5 mm each
    frames = []
    for i in range(n):
        col = (wall[:, 0] * mm + 500).reshape(h, w).astype(np.float32)
        row = ((wall[:, 1] + i * step_m) * mm + 1500).reshape(h, w).astype(np.float32)
        img = 120 + cv2.remap(texture, col, row, cv2.INTER_LINEAR)
        frames.append(np.clip(img + rng.normal(0, 0.5, img.shape), 0, 255).astype(np.uint8))
    return cam, projection, roi, frames


def dense_metres(frames, jac, maps):
    dense = DenseShift(frames[0].shape)
    dense.resample(maps)
    metres = []
    for i, f in enumerate(frames):
        found = dense.shift(f, i / 30)
        if found is not None:
            (du, dv), _, since = found
            metres.append((jac[0] * dv + jac[1] * du, round(i - since * 30)))
    return metres


def test_at_a_tilt_the_dense_shift_is_read_on_the_wall_grid_to_a_fraction_of_a_percent():
    # at 40 deg the near rows move more pixels than the far ones: one phase correlation of the
    # image reads a mean of them that its Jacobian does not know (here 1.2 % long, at 15 px a
    # frame); on the grid even in wall metres the motion is one shift
    step = 0.008
    cam, projection, roi, frames = wall_frames(40.0, step, 30)

    def wall(px):
        return projection.to_wall(cam.normalise(px))

    def pixels(sy):
        return cam.to_pixels(projection.to_image(sy))

    jac, maps = dense_conversion(wall, pixels, roi, 2, centre_jacobian(wall, roi)[0])
    assert maps is not None
    on_grid = dense_metres(frames, jac, maps)
    assert len(on_grid) > 10
    ratio = sum(m for m, _ in on_grid) / (step * sum(k for _, k in on_grid))
    assert ratio == pytest.approx(1.0, abs=0.004)
    in_image = dense_metres(frames, window_jacobian(wall, roi), None)
    ratio_image = sum(m for m, _ in in_image) / (step * sum(k for _, k in in_image))
    assert abs(ratio_image - 1.0) > 0.008


def faint_frames_under_a_highlight(px_per_frame: float, copied_share: float, n: int = 40, light: float = 0.0):
    """A faint wall (3 % contrast) moving px_per_frame down a 240 x 240 window under the LED's fixed
    highlight (clipped at its centre), with sensor noise; copied_share of its 4 x 4 blocks the encoder
    copied from the last frame, noise and all (a wet wall at CRF 38). `light`: the LED's light on
    the wall swings by this share over n frames (the car's pose changes its reach), and with it the
    clipped disc."""
    rng = np.random.default_rng(1)
    tex = cv2.GaussianBlur(rng.random((6000, 640)).astype(np.float32) * 255, (0, 0), 6.0)
    faint = 120 + 0.03 * (tex - tex.mean()) / tex.std() * 255 / 4
    yy, xx = np.mgrid[0:240, 0:240]
    lobe = 200 * np.exp(-((yy - 120) ** 2 + (xx - 120) ** 2) / (2 * 40 ** 2))
    prev = None
    for i in range(n):
        m = np.float32([[1, 0, -200], [0, 1, px_per_frame * i - 3000]])
        gain = 1.0 + light * math.sin(2 * math.pi * i / n)
        img = (cv2.warpAffine(faint, m, (240, 240), flags=cv2.INTER_LINEAR) + lobe) * gain
        img = np.clip(img + rng.normal(0, 0.8, img.shape), 0, 255).astype(np.uint8)
        if prev is not None:
            copied = np.kron(rng.random((60, 60)) < copied_share, np.ones((4, 4), bool))
            img[copied] = prev[copied]
        prev = img
        yield img


def test_next_to_no_motion_with_no_brake_before_it_is_no_dense_measurement():
    """What stays put in the image (the highlight, blocks the encoder copied) is all a dense shift
    can correlate once it reads next to no motion: a wall that stands is all running mean, and a
    camera's frames of it flat-field to noise. At 30 px a frame with 60 % of the blocks copied the
    shift read a stand (a lobe run on a wet brick wall: -51.5 %); a wall at 3 px a frame is still read."""
    for px, share, read in ((30.0, 0.6, False), (30.0, 0.0, True), (3.0, 0.35, True)):
        dense = DenseShift((240, 240))
        found = [dense.shift(f, i / 30) for i, f in enumerate(faint_frames_under_a_highlight(px, share))]
        shifts = [s[0][1] for s in found if s is not None]
        if read:
            assert len(shifts) > 20 and np.median(shifts[1:]) == pytest.approx(px, rel=0.25)
        else:
            assert not shifts


def test_a_clipped_highlight_that_breathes_with_the_light_does_not_pull_the_shift_to_a_stand():
    """Where the highlight clips, a flat-fielded frame is flat, and where it clipped a moment ago the
    running mean is no wall's: both stand out of the wall around them and stay put while the wall
    moves under them. With the light swinging by 10 % a wall at 8 px a frame was read at 1.2-7.0 px,
    and one at 30 px a frame on 11 frames of 30. Masked out, in both frames and wherever the running
    mean saw a clip (the refinement's weights moved with the shift), they leave the wall around them
    to be read: 7.7-8.0 and 29.2-30.0 px."""
    for px in (8.0, 30.0):
        dense = DenseShift((240, 240))
        found = [dense.shift(f, i / 30) for i, f in enumerate(faint_frames_under_a_highlight(px, 0.0, light=0.1))]
        per_frame = [dv / round(i - since * 30) for i, s in enumerate(found) if s is not None
                     for (_, dv), _, since in [s]]
        assert len(per_frame) > 20
        assert 0.85 * px < min(per_frame) and max(per_frame) < 1.1 * px


def lines_along_the_motion(seed: int, n: int = 60):
    """A wall of faint lines along the motion only (a brick wall's mortar lines along the pipe), moving
    30 px a frame down a 240 x 240 window, under a highlight (not clipped) whose light breathes by 20 %."""
    rng = np.random.default_rng(seed)
    cols = cv2.GaussianBlur(rng.random((1, 640)).astype(np.float32), (0, 0), 3.0)
    wall = np.repeat(120 + 0.03 * 255 / 4 * (cols - cols.mean()) / cols.std(), 6000, axis=0)
    yy, xx = np.mgrid[0:240, 0:240]
    lobe = 100 * np.exp(-((yy - 120) ** 2 + (xx - 120) ** 2) / (2 * 40 ** 2))
    for i in range(n):
        m = np.float32([[1, 0, -200], [0, 1, 30.0 * i - 3000]])
        img = cv2.warpAffine(wall, m, (240, 240), flags=cv2.INTER_LINEAR) + lobe * (1 + 0.2 * math.sin(i / 5))
        yield np.clip(img + rng.normal(0, 0.8, img.shape), 0, 255).astype(np.uint8)


def test_a_slow_start_that_does_not_add_up_across_its_frames_is_not_believed():
    """Lines along the motion say nothing of it, and what stays put reads next to no shift frame by
    frame, a pixel or two each way: three in a row, just over stop_px, were a crawler setting off (a
    lobe run on a wet brick wall: -36 %). Across the three frames at once it reads no sum of them.
    On four walls of eight (seeds 1-8) the shift believed 13 such starts without the check (8 since
    shifts that swing each way are no motion either)."""
    believed = {}
    for slow in (0.0, DenseParams().slow_px):
        shifts = []
        for seed in (2, 3, 6, 7):
            dense = DenseShift((240, 240), DenseParams(slow_px=slow))
            shifts += [s for i, f in enumerate(lines_along_the_motion(seed)) if (s := dense.shift(f, i / 30))]
        believed[slow] = len(shifts)
    assert believed[0.0] >= 5 and believed[DenseParams().slow_px] <= 1


@pytest.mark.parametrize("every", [3, 2])
def test_frames_that_never_came_do_not_stop_the_dense_shift(every):
    """A camera drops the frames the loop comes too late for, and a recording has gaps. Counted per
    frame received, one drop in three left a faint wall unmeasured: each shift across a drop broke
    the steadiness of its neighbours. Judged a frame period at a time, the wall is read across them."""
    dense = DenseShift((240, 240))
    covered, moved = 0, 0.0
    for i, f in enumerate(faint_frames_under_a_highlight(8.0, 0.0, n=80)):
        if i % every == every - 1:
            continue
        found = dense.shift(f, i / 30)
        if found is not None:
            (_, dv), _, since = found
            moved, covered = moved + dv, covered + round((i / 30 - since) * 30)
    assert covered > 60 and moved / covered == pytest.approx(8.0, rel=0.03)


def test_one_odd_timestamp_is_no_frame_period():
    # the period is the second shortest of the last nine intervals: one frame stamped a microsecond
    # after the one before does not make every later shift span thousands of periods
    dense = DenseShift((240, 240))
    covered = 0
    for i, f in enumerate(faint_frames_under_a_highlight(8.0, 0.0, n=80)):
        t = 29 / 30 + 1e-6 if i == 30 else i / 30
        found = dense.shift(f, t)
        if found is not None and i > 31:
            covered += round((t - found[2]) * 30)
    assert covered > 40


def test_shifts_that_swing_each_way_are_no_motion():
    """A faint wall's noise read +4.9, +0.7 and -2.0 px on three frames in a row, a 'steady brake'
    within a pixel; believed as a crawl, it settled 2 s of a drive at 30 px a frame as a stand (a
    lobe run on a wet brick wall: -26 %). Their net is under stop_px a frame: no motion, like a
    stand's. A slow start that goes on for slow_confirm_s (six frames) still adds up."""
    rng = np.random.default_rng(4)
    wall = cv2.GaussianBlur(rng.uniform(0, 255, (900, 300)).astype(np.float32), (0, 0), 2.0)

    def believed(steps):
        dense, y, out = DenseShift((240, 240), DenseParams()), 100.0, []
        for i, dy in enumerate([30.0] * (DenseParams().warmup + 1) + steps):   # (the running mean warms up)
            y += dy
            m = np.float32([[1, 0, -30], [0, 1, -y]])
            f = cv2.warpAffine(wall, m, (240, 240), flags=cv2.INTER_LINEAR)
            out.append(dense.shift(np.clip(f, 0, 255).astype(np.uint8), i / 30))
        return [s for s in out if s is not None]

    assert not believed([5.0, 1.0, -2.0])
    assert believed([3.0, 3.5, 4.0, 4.5, 5.0, 5.5])


def test_a_slow_shift_that_swings_back_within_a_pitch_period_is_no_motion():
    """What the dense shift read on an independent stress run's wet wall at CRF 18, where the crawler
    drove at 53 px a frame and the LED's mirror point swung with the car's pitch (0.3 degrees at
    3 Hz, ~5 px in the image): 3.4, 3.1, 3.6 px a frame, steady and adding up, believed as a crawl
    (the gap after it carried at 0.02 m/s: -9.1 %), then 4.9, 5.9 and back through none. A slow first
    motion must go on steadily for slow_confirm_s (0.2 s: six frames at 30 fps); this one does not.
    With three frames enough (slow_confirm_s 0), it was believed."""
    rng = np.random.default_rng(4)
    wall = cv2.GaussianBlur(rng.uniform(0, 255, (900, 300)).astype(np.float32), (0, 0), 2.0)
    swing = [3.4, 3.1, 3.6, 4.9, 5.9, 0.7, -2.1, -1.1, 2.4, 1.7, -2.0, -1.8]

    def believed(params):
        dense, y, out = DenseShift((240, 240), params), 100.0, []
        for i, dy in enumerate([30.0] * (params.warmup + 1) + swing):
            y += dy
            m = np.float32([[1, 0, -30], [0, 1, -y]])
            f = cv2.warpAffine(wall, m, (240, 240), flags=cv2.INTER_LINEAR)
            out.append(dense.shift(np.clip(f, 0, 255).astype(np.uint8), i / 30))
        return [s for s in out[params.warmup + 1:] if s is not None]

    assert not believed(DenseParams())
    assert believed(DenseParams(slow_confirm_s=0.0))


def test_a_slow_start_that_speeds_up_is_summed_from_its_first_frame():
    """A wall read at 2, 3, 4, 5 px a frame and faster: while slow the shift waits for 0.2 s of
    them, and once fast three suffice; the frames pending from the slow part are summed too (dropped
    when the need fell to three, 65 of 75.5 px were believed: a review; now 74, as before the wait)."""
    rng = np.random.default_rng(4)
    wall = cv2.GaussianBlur(rng.uniform(0, 255, (2000, 300)).astype(np.float32), (0, 0), 2.0)
    steps = [2.0, 3.0, 4.0, 5.0, 6.5, 8.0, 9.5, 11.0, 12.5, 14.0]
    params = DenseParams()
    dense, y, moved = DenseShift((240, 240), params), 100.0, 0.0
    first = params.warmup + 1                       # (read at 30 px a frame while the mean warms up)
    for i, dy in enumerate([30.0] * first + steps):
        y += dy
        m = np.float32([[1, 0, -30], [0, 1, -y]])
        f = cv2.warpAffine(wall, m, (240, 240), flags=cv2.INTER_LINEAR)
        found = dense.shift(np.clip(f, 0, 255).astype(np.uint8), i / 30)
        moved += found[0][1] if found is not None and i >= first else 0.0
    assert abs(moved) == pytest.approx(sum(steps), rel=0.03)
