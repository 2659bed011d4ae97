"""The three wheel backends on hw_sim's encoder: a fake evdev input device (the kernel driver's
position and events), gpiozero's MockFactory pins driven with quadrature edges, real Zenoh sessions
on loopback. And the restart target: the kernel-encoder backend loses <= 1 cm across a kill."""

import json
import logging
import sys

import pytest
from gpiozero.pins.mock import MockFactory

from conftest import wait_for
from crawler.wheel import (FusionParams, NoWheel, WheelFusion, WheelSettings, WheelUnavailable,
                           open_wheel)
from crawler.wheel.gpio import GpioEncoder
from crawler.wheel.kernel import KernelEncoder, open_input
from crawler.wheel.remote import ZenohWheel
from hw_sim.encoder import FakeInputDevice, QuadratureDriver, SimEncoder, VisionModel
from hw_sim.motion import Motion

CPM = 5000.0


class Clock:
    def __init__(self, t=0.0):
        self.t = t

    def __call__(self):
        return self.t


def kernel_port(enc, clock, *, boot="boot-1", **fake):
    s = WheelSettings.from_dict({"backend": "evdev", "device": "rotary@11", "counts_per_m": CPM})
    return open_wheel(s, clock=clock, opener=lambda name: FakeInputDevice(enc, name=name, **fake),
                      boot_id=lambda: boot)


# -- kernel rotary-encoder (evdev) ------------------------------------------------------------------

def test_kernel_position_is_read_at_open_and_every_frame_with_one_ioctl():
    clock = Clock(0.0)
    enc = SimEncoder(Motion("constant", 0.2, 10).distance, counts_per_m=CPM, clock=clock, t_boot=0.0)
    clock.t = 2.0
    with kernel_port(enc, clock) as port:
        assert isinstance(port, KernelEncoder) and port.absolute
        r = port.read()
        assert r.position_m == pytest.approx(0.4, abs=1 / CPM) and r.t_s == 2.0
        assert r.period_m == pytest.approx((1 << 30) / CPM) and r.epoch.startswith("boot-1:")
        clock.t = 3.0
        assert port.read().position_m == pytest.approx(0.6, abs=1 / CPM)
    assert port.read() is None                                   # closed: no reading, no error


def test_kernel_restart_with_rollover_loses_under_a_centimetre():
    """The daemon-level target on the kernel backend: killed at 5 s (saved at 4.5 s), back at
    6.5 s, a position that wraps every 5000 counts (1 m) while it was down (at 4.9 s)."""
    clock = Clock(0.0)
    motion = Motion("constant", 0.2, 15.0)
    enc = SimEncoder(motion.distance, counts_per_m=CPM, scale=1.03, slip=[(8, 9)], clock=clock, t_boot=0.0)
    params = FusionParams(quantum_m=1 / CPM)

    def run(fusion, vision, port, t0, t1):
        out = None
        for i in range(round(t0 * 30), round(t1 * 30) + 1):
            est = vision.estimate(i / 30)
            clock.t = i / 30 + 0.01
            out = fusion.update(est, port.read())
        return out

    vision = VisionModel(motion.distance, featureless=[(1.0, 1.3)])
    fusion = WheelFusion(params)
    with kernel_port(enc, clock, steps=5000) as port:
        run(fusion, vision, port, 0.0, 4.5)
        saved = json.dumps(fusion.to_dict())
        run(fusion, vision, port, 4.5 + 1 / 30, 5.0)
    with kernel_port(enc, clock, steps=5000) as port:             # a new process, a new open
        resumed = WheelFusion.from_dict(json.loads(saved), params)
        last = run(resumed, VisionModel(motion.distance, seed=5), port, 6.5, 15.0)
    assert abs(last.distance_m - motion.distance(15.0)) <= 0.01
    assert abs(last.distance_m - motion.distance(15.0)) <= 0.002


