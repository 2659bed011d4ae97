"""Files of a simulated run, laid out like a Raspberry Pi recording plus ground truth.

NAME.h264  raw Annex-B H.264 (libx264, yuv420p, grey in Y, U = V = 128), like `rpicam-vid -o`
NAME.pts   `# timecode format v2`, one timestamp in ms per frame, like `rpicam-vid --save-pts`
NAME.csv   frame,t_s,distance_m,speed_m_s,tilt_deg,camera_height_m,led_light,wet,lost_before
           (frame = index in the stream; GT_COLUMNS says what each means)
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

GT_COLUMNS = {   # name: meaning, all at the frame's t (its top row, mid-exposure)
    "frame": "index in the stream (dropped frames are not in it)",
    "t_s": "the frame's time, s",
    "distance_m": "true distance travelled since t = 0, m (forward positive)",
    "speed_m_s": "true speed, m/s",
    "tilt_deg": "true camera tilt (tilt_schedule or tilt_deg, plus pitch jitter), deg",
    "camera_height_m": "true camera-to-crown distance H (height profile and bounce included), m",
    "led_light": "LED light the frame collected, mean over its rows: 1 lit, ~0 in a blackout",
    "wet": "share of the centre column's wall on a wet patch (0..1)",
    "lost_before": "sensor frames lost just before this one (drop_prob, dropped_bursts)",
}
GT_HEADER = ",".join(GT_COLUMNS)
GT_HEADER_V1 = "frame,t_s,distance_m,speed_m_s"     # before pose and disturbance columns
PTS_HEADER = "# timecode format v2"
GT_DTYPE = np.dtype([(n, np.int64 if n in ("frame", "lost_before") else np.float64) for n in GT_COLUMNS])
SIDECAR_VERSION = 3               # 3: photographed walls laid in random pieces (2 repeated every half image)


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
    """The ground-truth CSV as a structured array with the fields of GT_COLUMNS. A version-1 file
    (frame,t_s,distance_m,speed_m_s) has NaN tilt/height/light/wet and lost_before -1."""
    with open(path) as f:
        header = f.readline().strip()
        if header not in (GT_HEADER, GT_HEADER_V1):
            raise SimError(f"{path}: header {header!r} is not {GT_HEADER!r}")
        data = np.loadtxt(f, delimiter=",", dtype=np.float64, ndmin=2)
    names = header.split(",")
    out = np.empty(len(data), GT_DTYPE)
    for name in GT_DTYPE.names:
        if name in names:
            out[name] = data[:, names.index(name)] if len(data) else []
        else:
            out[name] = -1 if GT_DTYPE[name].kind == "i" else np.nan
    return out


def ground_truth_rows(sim: Simulator) -> Iterator[tuple[int, float, int, str]]:
    """(sensor index, t, lost_before, CSV row without the frame index) of each kept frame."""
    t, keep = sim.schedule()
    last = -1
    for k in np.flatnonzero(keep):
        g = sim.truth(float(t[k]))
        yield int(k), float(t[k]), int(k - last - 1), (
            f"{t[k]:.9f},{g['distance_m']:.9f},{g['speed_m_s']:.9f},{g['tilt_deg']:.6f},"
            f"{g['camera_height_m']:.9f},{g['led_light']:.6f},{g['wet']:.4f},{k - last - 1}")
        last = k


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
        "ground_truth_columns": GT_COLUMNS,
        "texture": cfg.texture,
        "tilt_schedule": [list(k) for k in cfg.tilt_schedule],     # (t_s, tilt_deg), linear between
        "height_profile": [list(k) for k in cfg.height_profile],   # (y_m, extra_height_mm), linear between
        "led_blackouts": [list(k) for k in cfg.led_blackouts],     # s
        "wet_patches": [list(k) for k in cfg.wet_patches],         # m along the pipe
        "dropped_bursts": [list(k) for k in cfg.dropped_bursts],   # s
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
            rows = ground_truth_rows(sim)
            for f in prefetch(sim.frames()):
                k, t, _, row = next(rows)
                assert k == f.sensor_index
                enc.write(f.image)
                gt.write(f"{f.index},{row}\n")
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
