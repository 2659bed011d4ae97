"""[wheel]: every value validated once, with one line that names the key, the value and the fix."""

import pytest

from crawler.errors import BadConfig
from crawler.wheel import WheelSettings


def test_no_section_means_no_wheel():
    s = WheelSettings.from_dict({})
    assert s.backend == "none" and not s.enabled
    assert s.key == "crawler/crawler1/wheel"


def test_each_backend_with_its_keys():
    k = WheelSettings.from_dict({"backend": "evdev", "device": "rotary@11", "counts_per_m": 7640,
                                 "direction": -1, "axis": 0})
    assert k.enabled and k.device == "rotary@11" and k.direction == -1
    assert k.fusion_params().quantum_m == pytest.approx(1 / 7640)
    g = WheelSettings.from_dict({"backend": "gpiozero", "pins": [17, 27], "counts_per_m": 1910})
    assert g.pins == (17, 27)
    z = WheelSettings.from_dict({"backend": "zenoh", "resolution_m": 0.002}, name="c7")
    assert z.key == "crawler/c7/wheel" and z.fusion_params().quantum_m == 0.002
    assert set(WheelSettings.keys()) >= {"backend", "device", "pins", "counts_per_m", "direction", "key"}


@pytest.mark.parametrize("table, message", [
    ({"backend": "evdev", "device": "x", "counts_per_m": -3},
     "[wheel] counts_per_m = -3 must be > 0; set the encoder's counts per metre"),
    ({"backend": "evdev", "device": "x", "counts_per_m": "many"}, "[wheel] counts_per_m = 'many' must be a number"),
    ({"backend": "evdev", "device": "x"}, "[wheel] counts_per_m is missing"),
    ({"backend": "gpiozero", "counts_per_m": 100}, "[wheel] pins = None must be two different BCM"),
    ({"backend": "gpiozero", "counts_per_m": 100, "pins": [17, 17]}, "[wheel] pins = [17, 17] must be two"),
    ({"backend": "gpiozero", "counts_per_m": 100, "pins": [17, 40]}, "0..27"),
    ({"backend": "evdev", "counts_per_m": 100}, "[wheel] device = None must name the encoder"),
    ({"backend": "kernel"}, "[wheel] backend = 'kernel' must be one of none, evdev, gpiozero, zenoh"),
    ({"backend": "zenoh", "key": "crawler/*/wheel"}, "[wheel] key = 'crawler/*/wheel' must be a plain"),
    ({"direction": 2}, "[wheel] direction = 2 must be 1 or -1"),
    ({"direction": True}, "[wheel] direction = True must be 1 or -1"),
    ({"noise": 0}, "[wheel] noise = 0 must be between 0 and 1"),
    ({"scale": 1.6e9}, "check counts_per_m instead"),
    ({"slip_window_s": float("nan")}, "[wheel] slip_window_s = nan must be between"),
    ({"axis": -1}, "[wheel] axis = -1 must be the overlay's linux_axis"),
    ({"counts_per_mm": 5}, "[wheel] unknown key 'counts_per_mm'; known keys: backend, counts_per_m"),
    ([1, 2], "[wheel] must be a table"),
])
def test_bad_values_are_refused_with_the_key_the_value_and_the_fix(table, message):
    with pytest.raises(BadConfig) as err:
        WheelSettings.from_dict(table)
    assert message in str(err.value)
    assert "\n" not in str(err.value)


def test_settings_are_frozen():
    s = WheelSettings.from_dict({})
    with pytest.raises(AttributeError):
        s.backend = "evdev"
