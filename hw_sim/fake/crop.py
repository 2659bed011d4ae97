"""libcamera's integer crop arithmetic (pipeline_base.cpp applyScalerCrop, scaleIspCrop): ScalerCrop
in native pixels <-> the ISP crop in mode pixels."""
from __future__ import annotations

from .sensors import ISP_MIN_CROP, SensorMode


def tdiv(a: int, b: int) -> int:
    return a // b if a >= 0 else -(-a // b)    # C++ division truncates toward zero


def isp_crop(native, m: SensorMode):
    """ScalerCrop -> ISP crop in mode pixels: at least the minimum size (same aspect), same centre,
    inside the mode."""
    (ax, ay, aw, ah), (ow, oh) = m.crop, m.size
    x, y, w, h = (int(v) for v in native)
    if not w or not h:
        x, y, w, h = 0, 0, 1, 1
    ix, iy, iw, ih = tdiv((x - ax) * ow, aw), tdiv((y - ay) * oh, ah), w * ow // aw, h * oh // ah
    mw, mh = ISP_MIN_CROP
    mw, mh = (w * mh // h, mh) if mw * h < w * mh else (mw, mw * h // w)
    sw, sh = max(iw, mw), max(ih, mh)
    x0, y0 = ix + iw // 2 - sw // 2, iy + ih // 2 - sh // 2
    sw, sh = min(sw, ow), min(sh, oh)
    return (min(max(x0, 0), ow - sw), min(max(y0, 0), oh - sh), sw, sh)


def native_crop(isp, m: SensorMode):
    (ax, ay, aw, ah), (ow, oh), (x, y, w, h) = m.crop, m.size, isp
    return (tdiv(x * aw, ow) + ax, tdiv(y * ah, oh) + ay, w * aw // ow, h * ah // oh)


def default_isp_crop(m: SensorMode, out):
    """VC4's default: the mode bounded to the largest output's aspect ratio, centred."""
    (w, h), (rw, rh) = m.size, out
    sw, sh = (rw * h // rh, h) if w * rh > rw * h else (w, w * rh // rw)
    return (w // 2 - sw // 2, h // 2 - sh // 2, sw, sh)
