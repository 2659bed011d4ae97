"""The sensors the fake copies: mode tables from the RPi kernel drivers and picamera2's prints.

Line time = HTS / pixel rate; a mode's fastest frame is (height + VBLANK_min) lines. Also
picamera2's SensorFormat and a stand-in for libcamera.Transform.
"""
from __future__ import annotations

import re
from dataclasses import dataclass

ISP_MIN_CROP = (32, 32)     # smallest ISP crop, mode pixels (libcamera asks the ISP; assumed here)
EXPOSURE_MIN_LINES = 4      # approximate: the drivers' shortest integration
FRAME_LINES_MAX = 0xFFFF    # approximate: the drivers' longest frame
REF_EXPOSURE = 8000.0       # exposure (us) x analogue gain that gives SimConfig.brightness


@dataclass(frozen=True)
class SensorMode:
    """One raw mode, timings from the RPi kernel driver: line = HTS / pixel rate."""
    size: tuple[int, int]
    crop: tuple[int, int, int, int]     # crop_limits: analogue crop, active-area native pixels
    hts: int
    pixel_rate_mhz: float
    vblank_min: int

    @property
    def line_us(self) -> float:
        return self.hts / self.pixel_rate_mhz

    @property
    def min_lines(self) -> int:
        return self.size[1] + self.vblank_min


@dataclass(frozen=True)
class SensorSpec:
    model: str
    i2c: str                            # last part of the libcamera Id
    rotation: int                       # device-tree mounting; libcamera undoes it with sensor flips
    pixel_array: tuple[int, int]
    active: tuple[int, int, int, int]
    formats: tuple[str, ...]            # raw formats in libcamera's order; each has every mode
    modes: tuple[SensorMode, ...]
    fov_deg: tuple[float, float]        # (horizontal, vertical) across the active area
    max_gain: float
    cfa: int                            # ColorFilterArrangement: 0 RGGB, 2 GBRG
    unit_cell_nm: int


def _imx219(size, crop):
    return SensorMode(size, crop, 3448, 182.4, 32)


SENSORS = {
    "ov5647": SensorSpec("ov5647", "ov5647@36", 0, (2624, 1956), (16, 6, 2592, 1944), ("SGBRG10_CSI2P",), (
        SensorMode((640, 480), (16, 0, 2560, 1920), 1852, 55.0, 24),
        SensorMode((1296, 972), (0, 0, 2592, 1944), 1896, 81.6667, 24),
        SensorMode((1920, 1080), (348, 434, 1928, 1080), 2416, 81.6667, 24),
        SensorMode((2592, 1944), (0, 0, 2592, 1944), 2844, 87.5, 24)), (53.50, 41.41), 63.9375, 2, 1400),
    "imx219": SensorSpec("imx219", "imx219@10", 180, (3296, 2480), (8, 8, 3280, 2464),
                         ("SRGGB10_CSI2P", "SRGGB8"), (
        _imx219((640, 480), (1000, 752, 1280, 960)), _imx219((1640, 1232), (0, 0, 3280, 2464)),
        _imx219((1920, 1080), (680, 692, 1920, 1080)), _imx219((3280, 2464), (0, 0, 3280, 2464))),
        (62.2, 48.8), 10.666667, 0, 1120),
    "imx708": SensorSpec("imx708", "imx708@1a", 180, (4640, 2658), (16, 24, 4608, 2592), ("SRGGB10_CSI2P",), (
        SensorMode((1536, 864), (768, 432, 3072, 1728), 5216, 566.4, 40),
        SensorMode((2304, 1296), (0, 0, 4608, 2592), 7824, 585.6, 40),
        SensorMode((4608, 2592), (0, 0, 4608, 2592), 15648, 595.2, 58)), (66.0, 41.0), 16.0, 0, 1400),
}


class SensorFormat:
    """picamera2.sensor_format.SensorFormat: 'SRGGB10_CSI2P' -> bit_depth 10, unpacked 'SRGGB10'."""

    def __init__(self, fmt: str):
        pixels, _, packing = str(fmt).partition("_")
        self.packing = packing or None
        self.bit_depth = int(re.search(r"\d+$", pixels).group())
        self.bayer_order = re.search("[RGB]+", pixels).group()

    @property
    def unpacked(self) -> str:
        return f"S{self.bayer_order}{self.bit_depth}"

    @property
    def format(self) -> str:
        return self.unpacked + (f"_{self.packing}" if self.packing else "")

    def __repr__(self) -> str:
        return self.format


class Transform:
    """Stand-in for libcamera.Transform, which exists only on Raspberry Pi OS."""

    def __init__(self, rotation=0, hflip=False, vflip=False, transpose=False):
        half = rotation % 360 == 180
        self.hflip, self.vflip, self.transpose = bool(hflip) ^ half, bool(vflip) ^ half, bool(transpose)
