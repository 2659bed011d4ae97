"""The small interfaces between the measuring loop and the world. Hardware lives behind these.

The loop (crawler/daemon.py) sees a FrameSource, the LEDs and one list of Outputs, nothing else; the
composition root (crawler/service.py) builds them. Null objects stand in for the parts a run does
not have, so the loop never asks "is there one?".
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Iterator, Protocol

import numpy as np


@dataclass
class Frame:
    """One grey frame: the Y plane (a view; copy it to keep it) and its sensor time in seconds.

    `index` numbers the source's own frames (the sensor's, the recording's), so a gap is frames the
    source dropped or lost before the loop saw them (the status's `dropped_frames`)."""

    index: int
    t_s: float
    gray: np.ndarray
    qp: float | None = None   # a recording's mean quantiser (H.264 QP); None for raw frames (crawler/codec.py)
    intra: bool = False       # a recording's I-frame: the encoder coded the picture anew (crawler/stands.py)


class FrameSource(Protocol):
    """A context manager that yields frames until the recording ends or the camera stops.

    After entering, `camera` is the exact camera of the frames (geometry.Camera) and `default_roi`
    the region to measure unless [odometry] roi says otherwise.
    """

    kind: str          # "camera", "sim", "replay" or "replay-fallback": the status's `source`
    description: str   # e.g. "replay demo.h264 (times from demo.pts)"
    warnings: list

    def __enter__(self) -> "FrameSource": ...
    def __exit__(self, *exc) -> None: ...
    def frames(self) -> Iterator[Frame]: ...
    def info(self) -> dict: ...          # what the status shows of the source (the sensor plan)


class Run(Protocol):
    """What outputs may ask of the run in progress (the Daemon implements it)."""

    name: str
    run_id: str

    @property
    def distance_m(self) -> float: ...
    def status(self) -> dict: ...
    def state(self) -> dict: ...         # what a checkpoint keeps
    def describe(self, estimate) -> dict: ...   # an estimate with the run's fields, as published


class Output:
    """Where each measured frame goes: a log, a video, the network, the checkpoint, the watchdog.

    Every hook is a working no-op (like picamera2's null outputs), so an output implements only what
    it needs. Entering opens and probes it, so a file that cannot be written fails before the first
    frame; leaving releases it.
    """

    def __enter__(self) -> "Output":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def start(self, run: Run) -> None:
        """Measurement begins (LEDs on, the first frame is next)."""

    def write(self, frame: Frame, estimate, run: Run) -> None:
        """One processed frame and its estimate."""

    def reset(self, run: Run) -> None:
        """The operator reset the distance: a new run."""

    def note(self, topic: str, payload: dict) -> None:
        """Something happened worth publishing on its own topic (an observation, a slip event)."""

    def report(self, status: dict) -> None:
        """Add this output's fields (its errors, its truth) to a status being built."""

    def summarize(self, summary: dict) -> None:
        """Add this output's fields to the closing summary line."""

    def stop(self, run: Run) -> None:
        """Measurement ended (normally, by a fault or a crash): the last word."""

    def close(self) -> None:
        """Release files, sockets, sessions."""