def test_small_steps_on_the_overlay_are_warned_about(caplog):
    enc = SimEncoder(lambda t: 0.0 * t, clock=Clock(), t_boot=0.0)
    with caplog.at_level(logging.WARNING):
        with kernel_port(enc, Clock(), steps=24):
            pass
    assert "steps=1073741824" in caplog.text


def test_relative_axis_loses_what_happens_while_closed_and_what_overflows(caplog):
    clock = Clock(0.0)
    enc = SimEncoder(lambda t: 0.2 * t, counts_per_m=CPM, clock=clock, t_boot=0.0)
    with kernel_port(enc, clock, absolute=False) as port:
        assert not port.absolute
        clock.t = 0.005                                           # 5 counts: all queued
        assert port.read().position_m == pytest.approx(5 / CPM)
        first_epoch = port.epoch
        clock.t = 0.1                                             # 95 counts: the buffer holds 31
        with caplog.at_level(logging.WARNING):
            r = port.read()
        assert port.dropped == 1 and "overflowed" in caplog.text
        assert r.position_m < 0.1 * 0.2 * 0.5
    clock.t = 1.0
    with kernel_port(enc, clock, absolute=False) as port:         # counts made while closed: gone
        assert port.read().position_m == 0.0 and port.epoch != first_epoch


def test_an_unplugged_encoder_gives_no_reading_and_says_so_once(caplog):
    clock = Clock(1.0)
    enc = SimEncoder(lambda t: 0.2 * t, counts_per_m=CPM, clock=clock, t_boot=0.0)
    devices = []
    s = WheelSettings.from_dict({"backend": "evdev", "device": "/dev/input/event0", "counts_per_m": CPM})
    port = KernelEncoder.from_settings(s, clock=clock,
                                       opener=lambda p: devices.append(FakeInputDevice(enc, path=p)) or devices[-1])
    with port, caplog.at_level(logging.WARNING):
        assert port.read() is not None
        devices[0].unplug()
        assert port.read() is None and port.read() is None
    assert caplog.text.count("cannot be read") == 1


def test_a_device_without_the_axis_is_refused():
    enc = SimEncoder(lambda t: 0.0 * t, clock=Clock(), t_boot=0.0)
    with pytest.raises(WheelUnavailable, match=r"no axis 0 .*\[wheel\] axis"):
        kernel_port(enc, Clock(), axis=1).open()


def test_missing_python_evdev_names_the_apt_package_and_the_venv_flag(monkeypatch):
    monkeypatch.setitem(sys.modules, "evdev", None)
    with pytest.raises(WheelUnavailable) as err:
        open_input("rotary@11")
    assert "apt install python3-evdev" in str(err.value) and "--system-site-packages" in str(err.value)


def test_an_unknown_device_name_or_path_is_one_clear_line(monkeypatch):
    import evdev

    monkeypatch.setattr(evdev, "list_devices", lambda: [])
    with pytest.raises(WheelUnavailable, match="no input device of that name .*dtoverlay=rotary-encoder"):
        open_input("rotary@11")
    with pytest.raises(WheelUnavailable, match="'/dev/input/event99' cannot be opened"):
        open_input("/dev/input/event99")


# -- gpiozero RotaryEncoder ---------------------------------------------------------------------------

def test_gpiozero_counts_full_periods_beyond_its_default_clamp_and_backwards():
    clock = Clock(0.0)
    path = {"m": 0.0}
    enc = SimEncoder(lambda t: path["m"] + 0.0 * t, counts_per_m=4 * 1250, clock=clock, t_boot=0.0)
    factory = MockFactory()
    s = WheelSettings.from_dict({"backend": "gpiozero", "pins": [17, 27], "counts_per_m": 1250})
    with open_wheel(s, clock=clock, pin_factory=factory) as port:
        assert isinstance(port, GpioEncoder)
        quad = QuadratureDriver(enc, factory.pin(17), factory.pin(27))
        path["m"] = 0.1                                           # 500 edges, 125 periods
        assert quad.sync() == 500
        assert port.encoder.steps == 125                          # not clamped at 16
        assert port.read().position_m == pytest.approx(0.1, abs=1 / 1250)
        path["m"] = 0.04
        quad.sync()
        assert port.read().position_m == pytest.approx(0.04, abs=1 / 1250)


