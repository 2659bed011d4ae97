"""Where processed frames go on disk and on the terminal: a JSONL log, an annotated video, a progress line.

The network (link.py), the checkpoint (checkpoint.py) and the watchdog (sdnotify.py) are Outputs too,
each beside the code of its concern.
"""

from __future__ import annotations

import json
import os
import sys
import time
from pathlib import Path

import cv2
import numpy as np

from .errors import CrawlerError
from .ports import Output


MIN_FREE_BYTES = 1 << 20     # refuse to start a file on a disk with less room than this


class OutputError(CrawlerError, OSError):
    """An output file cannot be written; the message names the file and the OS error."""


def probe_file(path: Path, what: str) -> None:
    """Fail now, before the first frame, if `path` cannot take a file: a missing or unwritable folder,
    a device, a full disk. Creates the (empty) file."""
    where = f"cannot write {what} {str(path)!r}"
    if path.is_dir():
        raise OutputError(f"{where}: it is a folder; give a file name")
    if not path.parent.is_dir():
        raise OutputError(f"{where}: folder {str(path.parent)!r} does not exist")
    if path.exists() and not (path.is_file() or path.is_fifo() or str(path) == os.devnull):
        raise OutputError(f"{where}: it is a device, not a file")
    try:
        with open(path, "ab"):
            pass
    except OSError as exc:
        raise OutputError(f"{where}: {exc.strerror}") from None
    st = os.statvfs(path.parent)
    if path.is_file() and st.f_bavail * st.f_frsize < MIN_FREE_BYTES:     # /proc, a full disk
        raise OutputError(f"{where}: the disk holding it has only {st.f_bavail * st.f_frsize // 1024} kB "
                          "free; free some room or choose another disk")


class JsonlLog(Output):
    """One JSON object per frame, flushed as written so a crash loses at most the current line.

    A write that fails (a full disk) ends the run with the file and the OS error named; what was
    written stays.
    """

    def __init__(self, path: str | Path):
        self.path = Path(path)
        probe_file(self.path, "log")
        try:
            self._f = open(self.path, "w", buffering=1)
        except OSError as exc:
            raise OutputError(f"cannot write log {str(self.path)!r}: {exc.strerror}") from None

    def write(self, frame, estimate, run):
        try:
            self._f.write(json.dumps(run.describe(estimate), allow_nan=False) + "\n")
        except OSError as exc:
            raise OutputError(f"cannot write log {str(self.path)!r}: {exc.strerror}") from None

    def close(self):
        if self._f.closed:
            return
        try:
            self._f.close()
        except OSError as exc:
            raise OutputError(f"cannot finish log {str(self.path)!r}: {exc.strerror}") from None


