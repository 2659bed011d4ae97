"""hw_sim's fake Picamera2: picamera2's API shape, real-time pacing, stalls, and a geometry round
trip through crawlerd's own window plan, camera source and odometer."""
import time

import numpy as np
import pytest

from hw_sim import SimConfig, Simulator
from hw_sim.picamera2_fake import SENSORS, ManualClock, SimWorld, Transform, make_picamera2

# Real sensor mode tables (picamera2 prints on Raspberry Pi OS Bookworm, VC4): size, fps, crop_limits
MODES = {
    "ov5647": [((640, 480), 58.92, (16, 0, 2560, 1920)), ((1296, 972), 43.25, (0, 0, 2592, 1944)),
               ((1920, 1080), 30.62, (348, 434, 1928, 1080)), ((2592, 1944), 15.63, (0, 0, 2592, 1944))],
    "imx219": [((640, 480), 103.33, (1000, 752, 1280, 960)), ((1640, 1232), 41.85, (0, 0, 3280, 2464)),
               ((1920, 1080), 47.57, (680, 692, 1920, 1080)), ((3280, 2464), 21.19, (0, 0, 3280, 2464))],
    "imx708": [((1536, 864), 120.13, (768, 432, 3072, 1728)), ((2304, 1296), 56.03, (0, 0, 4608, 2592)),
               ((4608, 2592), 14.35, (0, 0, 4608, 2592))],
}


def _camera(sensor="imx219", clock=None, **fields):
    kw = {"clock": clock.ns, "sleep": clock.sleep} if clock else {}
    world = SimWorld(sensor, **kw, **fields)
    return world, make_picamera2(world)


def _video(cam, size=(320, 240), fps=100.0, **controls):
    d = int(round(1e6 / fps))
    cfg = cam.create_video_configuration(main={"size": size, "format": "YUV420"}, raw=None,
                                         sensor={"output_size": (640, 480), "bit_depth": 10},
                                         controls={"FrameDurationLimits": (d, d), **controls}, buffer_count=4)
    cam.configure(cfg)
    return cfg


# --- API shape ------------------------------------------------------------------------------------

def test_global_camera_info_and_open():
    world, Picamera2 = _camera()
    info = Picamera2.global_camera_info()
    assert info == [{"Model": "imx219", "Location": 2, "Rotation": 180,
                     "Id": "/base/soc/i2c0mux/i2c@1/imx219@10", "Num": 0}]
    with pytest.raises(IndexError):
        Picamera2(1)
    cam = Picamera2(0)
    with pytest.raises(RuntimeError, match="did not complete"):     # busy, as with a second process
        Picamera2(0)
    props = cam.camera_properties
    assert props["PixelArraySize"] == (3296, 2480)
    assert props["PixelArrayActiveAreas"] == [(8, 8, 3280, 2464)]
    assert props["ScalerCropMaximum"] == (0, 0, 0, 0)
    cam.close()
    cam.close()                                                     # idempotent
    assert cam.camera_properties == {}
    world.connected = False
    assert Picamera2.global_camera_info() == []


