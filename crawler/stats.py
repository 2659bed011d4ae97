"""Bookkeeping of a run: what it did, for the closing summary line."""

from __future__ import annotations

from dataclasses import dataclass, field


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

    def summary(self, distance_m: float, lateral_m: float) -> dict:
        duration = (self.last_t - self.first_t) if self.frames else 0.0
        out = {
            "frames": self.frames,
            "duration_s": round(duration, 6),
            "distance_m": round(distance_m, 6),
            "lateral_m": round(lateral_m, 6),
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
