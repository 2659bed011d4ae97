"""A stand the frames show on a wall too faint to measure (crawler/stands.py), on synthetic frames
of a faint wall under a fixed highlight with a camera's noise, at the dense shift's quarter size."""

import cv2
import numpy as np
import pytest

from crawler.stands import StandWatch

FPS = 30.0
SIZE = 60


def faint_wall(rows: int, amplitude: float, seed: int = 0) -> np.ndarray:
    """A strip of smooth texture (grain a few pixels wide) with this standard deviation."""
    rng = np.random.default_rng(seed)
    grain = cv2.GaussianBlur(rng.normal(0, 1, (rows, SIZE)).astype(np.float32), (0, 0), 1.5)
    return grain * (amplitude / grain.std())


def frames_of(positions, amplitude=2.0, noise=0.4, seed=1, gain=1.0, highlight_dn=60.0):
    """Quarter-size frames of the wall at these row positions (sub-pixel: interpolated), with a
    fixed highlight and fresh noise in each, lit at `gain` (each frame's or all's), as 8-bit
    pictures."""
    wall = faint_wall(int(max(positions)) + SIZE + 4, 1.0, seed)
    yy, xx = np.mgrid[0:SIZE, 0:SIZE].astype(np.float32)
    highlight = highlight_dn * np.exp(-((xx - 30) ** 2 + (yy - 20) ** 2) / (2 * 9.0 ** 2))
    rng = np.random.default_rng(seed + 1)
    amps = np.broadcast_to(np.asarray(amplitude, np.float64), (len(positions),))
    gains = np.broadcast_to(np.asarray(gain, np.float64), (len(positions),))
    out = []
    for y, a, g in zip(positions, amps, gains):
        win = cv2.remap(wall, xx, yy + np.float32(y), cv2.INTER_LINEAR)
        img = g * (110.0 + highlight + a * win) + rng.normal(0, noise, win.shape)
        out.append(np.clip(np.rint(img), 0, 255).astype(np.uint8))
    return out


def brake_stand_go(cruise_px=1.0, cruise=40, ramp=4, stand=30, after=30):
    """Row positions of a wall that moves at cruise_px a frame, brakes over `ramp` frames to a stand,
    stands `stand` frames and sets off again; and the frame indices of the stop and the start."""
    speeds = ([cruise_px] * cruise + list(np.linspace(cruise_px, 0, ramp + 1)[1:]) + [0.0] * stand
              + list(np.linspace(0, cruise_px, ramp + 1)[1:]) + [cruise_px] * after)
    stop, start = cruise + ramp, cruise + ramp + stand
    return np.concatenate([[0.0], np.cumsum(speeds)]), stop, start


def watch(frames):
    w = StandWatch()
    return [w.update(k / FPS, f) for k, f in enumerate(frames)]


@pytest.mark.parametrize("ramp", [4, 12, 20])
def test_a_crawler_that_stops_on_a_faint_wall_is_seen_to_stand_from_its_stop_to_its_start(ramp):
    # (a long brake's slow frames, taken into the yardstick at once, pulled it down until the
    # stand's noise passed for a drive: no stand at 12 frames and more)
    pos, stop, start = brake_stand_go(ramp=ramp)
    seen = watch(frames_of(pos))
    stood = [k for k, s in enumerate(seen) if s is not None]
    assert stood, "no stand seen"
    since, until = seen[stood[-1] - 1]
    # the stand is known within a quarter of the brake and of the start: the slowest of their frames
    # change the picture as little as a stand does, and it is said from half the comparison's span
    # inside them (it stood from frame stop - 1, it moved from frame start); nowhere while it moved.
    # Said where the frames first and last looked still, it began 1.5-3.5 frames early and ended
    # as late, and the bridge, which adds the brake and the start itself, lost 7 mm a stand at 0.1 m/s
    assert stop - 1 - ramp / 4 <= since * FPS <= stop
    assert start - 1 <= until * FPS <= start + ramp / 4
    assert min(stood) > stop - ramp and max(stood) <= start + ramp + 4
    assert min(stood) <= stop + 4               # said from the third still frame on


