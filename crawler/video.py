"""Recorded video as a frame source: raw Annex-B H.264 (as picamera2 and rpicam-vid write), MP4, MKV.

Frames come out as the decoder's Y plane, never colour-converted. Frame times come, in order of
preference, from a --pts file, from --fps, from the container, or from a `<name>.pts` file beside
the video; which one was used is part of the source's description, because wrong times mean
wrong speeds.
"""

from __future__ import annotations

import struct
import time
from pathlib import Path
from typing import Iterator

import numpy as np

from .errors import VideoError
from .geometry import Camera
from .ports import Frame

RAW_FORMATS = ("h264", "hevc", "mjpeg")          # elementary streams: no timestamps of their own
# a damaged raw stream can be parsed into more frames than were recorded (a flipped byte that looks like
# a start code splits one): no pts file fits it then, --fps still does (off by a frame after a split)
_SPLIT_FRAMES = " (if the recording is damaged, replay it with --fps N instead)"
IMAGE_FORMATS = ("image2", "png_pipe", "jpeg_pipe", "bmp_pipe", "tiff_pipe", "webp_pipe", "gif")


def read_pts(path: str | Path) -> np.ndarray:
    """Frame times in seconds from rpicam-vid's `# timecode format v2` file or picamera2's pts lines.

    Both hold one millisecond timestamp per line; comment lines start with '#'.
    """
    path = Path(path)
    try:
        lines = path.read_text().splitlines()
    except FileNotFoundError:
        raise VideoError(f"pts file {str(path)!r} not found") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise VideoError(f"pts file {str(path)!r} cannot be read: {exc}") from None
    times = []
    for n, line in enumerate(lines, 1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        try:
            times.append(float(line.split()[0]) / 1000.0)
        except ValueError:
            raise VideoError(f"pts file {str(path)!r} line {n}: {line[:40]!r} is not a millisecond "
                             "timestamp") from None
    t = np.asarray(times)
    if len(t) == 0:
        raise VideoError(f"pts file {str(path)!r} holds no timestamps")
    bad = np.flatnonzero(np.diff(t) <= 0)
    if len(bad):
        raise VideoError(f"pts file {str(path)!r}: timestamp {bad[0] + 2} ({t[bad[0] + 1] * 1000:g} ms) "
                         "does not increase; frame times must be strictly increasing")
    return t - t[0]


class VideoReplay:
    """A recording played back as a FrameSource.

    `camera` describes its frames (from [camera], built by the caller); `default_roi` is the thesis's
    square under the centre row. With `realtime`, frames are handed on at their times, as a camera
    delivers them: never early, and a loop that falls behind gets the newest frame, the ones it was
    too late for dropped (numbered gaps, counted in `frames_dropped`), never an ever longer backlog.
    """

    def __init__(self, path: str | Path, camera: Camera, pts: str | Path | None = None,
                 fps: float | None = None, *, realtime: bool = False, kind: str = "replay",
                 default_roi=None):
        self.path = Path(path)
        self.camera = camera
        self.pts_path = Path(pts) if pts else None
        self.fps = fps
        self.expect_size = (camera.width, camera.height)
        self.kind = kind
        self.default_roi = default_roi or (0, 0, camera.width, camera.height)
        self.pacer = Pacer() if realtime else None
        self.timing = ""
        self.description = f"replay {self.path.name}"
        self.warnings: list[str] = []
        self._container = None
        self._times = None
        self.packets = None
        self.frames_total = self.frames_lost = self.frames_damaged = self.frames_dropped = 0

    def __enter__(self):
        import av   # PyAV: python3-av on Raspberry Pi OS

        if self.path.is_dir():
            raise VideoError(f"video {str(self.path)!r} is a folder; pass the recording's file")
        if not self.path.is_file():
            raise VideoError(f"video {str(self.path)!r} not found")
        try:
            self._container = av.open(str(self.path))
        except (av.error.FFmpegError, OSError, ValueError) as exc:
            raise VideoError(f"video {str(self.path)!r} cannot be opened: {exc}") from None
        fmt = self._container.format.name
        if not self._container.streams.video:
            self._container.close()
            raise VideoError(f"{str(self.path)!r} holds no video stream")
        if fmt in IMAGE_FORMATS or fmt.endswith("_pipe") and fmt not in RAW_FORMATS:
            self._container.close()
            raise VideoError(f"{str(self.path)!r} is a still image ({fmt}), not a video recording")
        if self.pts_path is not None:
            self._times = read_pts(self.pts_path)
            self.timing = f"times from {self.pts_path.name}"
            self._check_count(self.pts_path)
        elif self.fps is not None:
            self.timing = f"times from --fps {self.fps:g}"
        else:
            sidecar = self.path.with_suffix(".pts")
            if self._container.format.name in RAW_FORMATS and sidecar.is_file():
                self._times = read_pts(sidecar)
                self.timing = f"times from {sidecar.name} (found beside the video)"
                self._check_count(sidecar)
            else:
                self.timing = "times from the container"
        self.description = f"replay {self.path.name} ({self.timing})"
        return self

    def info(self) -> dict:
        return {}

    def __exit__(self, *exc):
        if self._container is not None:
            self._container.close()
            self._container = None

    def frames(self) -> Iterator[Frame]:
        first = None
        last = float("-inf")
        anew = False                # an I-frame since the last frame handed on (a paced one may skip it)
        for k, frame, intra in self._decoded():
            t = self._time_of(frame, k)
            if first is None:
                first = t
                self._check_size(frame)
            if t <= last:
                raise VideoError(f"{self.path.name}: frame {k} time {t:.6f} s does not increase "
                                 f"({self.timing})")
            last, anew = t, anew or intra
            if self.pacer is not None and not self.pacer.due(t - first):
                self.frames_dropped += 1
                continue
            yield Frame(k, t - first, _y_plane(frame), _mean_qp(frame), anew)
            anew = False
            if self.pacer is not None:
                self.pacer.asked()
        self._report_losses()

    def _decoded(self):
        """(index in the stream, frame, an I-frame: coded anew, not from the frames before it) of
        every frame that decodes; a damaged packet is counted and skipped, not the end of the
        stream. A frame the decoder could only conceal (it flags it corrupt) is counted too: it is
        measured, but what it shows is partly the decoder's guess.

        Raw streams carry no timestamps, so each packet is stamped with its index: a frame that comes
        out then knows its place even when frames before it were lost (exact for the I/P-only streams
        the Pi's encoder writes; with B-frames, counting is the best there is).
        """
        import av

        stream = self._container.streams.video[0]
        stream.thread_type = "AUTO"
        stream.codec_context.options = {"export_side_data": "venc_params"}    # each frame's QP (_mean_qp)
        raw = self._container.format.name in RAW_FORMATS
        sent = out = failed = damaged = 0
        reorders = False            # B-frames: frames leave the decoder out of packet order
        prev = -1
        kinds = av.video.frame.PictureType
        for packet in self._container.demux(stream):
            if packet.size:
                if raw:
                    packet.pts = packet.dts = sent
                sent += 1
            try:
                decoded = packet.decode()
            except av.error.FFmpegError:
                failed += 1
                if sent >= 10 and failed > sent // 2:
                    raise VideoError(f"{self.path.name}: {failed} of the first {sent} frames do not decode; "
                                     "is it a video recording (H.264, MP4, MKV)?") from None
                continue
            for frame in decoded:
                reorders = reorders or frame.pict_type == kinds.B
                if raw and not reorders:
                    if frame.pts <= prev:       # a damaged stream repeated a picture: not a new frame
                        continue
                    k = prev = frame.pts
                else:
                    k = out
                damaged += bool(getattr(frame, "is_corrupt", False))      # the decoder flags it
                yield k, frame, frame.pict_type == kinds.I
                out += 1
        self.frames_total, self.frames_lost = max(sent, out), max(sent, out) - out
        self.frames_damaged = damaged
        if out == 0:
            raise VideoError(f"video {str(self.path)!r} holds no decodable frames")

    def _report_losses(self):
        lost, damaged, total = self.frames_lost, self.frames_damaged, self.frames_total
        if self.frames_dropped:
            self.warnings.append(f"{self.frames_dropped} of {total} frames were dropped: the loop could not keep "
                                 "up with --realtime (the odometry measured across them)")
        if lost or damaged:
            what = " and ".join(part for part in (
                f"{lost} could not be decoded" if lost else "",
                f"{damaged} decoded with errors" if damaged else "") if part)
            self.warnings.append(f"{lost + damaged} of {total} frames are damaged ({what}): a damaged "
                                 "recording; the odometry measured or bridged across them")
        if self._times is not None and len(self._times) > total:
            msg = (f"pts file has {len(self._times)} timestamps but the video has {total} frames; the extra "
                   "timestamps were ignored. If the recording lost frames inside rather than at its end, "
                   "the times (and speeds) after the gap are wrong; the distance is not affected")
            self.warnings.append(msg)

    def _check_count(self, pts_path):
        """A pts file belongs to a recording frame for frame: count the stream's frames first.

        Demuxing (no decoding) is cheap. More frames than timestamps: the wrong pts file. Fewer: a
        recording cut short (warned about at the end).
        """
        import av

        try:
            with av.open(str(self.path)) as c:
                self.packets = sum(1 for p in c.demux(video=0) if p.size)
        except av.error.FFmpegError:
            self.packets = None
            return
        if self.packets > len(self._times):
            raise VideoError(f"{self.path.name} has {self.packets} frames but {pts_path.name} only "
                             f"{len(self._times)} timestamps; is it the right pts file?{_SPLIT_FRAMES}")

    def _time_of(self, frame, n: int) -> float:
        if self._times is not None:
            if n >= len(self._times):
                raise VideoError(f"{self.path.name} has more frames than the {len(self._times)} "
                                 f"timestamps of its pts file; is it the right pts file?{_SPLIT_FRAMES}")
            return float(self._times[n])
        if self.fps is not None:
            return n / self.fps
        if frame.time is None or self._container.format.name in RAW_FORMATS:
            raise VideoError(f"{self.path.name} is a raw stream without frame times; pass --pts FILE "
                             "(from rpicam-vid --save-pts or picamera2's pts=) or --fps N")
        return float(frame.time)

    def _check_size(self, frame):
        if self.expect_size and (frame.width, frame.height) != tuple(self.expect_size):
            w, h = self.expect_size
            raise VideoError(f"{self.path.name} is {frame.width}x{frame.height} but [camera] width/height "
                             f"say {w}x{h}; set them to the video's size (and its FOV or calibration)")


ENC_PARAMS = 19                   # AV_FRAME_DATA_VIDEO_ENC_PARAMS (FFmpeg >= 4.4)
ENC_PARAMS_H264 = 1               # AV_VIDEO_ENC_PARAMS_H264: QP on H.264's scale (VP9's and MPEG-2's differ)
_ENC_HEAD = struct.Struct("@INNii")  # AVVideoEncParams: nb_blocks, blocks_offset, block_size, type, qp


def _mean_qp(frame) -> float | None:
    """The frame's mean quantiser over its blocks, from the encoding parameters FFmpeg exports
    (AVVideoEncParams: the frame's QP, then each block's delta at offset 16), read from the raw side
    data so that every PyAV from 10 on gives it; None when the decoder gives none, or for a codec
    other than H.264 (the model is H.264's). Sigma's codec term (crawler/codec.py) is then left out."""
    for sd in frame.side_data:
        if getattr(sd.type, "value", sd.type) != ENC_PARAMS:     # an enum member, or a bare int (PyAV 10)
            continue
        buf = memoryview(sd).cast("B")
        if buf.nbytes < _ENC_HEAD.size:
            return None
        n, offset, size, kind, qp = _ENC_HEAD.unpack_from(buf)
        if kind != ENC_PARAMS_H264:
            return None
        if n == 0 or size < 20 or offset + n * size > buf.nbytes:
            return float(qp)
        delta = np.frombuffer(buf, np.int32, count=n * size // 4, offset=offset)[4::size // 4]
        return qp + float(delta.mean())
    return None


def _y_plane(frame) -> np.ndarray:
    """The luma plane as a (height, width) uint8 view, without colour conversion."""
    if frame.format.name in ("yuv420p", "yuvj420p", "yuv422p", "yuvj422p", "yuv444p", "nv12", "gray"):
        plane = frame.planes[0]
        buf = np.frombuffer(plane, np.uint8)
        return buf.reshape(frame.height, plane.line_size)[:, :frame.width]
    return frame.to_ndarray(format="gray")


class Pacer:
    """A recording's frames on the wall clock, as a camera makes them (replay --realtime)."""

    def __init__(self, clock=time.monotonic, sleep=time.sleep):
        self.clock, self.sleep = clock, sleep
        self._t0 = self._prev = self._asked = None

    def asked(self):
        """The loop asks for the next frame now: every frame due by now has come, the newest wins."""
        self._asked = self.clock()

    def due(self, t_s: float) -> bool:
        """Sleep until frame time t_s, or False (drop it) if its successor had come when the loop
        asked: a camera hands over the newest frame. Decoding never drops a frame, only the loop."""
        if self._t0 is None:
            self._t0 = self.clock() - t_s
        prev, self._prev = self._prev, t_s
        if self._asked is not None and prev is not None and self._asked >= self._t0 + 2 * t_s - prev:
            return False
        delay = self._t0 + t_s - self.clock()
        if delay > 0:
            self.sleep(delay)
        return True