def test_gpiozero_pins_already_taken_are_one_clear_line():
    factory = MockFactory()
    from gpiozero import Button

    held = Button(17, pin_factory=factory)
    try:
        with pytest.raises(WheelUnavailable, match=r"\[wheel\] pins = \[17, 27\] cannot be read"):
            GpioEncoder((17, 27), 1250, pin_factory=factory).open()
    finally:
        held.close()


def test_gpiozero_wheel_carries_a_blind_stretch():
    clock = Clock(0.0)
    motion = Motion("constant", 0.1, 4.0)
    enc = SimEncoder(motion.distance, counts_per_m=4 * 1250, scale=1.02, clock=clock, t_boot=0.0)
    factory = MockFactory()
    fusion = WheelFusion(FusionParams(quantum_m=1 / 1250))
    vision = VisionModel(motion.distance, featureless=[(2.0, 3.0)])
    with GpioEncoder((5, 6), 1250, clock=clock, pin_factory=factory) as port:
        quad = QuadratureDriver(enc, factory.pin(5), factory.pin(6))
        for i in range(121):
            est = vision.estimate(i / 30)
            clock.t = i / 30 + 0.01
            quad.sync()
            out = fusion.update(est, port.read())
    assert abs(out.distance_m - motion.distance(4.0)) < 0.002
    assert vision.estimate(4.0).distance_m < motion.distance(4.0) - 0.09   # vision alone lost 0.1 m


# -- Zenoh -------------------------------------------------------------------------------------------

@pytest.fixture
def zenoh_wheel(zenoh_pair):
    import zenoh

    from crawler.link import make_zenoh_config

    clock = Clock(100.0)
    port = ZenohWheel("crawler/c1/wheel", counts_per_m=CPM, direction=-1, timeout_s=0.5, clock=clock,
                      zenoh_config=make_zenoh_config("peer", listen=zenoh_pair["listen"], multicast=False))
    port.open()
    pub = zenoh.open(make_zenoh_config("peer", connect=zenoh_pair["connect"], multicast=False))
    try:
        yield port, pub, clock
    finally:
        pub.close()
        port.close()


def test_zenoh_counts_and_metres_with_the_controller_clock_mapped(zenoh_wheel):
    port, pub, clock = zenoh_wheel

    def position():
        r = port.read()
        return None if r is None else round(r.position_m, 9)

    assert port.read() is None
    assert wait_for(lambda: pub.put("crawler/c1/wheel", json.dumps({"counts": 1000})) or position() == -0.2)
    assert port.read().t_s == 100.0                                   # direction -1; arrival time
    pub.put("crawler/c1/wheel", json.dumps({"distance_m": 1.5, "t_s": 5.0, "epoch": "ctl-3"}))
    assert wait_for(lambda: position() == -1.5)
    assert port.read().epoch == "ctl-3"
    clock.t = 100.5
    pub.put("crawler/c1/wheel", json.dumps({"distance_m": 1.6, "t_s": 5.4}))
    assert wait_for(lambda: position() == -1.6)
    assert port.read().t_s == pytest.approx(100.4)                    # 5.4 on the controller's clock
    clock.t = 101.5
    assert port.read() is None                                        # older than timeout_s


def test_zenoh_bad_messages_are_counted_and_never_raise(zenoh_wheel, caplog):
    port, pub, clock = zenoh_wheel
    with caplog.at_level(logging.WARNING):
        for bad in ("{not json", "[1]", json.dumps({"speed": 1}), json.dumps({"counts": float("inf")})):
            pub.put("crawler/c1/wheel", bad)
        assert wait_for(lambda: port.rejected == 4)
    assert port.read() is None and caplog.text.count("message rejected") == 1


def test_no_wheel_is_a_null_port():
    with open_wheel(WheelSettings.from_dict({})) as port:
        assert isinstance(port, NoWheel) and port.read() is None