@pytest.mark.parametrize("sensor", sorted(MODES))
def test_sensor_modes_match_the_real_tables(sensor):
    _, Picamera2 = _camera(sensor)
    cam = Picamera2(0)
    modes = cam.sensor_modes
    spec = SENSORS[sensor]
    assert len(modes) == len(spec.formats) * len(MODES[sensor])
    for i, m in enumerate(modes):
        size, fps, crop = MODES[sensor][i % len(MODES[sensor])]
        assert (m["size"], m["fps"], m["crop_limits"]) == (size, fps, crop)
        assert str(m["format"]) == spec.formats[i // len(MODES[sensor])]
        assert m["bit_depth"] == m["format"].bit_depth and m["unpacked"] == m["format"].unpacked
        assert m["exposure_limits"][0] < m["exposure_limits"][1]
    assert str(modes[0]["format"]) in ("SGBRG10_CSI2P", "SRGGB10_CSI2P")
    # like picamera2, reading the modes left the camera configured in the last mode
    assert cam.camera_configuration()["sensor"]["output_size"] == MODES[sensor][-1][0]
    cam.close()


def test_create_video_configuration_defaults():
    _, Picamera2 = _camera()
    cam = Picamera2(0)
    cfg = cam.create_video_configuration()
    assert set(cfg) == {"use_case", "transform", "colour_space", "buffer_count", "queue", "main", "lores",
                        "raw", "controls", "sensor", "display", "encode"}
    assert cfg["controls"]["FrameDurationLimits"] == (33333, 33333)
    assert cfg["main"] == {"format": "XBGR8888", "size": (1280, 720), "preserve_ar": True}
    assert cfg["raw"] == {"format": "SRGGB10_CSI2P", "size": (1280, 720)} and cfg["buffer_count"] == 6
    with pytest.raises(ValueError, match="Bad key"):
        cam.create_video_configuration(main={"sise": (640, 480)})
    with pytest.raises(RuntimeError, match="Display stream lores was not defined"):
        cam.create_video_configuration(display="lores")
    cam.close()


def test_configure_fills_stride_and_picks_the_mode():
    _, Picamera2 = _camera()
    cam = Picamera2(0)
    cfg = cam.create_video_configuration(main={"size": (100, 80), "format": "YUV420"}, raw=None)
    cam.configure(cfg)
    cc = cam.camera_configuration()
    assert cc["main"]["stride"] == 128 and cc["main"]["framesize"] == 128 * 80 * 3 // 2
    assert cc["sensor"] == {"bit_depth": 10, "output_size": (640, 480)}
    # picamera2's score: a 1280x720 request gets the cropped 1080p mode, 800x600 the binned full FoV
    cam.configure(cam.create_video_configuration(main={"size": (1280, 720), "format": "YUV420"}))
    assert cam.camera_configuration()["sensor"]["output_size"] == (1920, 1080)
    assert cam.camera_configuration()["raw"]["size"] == (1920, 1080)
    cam.configure(cam.create_video_configuration(main={"size": (800, 600)}))
    assert cam.camera_configuration()["sensor"]["output_size"] == (1640, 1232)
    assert cam.camera_properties["ScalerCropMaximum"] == (0, 0, 3280, 2464)
    with pytest.raises(RuntimeError, match="Unexpected keys"):
        cam.configure(cam.create_video_configuration(sensor={"fps": 30}))
    cfg = cam.create_video_configuration(main={"size": [640, 480]})   # align_stream makes it a tuple
    cfg["main"]["size"] = [640, 480]
    with pytest.raises(RuntimeError, match="should be \\(width, height\\)"):
        cam.configure(cfg)
    with pytest.raises(NotImplementedError):
        cam.configure(cam.create_video_configuration(transform=Transform(hflip=1, vflip=1)))
    cam.close()


def test_errors_while_started_and_bad_controls():
    _, Picamera2 = _camera(clock=ManualClock())
    cam = Picamera2(0)
    _video(cam)
    with pytest.raises(RuntimeError, match="not advertised"):
        cam.set_controls({"Exposure": 1000})
    with pytest.raises(RuntimeError, match="not advertised"):
        cam.configure(cam.create_video_configuration(controls={"Bogus": 1}))
    _video(cam)
    cam.set_controls({"ExposureTime": 3000, "AnalogueGain": 2.0, "AeEnable": False, "FrameRate": 50})
    cam.start()
    cam.start()                                             # already started: nothing happens
    with pytest.raises(RuntimeError, match="must be stopped"):
        _video(cam)
    cam.sensor_modes_ = []
    with pytest.raises(RuntimeError, match="must be stopped"):
        cam.sensor_modes
    req = cam.capture_request(wait=1.0)
    md = req.get_metadata()
    assert md["ExposureTime"] == 3000 and md["AnalogueGain"] == 2.0 and abs(md["FrameDuration"] - 20000) < 20
    req.release()
    with pytest.raises(RuntimeError, match="negative ref_count"):
        req.release()
    with pytest.raises(RuntimeError, match="'main' is not defined"):
        req.make_array("main")                              # released: the buffer went back
    with cam.captured_request(wait=1.0) as r:
        with pytest.raises(RuntimeError, match="'lores' is not defined"):
            r.make_array("lores")
    cam.stop()
    cam.stop()                                              # no-op when stopped
    cam.close()


# --- frames ---------------------------------------------------------------------------------------

def test_yuv420_array_and_timestamps_at_the_frame_duration():
    clock = ManualClock()
    _, Picamera2 = _camera(clock=clock, tilt_deg=10)
    cam = Picamera2(0)
    _video(cam, size=(100, 80), fps=100)
    cam.start()
    ts = []
    for _ in range(5):
        with cam.captured_request(wait=1.0) as r:
            a = r.make_array("main")
            md = r.get_metadata()
        ts.append(md["SensorTimestamp"])
    assert a.shape == (120, 128) and a.dtype == np.uint8
    assert np.all(a[80:] == 128) and np.all(a[:80, 100:] == 0) and a[:80, :100].std() > 5
    period = md["FrameDuration"] * 1000
    assert np.all(np.abs(np.diff(ts) - period) <= 1000) and abs(period - 10_000_000) < 10_000
    clock.sleep(0.0555)                                     # fall behind: the newest frame comes next
    with cam.captured_request(wait=1.0) as r:
        gap = r.get_metadata()["SensorTimestamp"] - ts[-1]
    assert round(gap / period) == 5
    cam.close()


def test_pacing_is_real_time():
    world, Picamera2 = _camera()
    cam = Picamera2(0)
    _video(cam, fps=100)
    cam.start()
    cam.capture_request(wait=1.0).release()
    t0 = time.perf_counter()
    ts, ages = [], []
    for _ in range(10):
        r = cam.capture_request(wait=1.0)
        ts.append(r.get_metadata()["SensorTimestamp"])
        ages.append(time.monotonic_ns() - ts[-1])
        r.release()
    dt = time.perf_counter() - t0
    assert 0.08 <= dt <= 0.2, dt
    assert np.all(np.abs(np.diff(ts) - 10_000_000) < 10_000)         # consecutive frames, none skipped
    # monotonic ns: a frame is returned one readout (480 lines of 18.9 us) after its timestamp, never
    # sooner, and the quickest return shows it (a busy machine only adds to an age: one measured after
    # the loop once read 26.5 ms under load)
    assert min(ages) >= 9_000_000 and min(ages) < 20_000_000, ages
    assert abs(world.clock() - time.monotonic_ns()) < 1_000_000         # world time is wall time
    assert world.frames_delivered == 11
    cam.close()


def test_stall_times_out_and_resume_brings_frames_back():
    clock = ManualClock()
    world, Picamera2 = _camera(clock=clock)
    cam = Picamera2(0)
    _video(cam)
    cam.start()
    cam.capture_request(wait=1.0).release()
    world.stall()
    t0 = clock.ns()
    with pytest.raises(TimeoutError):
        cam.capture_request(wait=0.2)
    assert 0.2 <= (clock.ns() - t0) / 1e9 < 0.22
    with pytest.raises(TimeoutError):
        cam.capture_request(wait=0.2)
    world.resume()
    held = [cam.capture_request(wait=1.0) for _ in range(2)]
    assert held[0].get_metadata()["SensorTimestamp"] > clock.ns() - 40_000_000    # fresh frames
    # as in picamera2, each timed-out capture stayed queued, took a frame and holds its buffer for
    # good: 2 of the 4 buffers are gone, so holding 2 more starves the camera
    with pytest.raises(TimeoutError):
        cam.capture_request(wait=0.1)
    cam.cancel_all_and_flush()              # picamera2's advice after a timeout, before retrying
    cam.stop()                              # a restart gets every buffer back
    cam.start()
    assert len([cam.capture_request(wait=1.0) for _ in range(4)]) == 4
    cam.close()


def test_unreleased_requests_starve_the_camera():
    _, Picamera2 = _camera(clock=ManualClock())
    cam = Picamera2(0)
    _video(cam)                                 # buffer_count 4
    cam.start()
    held = [cam.capture_request(wait=1.0) for _ in range(4)]
    with pytest.raises(TimeoutError):
        cam.capture_request(wait=0.1)
    cam.cancel_all_and_flush()
    held.pop().release()
    cam.capture_request(wait=0.1).release()
    cam.close()


def test_scaler_crop_is_clamped_quantised_and_rendered_exactly():
    clock = ManualClock()
    world, Picamera2 = _camera("ov5647", clock=clock, tilt_deg=15)
    cam = Picamera2(0)
    cfg = cam.create_video_configuration(main={"size": (200, 150), "format": "YUV420"}, raw=None,
                                         sensor={"output_size": (640, 480), "bit_depth": 10},
                                         controls={"FrameDurationLimits": (20000, 20000)})
    cam.configure(cfg)
    lo, hi, default = cam.camera_controls["ScalerCrop"]
    assert hi == (16, 0, 2560, 1920) and default == (16, 0, 2560, 1920)
    cam.start()
    with cam.captured_request(wait=1.0) as r:
        assert r.get_metadata()["ScalerCrop"] == default
    # the VGA mode bins 4:1: the ISP crop lands on whole mode pixels, inside the mode's crop
    cam.set_controls({"ScalerCrop": (18, 2, 1001, 751)})
    with cam.captured_request(wait=1.0) as r:
        md = r.get_metadata()
        y = r.make_array("main")[:150, :200]
    assert md["ScalerCrop"] == (16, 0, 1000, 748)
    cam.set_controls({"ScalerCrop": (2000, 1500, 1000, 750)})
    with cam.captured_request(wait=1.0) as r:
        assert r.get_metadata()["ScalerCrop"] == (1576, 1172, 1000, 748)
    # the pixels are hw_sim's view through exactly the reported crop at the frame's top-row time
    line_us = 1852 / 55.0                                   # the VGA mode's line; the crop starts at row 0
    t = world.t_s(md["SensorTimestamp"]) - md["ExposureTime"] / 2 / 1e6
    rows = 748 * 480 / 1920
    sim = Simulator(SimConfig(width=2592, height=1944, hfov_deg=53.50, vfov_deg=41.41, tilt_deg=15,
                              duration_s=3600.0, window=md["ScalerCrop"], output_size=(200, 150), fps=50,
                              exposure_ms=md["ExposureTime"] / 1000, readout_ms=(rows - 1) * line_us / 1000))
    assert np.array_equal(y, sim.render(t))
    cam.close()


# --- geometry round trip through crawlerd ---------------------------------------------------------

def test_crawler_measures_the_true_distance_through_the_fake():
    from crawler.camera import SENSOR_FOV_DEG, Picamera2Source, plan_window, vblank_lines
    from crawler.settings import CameraSettings
    from crawler.geometry import Mount, make_projection
    from crawler.odometry import Odometer

    tilt = 20.0
    world, Picamera2 = _camera("imx219", tilt_deg=tilt, speed_m_s=0.2)
    window, out = (1160, 1232, 960, 480), (320, 160)     # below the centre row, inside the VGA mode
    probe = Picamera2(0)
    modes = probe.sensor_modes
    probe.close()
    plan = plan_window(modes, (3280, 2464), window, out, 100.0, SENSOR_FOV_DEG["imx219"],
                       vblank_lines("imx219", (640, 480)))
    assert plan.mode["size"] == (640, 480) and plan.scaler_crop == window
    src = Picamera2Source(CameraSettings(sensor_window=window, output_size=out, fps=100.0, exposure_us=2000,
                                         analogue_gain=4.0), Picamera2)
    with src:
        assert src.plan.scaler_crop == plan.scaler_crop and src.plan.camera == plan.camera
        odo = Odometer(src.plan.camera, make_projection("cylinder", Mount.from_car(0.30, 0.151, 0.054, tilt)),
                       (0, 0) + out)
        first = None
        for frame in src.frames():
            est = odo.update(frame.gray, frame.t_s)
            first = first or src.last_sensor_ns
            if frame.index >= 59:           # a loaded machine may drop frame 59
                break
        with src.cam.captured_request(wait=1.0) as r:
            assert r.get_metadata()["ScalerCrop"] == plan.scaler_crop   # the fake rendered what was planned
    truth = world.true_distance_m(src.last_sensor_ns) - world.true_distance_m(first)
    assert est.tracking and truth > 0.1
    assert abs(odo.distance - truth) / truth < 0.01, (odo.distance, truth)


def test_crawler_source_reports_a_stalled_camera():
    from crawler.camera import CameraStalled, Picamera2Source
    from crawler.settings import CameraSettings

    clock = ManualClock()
    world, Picamera2 = _camera("ov5647", clock=clock, tilt_deg=10)
    src = Picamera2Source(CameraSettings(output_size=(160, 120), fps=30.0, capture_timeout_s=0.5), Picamera2)
    with src:
        frames = src.frames()
        first = next(frames)
        assert first.gray.shape == (120, 160) and world.busy
        world.stall()
        with pytest.raises(CameraStalled):
            next(frames)
    assert not world.busy                                   # the source closed the camera


def test_controls_while_running_and_other_streams():
    clock = ManualClock()
    _, Picamera2 = _camera(clock=clock)
    cam = Picamera2(0)
    cfg = cam.create_video_configuration(main={"size": (64, 48)}, lores={"size": (32, 24)},
                                         controls={"FrameRate": 50})
    cam.configure(cfg)
    assert cfg["main"]["stride"] == 64 * 4                   # the caller's dicts gain stride, as in picamera2
    cam.start()
    with cam.captured_request(wait=1.0) as r:
        assert r.make_array("main").shape == (48, 64, 4) and r.make_array("lores").shape == (36, 32)
        assert r.make_array("raw").shape[0] == cam.camera_configuration()["sensor"]["output_size"][1]
        t0 = r.get_metadata()["SensorTimestamp"]
    cam.set_controls({"FrameDurationLimits": (40000, 40000)})
    ts = [cam.capture_metadata(wait=1.0)["SensorTimestamp"] for _ in range(4)]
    assert abs(ts[-1] - ts[-2] - 40_000_000) < 20_000 and ts[0] > t0
    flushed = clock.ns()
    with cam.captured_request(wait=1.0, flush=True) as r:
        md = r.get_metadata()
        assert md["SensorTimestamp"] - 1000 * md["ExposureTime"] >= flushed
    cam.close()


def test_mapped_array_is_the_request_buffer_until_release():
    from hw_sim.picamera2_fake import MappedArray, SimWorld, make_picamera2

    cam = make_picamera2(SimWorld("imx219", speed_m_s=0.1))(0)
    try:
        cam.configure(cam.create_video_configuration(main={"size": (320, 240), "format": "YUV420"}, raw=None))
        cam.start()
        request = cam.capture_request(wait=2.0)
        with MappedArray(request, "main", write=False) as m:
            view = m.array
            assert view.shape == (360, 320) and not view.flags.writeable
            assert view[:240].std() > 5                       # a textured wall in the Y plane
            assert (request.make_array("main") == view).all()
        request.release()
        assert not view.any()                                 # the camera took the memory back
        with pytest.raises(RuntimeError):
            with MappedArray(request, "main"):
                pass
    finally:
        cam.close()


# --- a camera under load: frames come on the sensor's clock, a late consumer loses some ------------

def _slow_consumer(cam, world, frames, work_s, sleep):
    """Capture, make the array, 'work' for work_s holding the request, release: as crawlerd does."""
    out = []
    for _ in range(frames):
        with cam.captured_request(wait=1.0) as r:
            now = world.clock()
            out.append((r.get_metadata(), now, r.make_array("main")[:240, :320].copy()))
            assert cam.buffers_in_use <= 4
            sleep(work_s)
    return out


def test_a_slow_consumer_on_a_manual_clock_gets_every_2nd_or_3rd_frame():
    clock = ManualClock()
    world, Picamera2 = _camera(clock=clock, tilt_deg=10, speed_m_s=0.3)
    cam = Picamera2(0)
    _video(cam, fps=100)
    cam.start()
    got = _slow_consumer(cam, world, 40, 0.025, clock.sleep)     # 2.5 frame periods per frame
    ts = np.array([g[0]["SensorTimestamp"] for g in got])
    gaps = np.round(np.diff(ts) / 10_000_000).astype(int)
    assert set(gaps[1:]) == {2, 3} and abs(gaps[1:].mean() - 2.5) < 0.1
    assert world.counts.dropped >= 55 and world.counts.max_buffers_in_use <= 4
    cam.close()


def test_a_slow_consumer_on_the_wall_clock_never_slows_the_world():
    """crawlerd issue 13: world time is wall time whatever the consumer does; frames are dropped."""
    world, Picamera2 = _camera(tilt_deg=10, speed_m_s=0.3)
    cam = Picamera2(0)
    _video(cam, fps=100)
    cam.start()
    dropped0, started = world.counts.dropped, world.clock()
    got = _slow_consumer(cam, world, 100, 0.025, time.sleep)    # 2.5 frame periods per frame, ~2.7 s
    dropped, now = world.counts.dropped - dropped0, world.clock()
    period, line_us = 10_000_000, 3448 / 182.4                   # IMX219 VGA mode
    readout = int(480 * line_us * 1000)                          # a frame completes 480 lines after its start
    ts = np.array([g[0]["SensorTimestamp"] for g in got])
    lag = np.array([g[1] for g in got]) - ts                     # wall time at delivery - frame start
    assert abs(world.clock() - time.monotonic_ns()) < 1_000_000
    assert np.all(lag >= readout) and np.all(lag - readout < period + 3_000_000), lag.max()
    assert abs(lag[-20:].mean() - lag[:20].mean()) < period / 2            # no drift over the run
    gaps = np.round(np.diff(ts) / period)
    assert 2.2 < gaps.mean() < 3.5 and np.mean((gaps >= 2) & (gaps <= 3)) > 0.7   # sleep() may oversleep
    skipped = (ts[-1] - ts[0]) // period + 1 - len(ts)
    before, after = (ts[0] - started) // period + 1, (now - ts[-1]) // period + 1   # frames outside the run
    assert skipped <= dropped <= skipped + before + after, (dropped, skipped, before, after)   # each one counted
    assert world.counts.max_buffers_in_use <= 4
    assert world.counts.rendered_late <= 30                      # the camera thread had most ready
    # each image is the frame of its SensorTimestamp: hw_sim's render of exactly that instant
    md, _, y = got[50]
    t = world.t_s(md["SensorTimestamp"]) - md["ExposureTime"] / 2 / 1e6    # the crop starts at row 0
    sim = Simulator(SimConfig(width=3280, height=2464, hfov_deg=62.2, vfov_deg=48.8, tilt_deg=10,
                              speed_m_s=0.3, duration_s=24 * 3600.0, window=md["ScalerCrop"],
                              output_size=(320, 240), fps=100, exposure_ms=md["ExposureTime"] / 1000,
                              readout_ms=479 * line_us / 1000))
    assert md["ScalerCrop"] == (1000, 752, 1280, 960) and np.array_equal(y, sim.render(t))
    assert world.true_distance_m(md["SensorTimestamp"]) == pytest.approx(0.3 * world.t_s(md["SensorTimestamp"]))
    cam.close()
