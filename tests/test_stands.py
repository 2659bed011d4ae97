"""A stand the frames show on a wall too faint to measure (crawler/stands.py), on synthetic frames
of a faint wall under a fixed highlight with a camera's noise, at the dense shift's quarter size."""

import cv2
import numpy as np

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


def watch(frames, follows=None):
    w = StandWatch()
    seen = []
    for k, f in enumerate(frames):
        seen.append(w.update(k / FPS, f, True if follows is None else follows[k]))
    return seen


def test_a_crawler_that_stops_on_a_faint_wall_is_seen_to_stand_from_its_stop_to_its_start():
    pos, stop, start = brake_stand_go()
    seen = watch(frames_of(pos))
    stood = [k for k, s in enumerate(seen) if s is not None]
    assert stood, "no stand seen"
    since, until = seen[stood[-1] - 1]
    # the stand is known within the brake and the start (4 frames each; the slowest of their frames
    # change the picture as little as the noise does), and nowhere while the wall moved
    assert stop - 4 <= since * FPS <= stop
    assert start <= until * FPS <= start + 4
    assert min(stood) > stop - 4 and max(stood) <= start + 4
    # (the frames say so from the third still frame on: none of them is needed to start it)
    assert min(stood) <= stop + 4


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


def test_a_keyframe_coded_anew_inside_a_stand_does_not_end_it():
    pos, stop, start = brake_stand_go(stand=40)
    frames = frames_of(pos)
    k = stop + 20
    recoded = np.random.default_rng(5).normal(0, 3, frames[k].shape)   # a keyframe: coded differently once
    frames[k] = np.clip(frames[k] + recoded, 0, 255).astype(np.uint8)
    seen = watch(frames)
    assert all(seen[i] is not None for i in range(stop + 5, start))
    assert seen[stop + 5] == (seen[start - 1][0], seen[stop + 5][1])   # one stand throughout


def test_what_changed_across_frames_the_watch_did_not_see_is_not_the_motion():
    # a keyframe inside the stand codes the still wall sharper (a different picture, copied from then
    # on); its first frames had texture enough to try features on, so the watch did not see them
    pos, stop, start = brake_stand_go(stand=50)
    frames = frames_of(pos)
    k0 = stop + 15
    sharper = np.random.default_rng(6).normal(0, 1.5, frames[0].shape)    # the grain's texture within 25 %
    for k in range(k0, start):
        frames[k] = np.clip(frames[k] + sharper, 0, 255).astype(np.uint8)
    w, seen = StandWatch(), []
    for k, f in enumerate(frames):
        if k0 <= k < k0 + 10:
            seen.append(w.stand)                # tried for features: not fed, the stand goes on
            continue
        seen.append(w.update(k / FPS, f, follows=k != k0 + 10))
    assert all(seen[i] is not None and seen[i][0] == seen[stop + 5][0] for i in range(stop + 5, start))


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
        w.update(k / FPS, frames[k], follows=k > stop + 10)
    assert w.stand is not None
    w.reset()
    for k in range(stop + 17, stop + 28):
        w.update(k / FPS, frames[k])
    assert w.stand is None                          # nothing to measure still frames against