def test_a_crawler_that_slows_down_in_steps_is_no_stand():
    # to 0.4 of its speed, then to 0.12: the second crawl changes the frames less than 0.3 of what
    # the drive did, but the yardstick has followed the first (its slow frames, going on, became it)
    speeds = ([1.0] * 40 + list(np.linspace(1.0, 0.4, 7)[1:]) + [0.4] * 40 + list(np.linspace(0.4, 0.12, 7)[1:])
              + [0.12] * 60)
    seen = watch(frames_of(np.concatenate([[0.0], np.cumsum(speeds)])))
    assert all(s is None for s in seen)


@pytest.mark.parametrize("crawl", [0.5, 0.3])
def test_a_crawler_that_slows_down_and_crawls_on_is_no_stand(crawl):
    # slowing to a third of its speed over six frames and crawling on: its slow frames become the
    # yardstick once they go on (a fifth of the speed changes the picture as little as a stand:
    # docs/odometry.md)
    speeds = [1.0] * 40 + list(np.linspace(1.0, crawl, 7)[1:]) + [crawl] * 80
    seen = watch(frames_of(np.concatenate([[0.0], np.cumsum(speeds)])))
    assert all(s is None for s in seen)


def test_a_wall_fading_into_a_wet_patch_while_the_crawler_drives_on_is_no_stand():
    # the texture falls eightfold over ten frames: the frames change less and less, the wall moves on
    n = 120
    amp = np.concatenate([np.full(40, 8.0), np.geomspace(8.0, 1.0, 10), np.full(n - 50, 1.0)])
    seen = watch(frames_of(np.arange(n + 1) * 1.0, amplitude=np.append(amp, 1.0)))
    assert all(s is None for s in seen)


def test_a_wall_that_turns_smooth_at_once_while_the_crawler_drives_on_is_no_stand():
    # a sharp edge of a wet patch: the frames change an eighth as much, the wall moves on; its
    # texture fell with it, so what the drive changed the frames by before is no yardstick
    n = 100
    seen = watch(frames_of(np.arange(n) * 1.0, amplitude=np.where(np.arange(n) < 40, 6.0, 0.75)))
    assert all(s is None for s in seen)


def test_a_light_that_changes_while_the_encoder_copies_a_moving_wall_is_not_the_motion():
    # the encoder copies a faint wall the crawler drives over (every frame the same picture) while
    # the LED brightens slowly, then steadily: the frames changed with the light, not with a motion
    n = 80
    gain = np.minimum(1.0 + 0.005 * np.arange(n), 1.2)
    seen = watch(frames_of(np.zeros(n), amplitude=2.0, noise=0.0, gain=gain))
    assert all(s is None for s in seen)


def test_a_light_coming_back_over_a_clipped_highlight_is_not_the_motion():
    # an LED coming back after a blackout, 8 % a frame, the highlight clipped: the picture does not
    # scale where it clips, so taking the light's level out leaves a change a steady one
    n = 60
    gain = np.minimum(0.5 + 0.04 * np.arange(n), 1.3)
    seen = watch(frames_of(np.zeros(n), amplitude=2.0, noise=0.0, gain=gain, highlight_dn=160.0))
    assert all(s is None for s in seen)


def test_a_wall_whose_motion_never_shows_above_the_noise_shows_no_stand():
    pos, stop, start = brake_stand_go()
    seen = watch(frames_of(pos, amplitude=0.05, noise=0.6))
    assert all(s is None for s in seen)


@pytest.mark.parametrize("recoded_dn", [1.0, 2.0, 5.0])
def test_a_keyframe_that_codes_the_still_picture_anew_does_not_end_the_stand(recoded_dn):
    # from a keyframe on, the still wall is another picture (coded anew, then copied): against the
    # frame three before, three frames in a row changed; and its texture may change with it (at 5 DN
    # by 74 %: no yardstick of that texture, the stand's own holds)
    pos, stop, start = brake_stand_go(stand=50)
    frames = frames_of(pos)
    recoded = np.random.default_rng(5).normal(0, recoded_dn, frames[0].shape)
    for k in range(stop + 20, len(frames)):
        frames[k] = np.clip(frames[k] + recoded, 0, 255).astype(np.uint8)
    seen = watch(frames)
    assert all(seen[i] is not None and seen[i][0] == seen[stop + 5][0] for i in range(stop + 5, start))


