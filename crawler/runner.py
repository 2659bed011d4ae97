"""The frame loop shared by replay, simulation and the live camera: frames in, estimates to sinks."""

from __future__ import annotations

import time
from dataclasses import dataclass, field

from .errors import CrawlerError
from .odometry import Odometer


@dataclass
class RunStats:
    """What a run did, for the closing summary line."""

    frames: int = 0
    tracked: int = 0
    first_t: float | None = None
    last_t: float | None = None
    wall_s: float = 0.0
    max_speed: float = 0.0
    quality_sum: float = 0.0
    error: str | None = None
    extra: dict = field(default_factory=dict)

    def add(self, est):
        self.frames += 1
        self.tracked += bool(est.tracking)
        self.quality_sum += est.quality
        if self.first_t is None:
            self.first_t = est.t_s
        self.last_t = est.t_s
        if est.speed_m_s is not None:
            self.max_speed = max(self.max_speed, abs(est.speed_m_s))

    def summary(self, odometer: Odometer) -> dict:
        duration = (self.last_t - self.first_t) if self.frames else 0.0
        out = {
            "frames": self.frames,
            "duration_s": round(duration, 6),
            "distance_m": round(odometer.distance, 6),
            "lateral_m": round(odometer.lateral, 6),
            "fps_processed": round(self.frames / self.wall_s, 2) if self.wall_s > 0 else None,
            "tracking_share": round(self.tracked / self.frames, 4) if self.frames else 0.0,
            "lost_frames": self.frames - self.tracked,
            "mean_quality": round(self.quality_sum / self.frames, 3) if self.frames else 0.0,
            "max_speed_m_s": round(self.max_speed, 4),
        }
        out.update(self.extra)
        if self.error:
            out["error"] = self.error
        return out


def run(source, odometer: Odometer, sinks=(), *, realtime: bool = False, stop=None,
        max_frames: int | None = None, clock=time.monotonic) -> RunStats:
    """Feed every frame of an entered source through the odometer into the sinks.

    A source that fails mid-way ends the run with the error recorded; what was measured up to the
    break is kept. `stop()` returning True ends the run between frames (signals).
    """
    stats = RunStats()
    start = clock()
    t0 = None
    try:
        for frame in source.frames():
            if realtime:
                if t0 is None:
                    t0 = clock() - frame.t_s
                delay = t0 + frame.t_s - clock()
                if delay > 0:
                    time.sleep(delay)
            est = odometer.update(frame.gray, frame.t_s)
            stats.add(est)
            for sink in sinks:
                sink.write(frame, est, odometer)
            if (stop is not None and stop()) or (max_frames is not None and stats.frames >= max_frames):
                break
    except CrawlerError as exc:
        stats.error = str(exc)
    finally:
        stats.wall_s = clock() - start
    return stats
