"""Camera calibration files: OpenCV intrinsics read from JSON or a calibrateCamera YAML/XML.

The file I/O that geometry.py (pure math) must not do.
"""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np

from .errors import BadConfig
from .geometry import Camera

EXPECTED = ('JSON {"camera_matrix": [[fx,0,cx],[0,fy,cy],[0,0,1]], "dist_coeffs": [...], '
            '"image_size": [w, h]} or a calibrateCamera YAML')


def load_calibration(path: str | Path, **kw) -> Camera:
    """The Camera of a calibration file; `kw` (flips, readout) are passed on to Camera."""
    path = Path(path)
    if not path.is_file():
        raise BadConfig(f"[camera] calibration = {str(path)!r}: no such file")
    try:
        if path.suffix.lower() == ".json":
            k, dist, (w, h) = _read_json(path)
        else:
            k, dist, (w, h) = _read_filestorage(path)
    except (KeyError, ValueError, TypeError, cv2.error, SystemError, UnicodeDecodeError) as exc:
        raise BadConfig(f"[camera] calibration = {str(path)!r} is not an OpenCV calibration ({exc}); "
                        f"expected {EXPECTED}") from None
    fx, fy, cx, cy = float(k[0, 0]), float(k[1, 1]), float(k[0, 2]), float(k[1, 2])
    if not (w > 0 and h > 0 and fx > 0 and fy > 0 and np.isfinite([fx, fy, cx, cy]).all()
            and np.isfinite(dist).all()):
        raise BadConfig(f"[camera] calibration = {str(path)!r} holds impossible intrinsics "
                        f"(fx={fx}, fy={fy}, cx={cx}, cy={cy}, image_size={w}x{h}); recalibrate")
    return Camera(w, h, fx, fy, cx, cy, distortion=tuple(float(x) for x in dist), **kw)


def _read_json(path: Path):
    data = json.loads(path.read_text())
    k = np.asarray(data["camera_matrix"], dtype=float).reshape(3, 3)
    dist = np.asarray(data.get("dist_coeffs", []), dtype=float).ravel()
    return k, dist, tuple(int(v) for v in data["image_size"])


def _read_filestorage(path: Path):
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    k = fs.getNode("camera_matrix").mat()
    d = fs.getNode("distortion_coefficients").mat()
    w, h = int(fs.getNode("image_width").real()), int(fs.getNode("image_height").real())
    if k is None or w <= 0 or h <= 0:
        raise KeyError("camera_matrix/image_width/image_height")
    return k, (np.zeros(0) if d is None else d.ravel()), (w, h)

