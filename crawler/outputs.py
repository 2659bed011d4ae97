"""Where processed frames go on disk and on the terminal: a JSONL log, an annotated video, a progress line.

The network (link.py), the checkpoint (checkpoint.py) and the watchdog (sdnotify.py) are Outputs too,
each beside the code of its concern.
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import cv2
import numpy as np

from .errors import CrawlerError
from .ports import Output


class JsonlLog(Output):
    """One JSON object per frame, flushed as written so a crash loses at most the current line."""

    def __init__(self, path: str | Path):
        self.path = Path(path)
        try:
            self._f = open(self.path, "w", buffering=1)
        except OSError as exc:
            raise CrawlerError(f"cannot write log {str(self.path)!r}: {exc.strerror}") from None

    def write(self, frame, estimate, run):
        self._f.write(json.dumps(estimate.as_dict()) + "\n")

    def close(self):
        self._f.close()


class Annotator(Output):
    """The headless version of the thesis's debug window: ROI, tracks, distance and speed on each frame.

    `tracks` is what it draws from: the odometer's roi, camera, tracked_points and track_origins.
    """

    def __init__(self, path: str | Path, tracks, fps: float = 30.0):
        import av

        self.path = Path(path)
        if not self.path.parent.is_dir():
            raise CrawlerError(f"cannot write annotated video {str(self.path)!r}: folder "
                               f"{str(self.path.parent)!r} does not exist")
        try:
            self._out = av.open(str(self.path), "w")
        except (av.error.FFmpegError, OSError, ValueError) as exc:
            raise CrawlerError(f"cannot write annotated video {str(self.path)!r}: {exc}") from None
        self._fps = fps
        self._stream = None
        self.tracks = tracks

    def write(self, frame, est, run):
        import av

        odometer = self.tracks

        img = cv2.cvtColor(frame.gray, cv2.COLOR_GRAY2BGR)
        x, y, w, h = odometer.roi
        colour = (0, 200, 0) if est.tracking else (0, 0, 255)
        cv2.rectangle(img, (x, y), (x + w - 1, y + h - 1), colour, 2)
        origin, cur = odometer.track_origins, odometer.tracked_points
        if len(cur) and len(origin) == len(cur):
            lines = np.stack([origin, cur], axis=1).round().astype(np.int32)
            cv2.polylines(img, list(lines), False, (0, 200, 255), 1, cv2.LINE_AA)
        for p in cur.round().astype(int):
            cv2.circle(img, (int(p[0]), int(p[1])), 3, (0, 255, 255), -1)
        cv2.circle(img, (int(odometer.camera.cx), int(odometer.camera.cy)), 4, (255, 128, 0), -1)
        cv2.line(img, (0, int(odometer.camera.cy)), (img.shape[1] - 1, int(odometer.camera.cy)), (255, 128, 0), 1)
        speed = "--" if est.speed_m_s is None else f"{est.speed_m_s:+.3f} m/s"
        lines = [f"distance {est.distance_m:+.4f} m", f"speed {speed}",
                 f"t {est.t_s:.3f} s  frame {est.frame}",
                 f"tracks {est.inliers}/{est.tracks}  q {est.quality:.2f}" + ("" if est.tracking else "  LOST")]
        for i, text in enumerate(lines):
            org = (10, 30 + 28 * i)
            cv2.putText(img, text, org, cv2.FONT_HERSHEY_SIMPLEX, 0.8, (0, 0, 0), 4, cv2.LINE_AA)
            cv2.putText(img, text, org, cv2.FONT_HERSHEY_SIMPLEX, 0.8, (255, 255, 255), 2, cv2.LINE_AA)
        if self._stream is None:
            from fractions import Fraction
            self._stream = self._out.add_stream("libx264", rate=Fraction(self._fps).limit_denominator(1000))
            self._stream.width, self._stream.height = img.shape[1] & ~1, img.shape[0] & ~1
            self._stream.pix_fmt = "yuv420p"
            self._stream.options = {"crf": "23", "preset": "veryfast"}
        img = img[: self._stream.height, : self._stream.width]
        vf = av.VideoFrame.from_ndarray(np.ascontiguousarray(img), format="bgr24")
        try:
            for packet in self._stream.encode(vf):
                self._out.mux(packet)
        except (av.error.FFmpegError, OSError) as exc:
            raise CrawlerError(f"cannot write annotated video {str(self.path)!r}: {exc}") from None

    def close(self):
        import av

        try:
            if self._stream is not None:
                for packet in self._stream.encode():
                    self._out.mux(packet)
            self._out.close()
        except (av.error.FFmpegError, OSError) as exc:
            raise CrawlerError(f"cannot finish annotated video {str(self.path)!r}: {exc}") from None


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
