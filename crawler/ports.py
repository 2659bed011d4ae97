"""The small interfaces between the odometry loop and the world. Hardware lives behind these."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Iterator, Protocol

import numpy as np


@dataclass
class Frame:
    """One grey frame: the Y plane (a view; copy it to keep it) and its sensor time in seconds."""

    index: int
    t_s: float
    gray: np.ndarray


class FrameSource(Protocol):
    """A context manager that yields frames until the recording ends or the camera stops."""

    description: str   # e.g. "replay demo.h264 (times from demo.pts)"

    def __enter__(self) -> "FrameSource": ...
    def __exit__(self, *exc) -> None: ...
    def frames(self) -> Iterator[Frame]: ...


class Sink(Protocol):
    """Receives every processed frame: logs, annotated video, network publishers."""

    def write(self, frame: Frame, estimate, odometer) -> None: ...
    def close(self) -> None: ...
