"""Camera calibration files: OpenCV intrinsics read from JSON or a calibrateCamera YAML/XML, and
written as JSON (by `crawlerd calibrate intrinsics`).

The file I/O that geometry.py (pure math) must not do.
"""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path

import cv2
import numpy as np

from .errors import BadConfig, CrawlerError
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


def write_calibration(path: str | Path, camera: Camera, **extra) -> Path:
    """Write `camera`'s intrinsics as the JSON load_calibration reads, atomically (a temporary file in
    the same folder, fsync, rename): a crash leaves the old file or the new one, never half of one.
    `extra` (RMS, board, frames...) is kept beside the three keys; readers ignore it."""
    path = Path(path)
    data = {"camera_matrix": camera.matrix.tolist(), "dist_coeffs": [float(x) for x in camera.distortion],
            "image_size": [camera.width, camera.height], **extra}
    text = json.dumps(data, indent=2, allow_nan=False) + "\n"
    if not path.parent.is_dir():
        raise CrawlerError(f"cannot write calibration {str(path)!r}: folder {str(path.parent)!r} does not exist")
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    except OSError as exc:
        raise CrawlerError(f"cannot write calibration {str(path)!r}: {exc.strerror}") from None
    try:
        os.fchmod(fd, 0o644)            # mkstemp's 0600 would hide it from the crawlerd service user
        with os.fdopen(fd, "w") as f:
            f.write(text)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except OSError as exc:
        raise CrawlerError(f"cannot write calibration {str(path)!r}: {exc.strerror}") from None
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
    return path


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

