"""Files of a simulated run, laid out like a Raspberry Pi recording plus ground truth.

NAME.h264  raw Annex-B H.264 (libx264, yuv420p, grey in Y, U = V = 128), like `rpicam-vid -o`
NAME.pts   `# timecode format v2`, one timestamp in ms per frame, like `rpicam-vid --save-pts`
NAME.csv   frame,t_s,distance_m,speed_m_s (frame = index in the stream)
NAME.json  every SimConfig field plus derived values (intrinsics of the output frame, ...)
"""
from __future__ import annotations

import json
import os
import queue
import threading
from fractions import Fraction
from pathlib import Path
from typing import Callable, Iterable, Iterator

import av
import numpy as np

from .config import BadValue, SimConfig, SimError
from .render import Simulator

GT_HEADER = "frame,t_s,distance_m,speed_m_s"
PTS_HEADER = "# timecode format v2"
GT_DTYPE = np.dtype([("frame", np.int64), ("t_s", np.float64), ("distance_m", np.float64),
                     ("speed_m_s", np.float64)])
SIDECAR_VERSION = 1


class H264Writer:
    """Encodes grey frames into a raw .h264 file. A context manager: the file is finished on exit."""

    def __init__(self, path: Path, width: int, height: int, fps: float, crf: int = 18,
                 preset: str = "veryfast"):
        self.width, self.height = width, height
        self._c = av.open(str(path), mode="w", format="h264")
        self._s = self._c.add_stream("libx264", rate=Fraction(fps).limit_denominator(100000))
        self._s.width, self._s.height, self._s.pix_fmt = width, height, "yuv420p"
        self._s.options = {"crf": str(crf), "preset": preset}
        self._yuv = np.full((height * 3 // 2, width), 128, np.uint8)
        self.frames = 0

    def write(self, grey: np.ndarray) -> None:
        self._yuv[:self.height] = grey
        frame = av.VideoFrame.from_ndarray(self._yuv, format="yuv420p")
        frame.pts = self.frames
        for packet in self._s.encode(frame):
            self._c.mux(packet)
        self.frames += 1

    def close(self) -> None:
        if self._c is None:
            return
        try:
            for packet in self._s.encode():
                self._c.mux(packet)
        finally:
            self._c.close()
            self._c = None

    def __enter__(self) -> "H264Writer":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def read_h264(path: str | os.PathLike) -> Iterator[np.ndarray]:
    """Decoded frames of a raw .h264 file as uint8 grey (the Y plane as stored, no range change)."""
    with av.open(str(path), format="h264") as c:
        for frame in c.decode(video=0):
            y = frame.planes[0]
            buf = np.frombuffer(y, np.uint8).reshape(-1, y.line_size)
            yield buf[:frame.height, :frame.width].copy()


def write_pts(path: Path, t_s: Iterable[float]) -> None:
    with open(path, "w") as f:
        f.write(PTS_HEADER + "\n")
        for t in t_s:
            f.write(f"{t * 1000.0:.3f}\n")


def read_pts(path: str | os.PathLike) -> np.ndarray:
    """Timestamps of a `# timecode format v2` file, in seconds."""
    lines = Path(path).read_text().splitlines()
    if not lines or not lines[0].startswith("# timecode format v2"):
        raise SimError(f"{path}: not a '# timecode format v2' file (first line {lines[:1]})")
    return np.array([float(x) for x in lines[1:] if x.strip()], dtype=np.float64) / 1000.0


def read_ground_truth(path: str | os.PathLike) -> np.ndarray:
    """The ground-truth CSV as a structured array with fields frame, t_s, distance_m, speed_m_s."""
    with open(path) as f:
        header = f.readline().strip()
        if header != GT_HEADER:
            raise SimError(f"{path}: header {header!r} is not {GT_HEADER!r}")
        data = np.loadtxt(f, delimiter=",", dtype=np.float64, ndmin=2)
    out = np.empty(len(data), GT_DTYPE)
    if len(data):
        out["frame"] = data[:, 0].astype(np.int64)
        for i, name in enumerate(GT_DTYPE.names[1:], start=1):
            out[name] = data[:, i]
    return out


def sidecar(sim: Simulator, frames: int, last_t: float, files: dict[str, str]) -> dict:
    """Every parameter plus the derived values a consumer needs without importing hw_sim."""
    cfg = sim.cfg
    tex = sim.texture
    t, keep = sim.schedule()
    return {
        "hw_sim_sidecar": SIDECAR_VERSION,
        "files": files,
        "config": cfg.to_dict(),
        "camera_height_m": sim.camera_height_m,
        "pipe_radius_m": sim.radius_m,
        "tilt_deg": cfg.tilt_deg,
        "vfov_deg": cfg.vfov_deg,          # of the full sensor
        "hfov_deg": cfg.hfov_deg,          # of the full sensor
        "sensor_width": cfg.width,
        "sensor_height": cfg.height,
        "window": list(cfg.window_px),     # sensor rectangle shown in the output frame
        "width": sim.width,                # of the output frame (the .h264)
        "height": sim.height,
        "fps": cfg.fps,
        **sim.intrinsics,                  # fx, fy, cx, cy of the output frame
        "distortion": list(sim.distortion),
        "mm_per_texel": cfg.mm_per_texel,
        "mm_per_texel_circumferential": tex.m_per_texel_circ * 1000.0,
        "texels_around": tex.n_cols,
        "frames": frames,
        "sensor_frames": int(len(t)),
        "dropped_frames": int(len(t) - keep.sum()),
        "blur_samples": sim.blur_samples if cfg.exposure_ms > 0 else 1,
        "first_t_s": 0.0,
        "last_t_s": last_t,
        "true_distance_m": sim.distance_at(last_t),          # at the last frame in the stream
        "path_length_m": sim.motion.path_length(),           # both directions, over [0, duration]
    }


def prefetch(items: Iterable, depth: int = 4) -> Iterator:
    """Yield from `items`, produced ahead in a thread: rendering (numpy/OpenCV, GIL released)
    overlaps encoding. The producer's exception is re-raised here; leaving early stops it."""
    q: queue.Queue = queue.Queue(depth)
    stop = threading.Event()
    end = object()

    def put(x) -> bool:
        while not stop.is_set():
            try:
                q.put(x, timeout=0.1)
                return True
            except queue.Full:
                pass
        return False

    def produce() -> None:
        try:
            for item in items:
                if not put((item, None)):
                    return
            put((end, None))
        except BaseException as e:  # handed to the consumer
            put((end, e))

    th = threading.Thread(target=produce, name="hw_sim-render", daemon=True)
    th.start()
    try:
        while True:
            item, err = q.get()
            if item is end:
                if err is not None:
                    raise err
                return
            yield item
    finally:
        stop.set()
        th.join()


def write_run(cfg: SimConfig, out_dir: str | os.PathLike, name: str,
              progress: Callable[[int, int], None] | None = None) -> dict[str, Path]:
    """Render cfg into out_dir/name.{h264,pts,csv,json}; progress(done, total) after each frame.

    Files are written under temporary names and renamed at the end, so a failed or interrupted
    run leaves no half-written set behind.
    """
    if not name or "/" in name or name in (".", ".."):
        raise BadValue(f"name={name!r} must be a plain file name")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    sim = Simulator(cfg)
    paths = {ext: out / f"{name}.{ext}" for ext in ("h264", "pts", "csv", "json")}
    tmp = {ext: p.with_name(p.name + ".part") for ext, p in paths.items()}
    total = int(sim.schedule()[1].sum())
    times: list[float] = []
    try:
        with H264Writer(tmp["h264"], sim.width, sim.height, cfg.fps, cfg.crf, cfg.preset) as enc, \
                open(tmp["csv"], "w") as gt:
            gt.write(GT_HEADER + "\n")
            for f in prefetch(sim.frames()):
                enc.write(f.image)
                gt.write(f"{f.index},{f.t_s:.9f},{f.distance_m:.9f},{f.speed_m_s:.9f}\n")
                times.append(f.t_s)
                if progress is not None:
                    progress(f.index + 1, total)
        write_pts(tmp["pts"], times)
        files = {ext: p.name for ext, p in paths.items()}
        meta = sidecar(sim, len(times), times[-1], files)
        tmp["json"].write_text(json.dumps(meta, indent=2) + "\n")
        for ext in paths:
            os.replace(tmp[ext], paths[ext])
    finally:
        for p in tmp.values():
            if p.exists():
                p.unlink()
    return paths
