"""picamera2's configuration dicts: stream defaults, checks, sensor-mode score, strides, controls."""
from __future__ import annotations

import re

from .sensors import SensorFormat

NR_FAST, NR_HIGH_QUALITY, NR_MINIMAL = 1, 2, 3   # libcamera draft.NoiseReductionModeEnum
YUV_FORMATS, RGB_BYTES = ("YUV420", "YVU420"), {"XBGR8888": 4, "XRGB8888": 4, "BGR888": 3, "RGB888": 3}
RAW_EXTRA = ("bit_depth", "crop_limits", "exposure_limits", "fps", "unpacked")
# Controls the RPi IPA advertises whatever the mode: name -> (min, max, default)
CONTROLS = {
    "AeEnable": (False, True, True), "ExposureTimeMode": (0, 1, 0), "AnalogueGainMode": (0, 1, 0),
    "AeMeteringMode": (0, 3, 0), "AeConstraintMode": (0, 3, 0), "AeExposureMode": (0, 3, 0),
    "ExposureValue": (-8.0, 8.0, 0.0), "AeFlickerMode": (0, 1, 0), "AeFlickerPeriod": (100, 1000000, None),
    "Brightness": (-1.0, 1.0, 0.0), "Contrast": (0.0, 32.0, 1.0), "Sharpness": (0.0, 16.0, 1.0),
    "Saturation": (0.0, 32.0, 1.0), "NoiseReductionMode": (0, 4, 0), "AwbEnable": (False, True, None),
    "AwbMode": (0, 7, 0), "ColourGains": (0.0, 32.0, None), "ColourTemperature": (100, 100000, None),
    "StatsOutputEnable": (False, True, False), "SyncMode": (0, 2, 0), "SyncFrames": (100, 100000, 1000)}
AF_CONTROLS = {"AfMode": (0, 2, 0), "AfRange": (0, 2, 0), "AfSpeed": (0, 1, 0), "AfTrigger": (0, 1, 0),
                "AfPause": (0, 2, 0), "LensPosition": (0.0, 15.0, 1.0)}


def stream_config(defaults: dict, updates, raw: bool = False):
    """picamera2's _make_initial_stream_config, then align_stream(optimal=False) (even sizes)."""
    if updates is None:
        return None
    valid = ("format", "size", "stride", "preserve_ar")
    for k, v in updates.items():
        if k in valid:
            defaults[k] = str(v) if isinstance(v, SensorFormat) else v
        elif not (raw and k in RAW_EXTRA):
            raise ValueError(f"Bad key {k!r}: valid stream configuration keys are {valid}")
    if not raw:
        w, h = defaults["size"]
        defaults["size"] = (w - w % 2, h - h % 2)
    return defaults


def check_config(c: dict) -> None:
    """picamera2's check_camera_config, plus what the fake cannot do."""
    for name in ("colour_space", "transform", "main", "lores", "raw"):
        if name not in c:
            raise RuntimeError(f"{name!r} key expected in camera configuration")
    t = c["transform"]
    if not all(hasattr(t, a) for a in ("hflip", "vflip", "transpose")):
        raise RuntimeError("Transform has incorrect type")
    if t.hflip or t.vflip or t.transpose:
        raise NotImplementedError("sensor flips are not simulated (hw_sim's rolling shutter runs top-down)")
    bad = set(c.get("sensor") or {}) - {"bit_depth", "output_size"}
    if bad:
        raise RuntimeError(f"Unexpected keys {bad} in sensor configuration")
    for name in ("main", "lores", "raw"):
        st = c[name]
        if st is None and name != "main":
            continue
        if type(st) is not dict:
            raise RuntimeError(name + " stream should be a dictionary")
        if "format" not in st or "size" not in st:
            raise RuntimeError(f"{'size' if 'format' in st else 'format'} not found in {name} stream")
        fmt, size = st["format"], st["size"]
        if type(fmt) is not str:
            raise RuntimeError("format in " + name + " stream should be a string")
        if name == "raw" and not re.fullmatch(r"S[RGB]{4}\d+(_\w+)?", fmt):
            raise RuntimeError("Unrecognised raw format " + fmt)
        if name != "raw" and fmt not in YUV_FORMATS and fmt not in RGB_BYTES:
            raise NotImplementedError(f"format {fmt} is not simulated: use YUV420, YVU420 or an RGB format")
        if type(size) is not tuple or len(size) != 2:
            raise RuntimeError("size in " + name + " stream should be (width, height)")
        if size[0] % 2 or size[1] % 2:
            raise RuntimeError("width and height should be even")
    if c["lores"] is not None:
        (mw, mh), (lw, lh) = c["main"]["size"], c["lores"]["size"]
        if lw > mw or lh > mh:
            raise RuntimeError("lores stream dimensions may not exceed main stream")
        if c["lores"]["format"] not in YUV_FORMATS:
            raise RuntimeError("lores stream must be YUV")


def mode_score(raw_mode: dict, bit_depth: int, size) -> float:
    """picamera2's sensor-mode score (which copies libcamera's): a bit larger, same aspect, same depth."""
    def sf(desired, actual):
        d = desired - actual
        return -d / 4 if d < 0 else d * 2
    (w, h), (mw, mh) = size, raw_mode["size"]
    return (sf(w, mw) + sf(h, mh) + 1500 * sf(w / h, mw / mh)
            + 500 * abs(bit_depth - SensorFormat(raw_mode["format"]).bit_depth))


def fill_stride(st: dict) -> None:
    """VC4 bytes per line: the width aligned to 32 pixels (bcm2835-isp), times bytes per pixel."""
    (w, h), fmt = st["size"], st["format"]
    if fmt in YUV_FORMATS:
        st["stride"] = -(-w // 32) * 32
        st["framesize"] = st["stride"] * h * 3 // 2
    else:
        bpp = RGB_BYTES.get(fmt)
        st["stride"] = -(-w // 32) * 32 * bpp if bpp else -(-(w * SensorFormat(fmt).bit_depth // 8) // 32) * 32
        st["framesize"] = st["stride"] * h
