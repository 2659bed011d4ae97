"""Bookkeeping of a run: what it did, for the closing summary line."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


class LoopLatency:
    """How long each frame-loop iteration took (measuring, commands, outputs; not waiting for the
    camera): the worst, and the 99th percentile from a 0.1 ms histogram (a few ns per frame)."""

    BIN_MS = 0.1
    BINS = 20_000                   # up to 2 s; longer ones land in the last bin (max stays exact)

    def __init__(self):
        self.hist = np.zeros(self.BINS, np.int64)
        self.max_ms = 0.0
        self.n = 0

    def add(self, ms: float):
        self.hist[min(int(ms / self.BIN_MS), self.BINS - 1)] += 1
        self.max_ms = max(self.max_ms, ms)
        self.n += 1

    def percentile(self, q: float) -> float:
        if not self.n:
            return 0.0
        i = int(np.searchsorted(np.cumsum(self.hist), q / 100.0 * self.n))
        return min((i + 1) * self.BIN_MS, self.max_ms)      # the bin's upper edge, never above the worst

    def as_dict(self) -> dict:
        return {"max": round(self.max_ms, 2), "p99": round(self.percentile(99), 2),
                "p50": round(self.percentile(50), 2)}


@dataclass
class RunStats:
    """What a run did, for the closing summary line."""

    frames: int = 0
    tracked: int = 0
    dropped: int = 0                  # frames the source dropped (the loop was late) or lost
    first_t: float | None = None
    last_t: float | None = None
    wall_s: float = 0.0
    max_speed: float = 0.0
    quality_sum: float = 0.0
    error: str | None = None
    loop: LoopLatency = field(default_factory=LoopLatency)

    def add(self, est):
        self.frames += 1
        self.tracked += bool(est.tracking)
        self.quality_sum += est.quality
        if self.first_t is None:
            self.first_t = est.t_s
        self.last_t = est.t_s
        if est.speed_m_s is not None:
            self.max_speed = max(self.max_speed, abs(est.speed_m_s))

    def summary(self, distance_m: float, lateral_m: float) -> dict:
        duration = (self.last_t - self.first_t) if self.frames else 0.0
        out = {
            "frames": self.frames,
            "duration_s": round(duration, 6),
            "distance_m": round(distance_m, 6) + 0.0,    # (+ 0.0: never "-0.0")
            "lateral_m": round(lateral_m, 6) + 0.0,
            "fps_processed": round(self.frames / self.wall_s, 2) if self.wall_s > 0 else None,
            "tracking_share": round(self.tracked / self.frames, 4) if self.frames else 0.0,
            "lost_frames": self.frames - self.tracked,
            "dropped_frames": self.dropped,
            "drop_rate": round(self.dropped / (self.frames + self.dropped), 4) if self.frames else 0.0,
            "mean_quality": round(self.quality_sum / self.frames, 3) if self.frames else 0.0,
            "max_speed_m_s": round(self.max_speed, 4),
            "loop_ms": self.loop.as_dict(),
        }
        if self.error:
            out["error"] = self.error
        return out
