"""The time a restarted daemon was down is a gap: measured across when it can be, never guessed.

The checkpoint keeps the last tracked frame's ROI and its distance. A restarted daemon makes it the
odometer's keyframe; if the first frames that can be tracked overlap it (the crawler stood still or
crept while the daemon was down), the motion across the restart is measured like any other step.
If they do not, the odometer starts afresh: the distance goes on from the checkpoint, and the gap
is declared, with how long it was, in the status and in every later message of the run
(`unmeasured_s`), unless a wheel encoder (which kept counting) carries it. Pure: no I/O.
"""

from __future__ import annotations


class RestartGap:
    def __init__(self, down_s: float, checkpoint_m: float, reference=None, wheel: bool = False):
        self.down_s = max(0.0, float(down_s))
        self.checkpoint_m = checkpoint_m
        self.reference = reference        # (ROI image, distance, lateral) saved before the restart, or None
        self.wheel = wheel
        self.state = "measuring"          # -> measured | unknown | wheel
        self.measured_m: float | None = None
        self._ref_m = None

    def begin(self, odometer, t_s: float) -> bool:
        """At the first frame: resume the odometer from the reference. False: there is none that fits
        (the gap is then settled at once: unknown, or the wheel's)."""
        if self.reference is not None:
            img, d, lat = self.reference
            self.reference = None         # the image is the odometer's now
            if odometer.resume_from(img, d, lat, t_s - self.down_s):
                self._ref_m = d
                return True
        odometer.reset(distance=self.checkpoint_m)
        self._settle(measured=False)
        return False

    @property
    def open(self) -> bool:
        return self.state == "measuring"

    def observe(self, est) -> float:
        """A raw odometer estimate while measuring: the first tracked one decides. Returns what the
        published distance must be shifted by (a fresh start counts on from the checkpoint)."""
        if not self.open or not est.tracking:
            return 0.0
        if est.continuous:
            self.measured_m = est.distance_m - self._ref_m
            self._settle(measured=True)
            return 0.0
        self._settle(measured=False)
        return self.checkpoint_m - self._ref_m

    def _settle(self, measured: bool):
        self.state = "measured" if measured else ("wheel" if self.wheel else "unknown")

    @property
    def unmeasured_s(self) -> float:
        """What this restart adds to the run's time whose distance is not in the figure."""
        return self.down_s if self.state == "unknown" else 0.0

    def as_dict(self) -> dict:
        return {"down_s": round(self.down_s, 3), "state": self.state,
                "measured_m": None if self.measured_m is None else round(self.measured_m, 6)}