class Annotator(Output):
    """The headless version of the thesis's debug window: ROI, tracks, distance and speed on each frame.

    `tracks` is what it draws from: the odometer's roi, camera, tracked_points and track_origins.
    """

    def __init__(self, path: str | Path, tracks, fps: float = 30.0, pipe_id: str = "", clock=time.time):
        import av
        from fractions import Fraction

        self.path = Path(path)
        probe_file(self.path, "annotated video")
        self._file = None
        try:
            self._file = _VideoFile(self.path)
            self._out = av.open(self._file, "w", options=_streaming_options(self.path))
            self._stream = self._out.add_stream("libx264", rate=Fraction(fps).limit_denominator(1000))
        except (av.error.FFmpegError, OSError, ValueError) as exc:
            if self._file is not None:
                self._file.close()
            raise OutputError(f"cannot write annotated video {str(self.path)!r}: {_why(exc)}") from None
        cam = tracks.camera
        self._stream.width, self._stream.height = cam.width & ~1, cam.height & ~1
        self._stream.pix_fmt = "yuv420p"
        self._stream.options = {"crf": "23", "preset": "veryfast"}
        self.tracks, self.pipe_id = tracks, pipe_id
        self._t0_unix = None          # wall clock of sensor time 0, for the date on the overlay
        self._clock = clock
        self._closed = False

    def write(self, frame, est, run):
        import av

        from .overlay import draw_inspection, draw_odometry, draw_tracks

        t = self.tracks
        img = cv2.cvtColor(frame.gray, cv2.COLOR_GRAY2BGR)
        draw_tracks(img, t.roi, t.camera, t.tracked_points, t.track_origins, est.tracking)
        if self._t0_unix is None:
            self._t0_unix = self._clock() - est.t_s
        when = time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(self._t0_unix + est.t_s))
        d = run.describe(est)
        draw_odometry(img, est)
        draw_inspection(img, d["footage"], d["direction"], self.pipe_id, when)
        img = img[: self._stream.height, : self._stream.width]
        vf = av.VideoFrame.from_ndarray(np.ascontiguousarray(img), format="bgr24")
        try:
            for packet in self._stream.encode(vf):
                self._out.mux(packet)
        except (av.error.FFmpegError, OSError) as exc:
            raise OutputError(f"cannot write annotated video {str(self.path)!r}: {_why(exc)}") from None

    def close(self):
        import av

        if self._closed:
            return
        self._closed = True
        failed = None
        try:
            for packet in self._stream.encode():
                self._out.mux(packet)
            self._out.close()           # writes the last fragment (or a plain MP4's index)
        except (av.error.FFmpegError, OSError) as exc:
            failed = exc
            try:
                self._out.close()       # free it; the first error is the one to report
            except (av.error.FFmpegError, OSError):
                pass
        self._file.close()
        failed = self._file.error or failed
        if failed is not None:
            raise OutputError(f"cannot finish annotated video {str(self.path)!r}: {_why(failed)}") from None


class _VideoFile:
    """The file PyAV writes the annotated video through. FFmpeg drops some write errors (the last
    fragment of an MP4, written at close, on a full disk): this keeps the first, for close() to report."""

    def __init__(self, path: Path):
        self.name = str(path)             # PyAV picks the container format from the name
        self._f = open(path, "wb")
        self.error: OSError | None = None

    def write(self, data) -> int:
        try:
            return self._f.write(data)
        except OSError as exc:
            self.error = self.error or exc
            raise

    def seek(self, offset: int, whence: int = 0) -> int:
        return self._f.seek(offset, whence)

    def tell(self) -> int:
        return self._f.tell()

    def close(self):
        try:
            self._f.close()
        except OSError as exc:
            self.error = self.error or exc


def _streaming_options(path: Path) -> dict:
    """An MP4 written as one-second fragments: a run cut short (a full disk, kill -9, a power cut)
    leaves a video that plays up to its last whole second. A plain MP4 is unreadable until its index
    is written at the very end. Matroska streams by nature."""
    if path.suffix.lower() in (".mp4", ".mov", ".m4v"):
        return {"movflags": "frag_keyframe+empty_moov+default_base_moof", "frag_duration": "1000000"}
    return {}


def _why(exc) -> str:
    """The OS error behind a PyAV error, in words."""
    return getattr(exc, "strerror", None) or str(exc)


class Progress(Output):
    """A single self-overwriting status line on a terminal's stderr; silent otherwise."""

    def __init__(self, stream=None, every_s: float = 0.5):
        self.stream = stream = stream or sys.stderr
        self.enabled = hasattr(stream, "isatty") and stream.isatty()
        self.every_s = every_s
        self._last = 0.0

    def write(self, frame, est, run):
        now = time.monotonic()
        if not self.enabled or now - self._last < self.every_s:
            return
        self._last = now
        speed = "--" if est.speed_m_s is None else f"{est.speed_m_s:+.3f}"
        state = "tracking" if est.tracking else "LOST"
        self.stream.write(f"\rframe {est.frame:6d}  t {est.t_s:8.2f} s  distance {est.distance_m:+9.4f} m  "
                          f"speed {speed} m/s  {state:8s}")
        self.stream.flush()

    def close(self):
        if self.enabled and self._last:
            self.stream.write("\n")