def test_a_blackout_inside_a_stand_neither_ends_it_nor_times_its_end():
    pos, stop, start = brake_stand_go(stand=50)
    frames = frames_of(pos)
    dark = range(start - 10, start + 10)            # an LED blackout; the crawler sets off inside it
    w, seen = StandWatch(), []
    for k, f in enumerate(frames):
        if k in dark:
            w.unseen()                              # nothing compared across it
            seen.append(w.stand)
            continue
        seen.append(w.update(k / FPS, f))
    assert all(seen[i] is not None and seen[i][0] == seen[stop + 5][0] for i in range(stop + 5, start - 10))
    shown = [x for x in seen if x is not None][-1]
    assert shown[1] * FPS <= start - 10             # it ended after its last still frame, unseen
    assert seen[-1] is None                         # ...and the frames after show it drove


def test_a_stand_that_ends_because_the_frames_move_again_says_when_the_crawler_set_off_once():
    pos, stop, start = brake_stand_go()
    w = StandWatch()
    for k, f in enumerate(frames_of(pos)):
        w.update(k / FPS, f)
        if k == start - 2:
            assert w.take_set_off() is None                 # standing: no set-off yet
    t = w.take_set_off()
    assert t is not None and abs(t * FPS - start) <= 1.5     # where it set off, within a frame or two
    assert w.take_set_off() is None                         # taken once


def test_a_measured_frame_ends_a_stand_but_keeps_the_yardstick():
    pos, stop, start = brake_stand_go()
    frames = frames_of(pos)
    w = StandWatch()
    for k, f in enumerate(frames[:stop + 10]):
        w.update(k / FPS, f)
    assert w.stand is not None
    w.measured()
    assert w.stand is None
    # still frames after it: a stand again at once, measured against the drive before it
    for k in range(stop + 10, stop + 17):
        w.update(k / FPS, frames[k])
    assert w.stand is not None
    w.reset()
    for k in range(stop + 17, stop + 28):
        w.update(k / FPS, frames[k])
    assert w.stand is None                          # nothing to measure still frames against


def test_an_i_frame_inside_a_stand_neither_ends_it_nor_do_the_p_frames_settling_after_it():
    """A recording's I-frame codes the still picture anew, and the P-frames after it settle over a
    few frames: compared 3 apart, seven frames in a row changed (a stand of 1.5 s on wet brick at
    CRF 38 ended at x264's I-frame, +18.5 % of the path). Nothing is compared across the I-frame
    (`recoded`), and a change no drive's size (below `slow` of the yardstick) ends a stand only at
    twice `moves` in a row; the set-off after it is still seen."""
    pos, stop, start = brake_stand_go(stand=60)
    frames, k0 = frames_of(pos), stop + 20
    rng = np.random.default_rng(7)
    anew, settle = rng.normal(0, 2.0, frames[0].shape), rng.normal(0, 3.0, frames[0].shape)
    for k in range(k0, len(frames)):
        frames[k] = np.clip(frames[k] + anew + min(k - k0, 5) / 5 * settle, 0, 255).astype(np.uint8)

    def seen_with(told):
        w, seen = StandWatch(), []
        for k, f in enumerate(frames):
            if told and k == k0:
                w.recoded()
            seen.append(w.update(k / FPS, f))
        return seen

    seen = seen_with(True)
    assert all(seen[i] is not None and seen[i][0] == seen[stop + 5][0] for i in range(stop + 5, start))
    assert seen[-1] is None and abs(seen[start][1] * FPS - start) <= 1.5     # it set off, then
    assert seen_with(False)[k0 + 8] is None         # not told: the I-frame and its P-frames end it
