"""Who renders a fake frame's pixels: a camera thread ahead of time, or the caller on demand.

On the Pi the ISP fills a buffer while the application works on the previous frame, so a frame
costs its consumer nothing. RenderAhead does the same on the wall clock: a thread renders each
frame a little before it completes, so make_array finds the pixels ready. On an injected clock
(ManualClock) no wall time passes in the world, so RenderNow simply renders in the caller.
Either way the pixels are the same pure function of the frame (Simulator.render at its time).
"""
from __future__ import annotations

import atexit
import logging
import threading
import weakref
from dataclasses import dataclass
from typing import Callable

import numpy as np

from ..render import Simulator
from .timeline import FrameCounts, FrameSettings

_log = logging.getLogger(__name__)
AHEAD_S = 0.080             # render up to this long before a frame completes
PREFETCH_S = 0.3            # when idle, generate the texture tiles of the view this far ahead
CACHE_FRAMES = 16
_RUNNING: weakref.WeakSet = weakref.WeakSet()     # camera threads a caller never stopped


@atexit.register
def _stop_all() -> None:
    """Stop every camera thread before the interpreter tears down: a daemon thread still inside
    OpenCV while the interpreter finalises aborts the process (a test that fails before close())."""
    for pump in list(_RUNNING):
        pump.stop()


@dataclass(frozen=True)
class FrameJob:
    """Everything a frame's pixels depend on."""
    k: int
    settings: FrameSettings
    t_s: float              # the window's top row, mid-exposure, seconds of world time
    brightness: float       # exposure x gain relative to REF_EXPOSURE


def render_frame(sim: Simulator, job: FrameJob) -> np.ndarray:
    img = sim.render(job.t_s)
    if abs(job.brightness - 1.0) > 1e-6:       # exposure x gain off the reference: brighter/darker
        img = np.clip(img * np.float32(job.brightness) + np.float32(0.5), 0, 255).astype(np.uint8)
    return img


class RenderNow:
    """Pixels rendered by whoever asks (an injected clock: rendering costs no world time)."""

    def __init__(self, simulator: Callable[[FrameSettings], Simulator]):
        self._simulator = simulator

    def pixels(self, job: FrameJob) -> np.ndarray:
        return render_frame(self._simulator(job.settings), job)

    def retarget(self, k: int) -> None:
        pass

    def stop(self) -> None:
        pass


class RenderAhead(RenderNow):
    """A camera thread that renders frames before they complete; pixels() takes them from it.

    `next_job(after)` (the camera's) gives the next frame worth rendering after frame `after`, or
    (None, seconds to wait); while it waits, the thread calls `prefetch()` (new texture tiles take
    tens of ms: made ahead, they never delay a frame). A frame the thread has not reached when it is asked for is rendered by
    the asker (counted in FrameCounts.rendered_late), or awaited if the thread is on it.
    """

    def __init__(self, simulator: Callable[[FrameSettings], Simulator],
                 next_job: Callable[[int], tuple[FrameJob | None, float]], counts: FrameCounts,
                 prefetch: Callable[[], None] = lambda: None):
        super().__init__(simulator)
        self._next_job, self._counts, self._prefetch = next_job, counts, prefetch
        self._cache: dict[FrameJob, np.ndarray] = {}
        self._busy: FrameJob | None = None
        self._claimed: set[FrameJob] = set()
        self._after, self._stop = -1, False
        self._cond = threading.Condition()
        self._thread = threading.Thread(target=self._run, name="hw_sim-camera", daemon=True)
        self._thread.start()
        _RUNNING.add(self)

    def _run(self) -> None:
        while True:
            with self._cond:
                if self._stop:
                    return
                after = self._after
            job, wait_s = self._next_job(after)     # takes the camera's lock: never under ours
            if job is None:
                self._prefetch_quietly()
            with self._cond:
                if self._stop or after != self._after:
                    continue                        # stopping, or retargeted meanwhile
                if job is None:
                    self._cond.wait(timeout=wait_s)
                    continue
                self._after = job.k
                if job in self._claimed or job in self._cache:
                    continue
                self._busy = job
            try:
                img = render_frame(self._simulator(job.settings), job)
            except Exception:               # the asker renders it again and sees the error itself
                _log.debug("rendering frame %d failed", job.k, exc_info=True)
                img = None
            with self._cond:
                self._busy = None
                if img is not None:
                    self._cache[job] = img
                    for old in sorted(self._cache, key=lambda j: j.k)[:-CACHE_FRAMES]:
                        del self._cache[old]
                self._cond.notify_all()

    def _prefetch_quietly(self) -> None:
        try:
            self._prefetch()
        except Exception:
            _log.debug("prefetching tiles failed", exc_info=True)

    def pixels(self, job: FrameJob) -> np.ndarray:
        with self._cond:
            while self._busy == job:
                self._cond.wait()
            img = self._cache.pop(job, None)
            if img is not None:
                for old in [j for j in self._cache if j.k < job.k]:
                    del self._cache[old]    # older frames were superseded: nobody will ask
                return img
            self._claimed.add(job)
            self._counts.rendered_late += 1
        try:
            return super().pixels(job)
        finally:
            with self._cond:
                self._claimed.discard(job)

    def retarget(self, k: int) -> None:
        """Frames from k on changed (new controls): render them again."""
        with self._cond:
            self._after = min(self._after, k - 1)
            self._cond.notify_all()

    def stop(self) -> None:
        with self._cond:
            self._stop = True
            self._cond.notify_all()
        if self._thread is not threading.current_thread():
            self._thread.join()
        _RUNNING.discard(self)
