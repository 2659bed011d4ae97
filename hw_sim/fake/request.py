"""picamera2's CompletedRequest and MappedArray on the fake camera's buffers."""
from __future__ import annotations

from typing import TYPE_CHECKING

import cv2
import numpy as np

from .configs import RGB_BYTES, YUV_FORMATS
from .pump import FrameJob

if TYPE_CHECKING:
    from .camera import FakePicamera2


class CompletedRequest:
    """A captured frame holding one camera buffer until release() (picamera2/request.py). Its
    pixels come with the first make_array: ready from the camera thread, or rendered then."""

    def __init__(self, picam2: FakePicamera2, metadata: dict, job: FrameJob):
        self.picam2, self.request, self.ref_count = picam2, object(), 1
        self.stop_count, self.configure_count = picam2.stop_count, picam2.configure_count
        self.config = picam2.camera_config.copy()
        self._md, self._job, self._grey = metadata, job, None
        self._mapped: dict[str, np.ndarray] = {}

    def acquire(self) -> None:
        if self.ref_count == 0:
            raise RuntimeError("CompletedRequest: acquiring lock with ref_count 0")
        self.ref_count += 1

    def release(self) -> None:
        self.ref_count -= 1
        if self.ref_count < 0:
            raise RuntimeError("CompletedRequest: lock now has negative ref_count")
        if self.ref_count == 0:
            self.picam2._released(self)
            self.request, self.config = None, {}
            for buf in self._mapped.values():    # the camera refills this memory with a new frame
                buf[...] = 0

    def get_metadata(self) -> dict:
        assert self.request is not None
        return dict(self._md)

    def _image(self) -> np.ndarray:
        if self._grey is None:
            self._grey = self.picam2._pixels(self._job)
        return self._grey

    def make_array(self, name: str) -> np.ndarray:
        """A copy shaped as picamera2's: YUV420 (h*3//2, stride) with Y = [:h, :w]; RGB (h, w, 3|4)."""
        cfg = self.config.get(name)
        if cfg is None:
            raise RuntimeError(f"Stream {name!r} is not defined")
        (w, h), fmt, stride = cfg["size"], cfg["format"], cfg["stride"]
        if name == "raw":
            return np.zeros((h, stride), np.uint8)     # raw Bayer pixels are not simulated
        y = self._image()
        if y.shape != (h, w):
            y = cv2.resize(y, (w, h), interpolation=cv2.INTER_AREA)
        if fmt in YUV_FORMATS:
            buf = np.full((h * 3 // 2, stride), 128, np.uint8)
            buf[:h, :w], buf[:h, w:] = y, 0
            return buf
        out = np.repeat(y[:, :, None], RGB_BYTES[fmt], axis=2)
        if RGB_BYTES[fmt] == 4:
            out[:, :, 3] = 255
        return out

    def make_buffer(self, name: str) -> np.ndarray:
        return self.make_array(name).ravel()

    def _mapped_buffer(self, name: str) -> np.ndarray:
        if self.request is None:
            raise RuntimeError("CompletedRequest: mapping a released request")
        if name not in self._mapped:
            self._mapped[name] = self.make_array(name)
        return self._mapped[name]


class MappedArray:
    """picamera2.MappedArray(request, stream, reshape=True, write=True): the request's buffer in place,
    no copy. Valid only until the request is released: the fake then zeroes it, as the camera would
    overwrite it, so a consumer that keeps a view sees the mistake."""

    def __init__(self, request: CompletedRequest, stream: str, reshape: bool = True, write: bool = True):
        self._request, self._stream, self._write = request, stream, write
        self.array = None

    def __enter__(self) -> "MappedArray":
        self.array = self._request._mapped_buffer(self._stream)
        if not self._write:
            self.array = self.array.view()
            self.array.flags.writeable = False
        return self

    def __exit__(self, *exc) -> None:
        self.array = None
