"""LEDs on gpiozero's mock pins, the checkpoint file, and the systemd notify protocol."""

import socket
import time

import pytest

from conftest import wait_for
from gpiozero.pins.mock import MockFactory, MockPWMPin

from crawler.checkpoint import Checkpoint, CheckpointOutput
from crawler.errors import CrawlerError
from crawler.leds import BrightnessLoop, Leds
from crawler.sdnotify import Notifier


@pytest.fixture
def pins():
    factory = MockFactory(pin_class=MockPWMPin)
    try:
        yield factory
    finally:
        factory.reset()


def test_leds_dim_switch_and_release(pins):
    leds = Leds([12, 13], brightness=0.6, pin_factory=pins)
    leds.on()
    assert [pins.pin(p).state for p in (12, 13)] == [0.6, 0.6]
    leds.set(0.25)
    assert pins.pin(12).state == 0.25 and leds.level == 0.25
    leds.set(3.0)                       # clamped, never more than full
    assert pins.pin(13).state == 1.0
    leds.close()
    leds.close()                        # twice is fine
    assert [s.state for s in pins.pin(12).states][-1] == 0.0


def test_leds_on_a_pin_without_pwm_say_so():
    with pytest.raises(CrawlerError, match="LED pin 12 cannot be driven"):
        Leds([12], pin_factory=MockFactory())       # plain MockPin: no PWM


def test_brightness_loop_converges_and_stays_in_bounds():
    loop = BrightnessLoop(target=110, gain=0.004, min_level=0.05)
    level = 0.2
    for _ in range(300):
        grey = 400 * level               # a wall whose grey level is proportional to the light
        level = loop.update(level, grey)
    assert 400 * level == pytest.approx(110, rel=0.02)
    assert loop.update(0.06, 255) == 0.05 and loop.update(0.99, 0) == 1.0


def test_checkpoint_round_trip_atomic_and_corrupt(tmp_path):
    cp = Checkpoint(tmp_path)
    assert cp.load() is None
    cp.save({"distance_m": 12.5, "frames": 3, "run_id": "abc123"})
    data = Checkpoint(tmp_path).load()
    assert data["distance_m"] == 12.5 and data["run_id"] == "abc123"
    assert not list(tmp_path.glob("*.tmp"))
    (tmp_path / "checkpoint.json").write_text("{half")
    assert Checkpoint(tmp_path).load() is None


def test_checkpoint_output_saves_off_the_loop_every_interval_on_reset_and_at_stop(tmp_path):
    class Run:
        distance_m = 0.0

        def state(self):
            return {"distance_m": self.distance_m, "run_id": "0123ab"}

    def saved():
        data = Checkpoint(tmp_path).load()
        return data and data["distance_m"]

    now, run = [0.0], Run()
    out = CheckpointOutput(Checkpoint(tmp_path), every_s=10.0, clock=lambda: now[0])
    out.write(None, None, run)                 # the first frame is handed over at once
    assert wait_for(lambda: saved() == 0.0, timeout=5)
    run.distance_m = 1.0
    now[0] = 5.0
    out.write(None, None, run)                 # within every_s: not handed over
    time.sleep(0.2)
    assert saved() == 0.0
    out.reset(run)
    assert wait_for(lambda: saved() == 1.0, timeout=5)
    run.distance_m = 2.0
    out.stop(run)                              # the last word is written before stop() returns
    assert saved() == 2.0
    out.close()


def test_notifier_sends_ready_watchdog_stopping(tmp_path):
    addr = str(tmp_path / "notify.sock")
    server = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    server.bind(addr)
    server.settimeout(1)
    now = [0.0]
    n = Notifier({"NOTIFY_SOCKET": addr, "WATCHDOG_USEC": "2000000"}, clock=lambda: now[0])
    n.ready("measuring")
    assert server.recv(200).decode() == "READY=1\nSTATUS=measuring"
    n.watchdog()
    assert server.recv(200) == b"WATCHDOG=1"
    now[0] = 0.5
    n.watchdog()                          # rate-limited to half the watchdog interval
    server.settimeout(0.05)
    with pytest.raises(socket.timeout):
        server.recv(200)
    server.settimeout(1)
    now[0] = 1.01
    n.watchdog()
    assert server.recv(200) == b"WATCHDOG=1"
    n.stopping()
    assert server.recv(200) == b"STOPPING=1"
    n.close()
    assert not Notifier({}).enabled       # outside systemd: a no-op
    Notifier({}).ready()


def test_exposure_is_a_whole_number_of_pwm_periods():
    from crawler.leds import pwm_exposure_us

    assert pwm_exposure_us(1500, 2000) == 1500          # the defaults: 3 periods
    assert pwm_exposure_us(1500, 1000) == 1000          # 1.5 periods: ties go to less blur
    assert pwm_exposure_us(1700, 1000) == 2000
    assert pwm_exposure_us(100, 1000) == 1000           # at least one period
    assert pwm_exposure_us(2600, 3000) == 2667


def test_a_busy_pin_is_named(pins):
    first = Leds([12], pin_factory=pins)
    try:
        with pytest.raises(CrawlerError, match=r"LED pin 12 cannot be driven \(gpiozero: .*no other program"):
            Leds([13, 12], pin_factory=pins)
        assert pins.pin(13).state == 0                  # the pin it did take is released again
    finally:
        first.close()

