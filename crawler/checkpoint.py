"""The run's distance on disk, so a restarted daemon resumes instead of starting from zero.

Beside it, the last tracked frame's ROI (reference.npy, with its distance in the checkpoint): a
restarted daemon measures its first frames against it, so the motion while it was down is measured
when the wall is still in view, and declared unknown when it is not.

Written atomically (temporary file, fsync, rename): a power cut leaves the old or the new file, never
half of one. Writing happens on a thread of its own: an SD card that stalls for tens of milliseconds
must not stall the frame loop. Everything read back is validated; a file that is not a valid
checkpoint is moved aside (kept, named with the time), never silently overwritten.
"""

from __future__ import annotations

import json
import logging
import math
import os
import re
import threading
import time
from pathlib import Path

import numpy as np

from .ports import Output

_log = logging.getLogger(__name__)
MAX_DISTANCE_M = 1e6          # a checkpoint further than this is not a pipe run
RUN_ID = re.compile(r"^[0-9a-f]{6,32}$")


class CorruptCheckpoint(ValueError):
    """The state file is not a valid checkpoint."""


def validate(data) -> dict:
    """The checkpoint's fields, checked: a finite distance, a run id, a frame count."""
    if not isinstance(data, dict):
        raise CorruptCheckpoint("not a JSON object")
    d = data.get("distance_m")
    if not _finite(d) or abs(d) > MAX_DISTANCE_M:
        raise CorruptCheckpoint(f"distance_m = {repr(d)[:40]} is not a finite distance")
    run_id = data.get("run_id")
    if not isinstance(run_id, str) or not RUN_ID.match(run_id):
        raise CorruptCheckpoint(f"run_id = {run_id!r} is not a run id")
    frames = data.get("frames", 0)
    if isinstance(frames, bool) or not isinstance(frames, int) or frames < 0:
        raise CorruptCheckpoint(f"frames = {frames!r} is not a frame count")
    ref = data.get("reference")
    if ref is not None and not (isinstance(ref, dict) and _finite(ref.get("distance_m"))
                                and _finite(ref.get("lateral_m"))):
        data = {k: v for k, v in data.items() if k != "reference"}     # unusable, not fatal
    tilt = data.get("tilt")
    if tilt is not None and not (isinstance(tilt, dict) and _finite(tilt.get("deg")) and abs(tilt["deg"]) < 90
                                 and _finite(tilt.get("sigma_deg")) and tilt["sigma_deg"] >= 0):
        data = {k: v for k, v in data.items() if k != "tilt"}          # tilt auto searches afresh
    return dict(data, distance_m=float(d))


def _finite(v) -> bool:
    if not isinstance(v, (int, float)) or isinstance(v, bool):
        return False
    try:
        return math.isfinite(v)
    except OverflowError:         # an integer beyond any float (JSON allows one)
        return False


class Checkpoint:
    """The state file in the state directory: load once at start, save as the run goes."""

    def __init__(self, directory: str | Path):
        self.path = Path(directory) / "checkpoint.json"
        self.problem: str | None = None       # what went wrong reading it (kept until a reset)

    def load(self) -> dict | None:
        """The saved run, or None if there is none. A corrupt one is moved aside and reported."""
        try:
            text = self.path.read_text()
        except FileNotFoundError:
            return None
        except (OSError, UnicodeDecodeError) as exc:
            return self._set_aside(f"unreadable ({exc})", "")
        try:
            return validate(json.loads(text))
        except (ValueError, CorruptCheckpoint) as exc:
            return self._set_aside(str(exc), text)

    def _set_aside(self, why: str, text: str) -> None:
        aside = self.path.with_name(f"checkpoint.corrupt-{time.strftime('%Y%m%d-%H%M%S')}.json")
        try:
            os.replace(self.path, aside)
            kept = f"kept as {aside.name}"
        except OSError as exc:
            kept = f"could not be moved aside ({exc.strerror})"
        m = re.search(r'"distance_m"\s*:\s*(-?[0-9.eE+]+)', text)
        lost = f"the distance it held ({m.group(1)} m) is lost" if m else "its distance is lost"
        self.problem = f"checkpoint {self.path} was corrupt ({why}); {kept}; {lost}; started a new run from 0 m"
        _log.error("%s", self.problem)
        return None

    @property
    def reference_path(self) -> Path:
        return self.path.with_name("reference.npy")

    def save_reference(self, img: np.ndarray) -> None:
        """The reference image, atomically (raises OSError)."""
        tmp = self.reference_path.with_suffix(".tmp")
        self.path.parent.mkdir(parents=True, exist_ok=True)
        with open(tmp, "wb") as f:
            np.save(f, np.ascontiguousarray(img), allow_pickle=False)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, self.reference_path)

    def load_reference(self, meta, roi) -> np.ndarray | None:
        """The saved reference for this ROI, or None (none, another ROI, unreadable: said why)."""
        if not isinstance(meta, dict):
            return None
        if list(meta.get("roi") or []) != list(roi):
            _log.warning("the saved reference frame is for ROI %s, not %s: the restart gap is not measured",
                         meta.get("roi"), list(roi))
            return None
        try:
            img = np.load(self.reference_path, allow_pickle=False)
        except (OSError, ValueError) as exc:
            _log.warning("cannot read the reference frame %s (%s): the restart gap is not measured",
                         self.reference_path, exc)
            return None
        if img.dtype != np.uint8 or img.shape != (roi[3], roi[2]):
            _log.warning("the reference frame %s is not a %dx%d grey image: the restart gap is not measured",
                         self.reference_path, roi[2], roi[3])
            return None
        return img

    def save(self, state: dict) -> None:
        """Write atomically; raises OSError (the caller reports it)."""
        data = dict(state, saved_unix_s=round(time.time(), 3))
        text = json.dumps(data, allow_nan=False)
        tmp = self.path.with_suffix(".tmp")
        self.path.parent.mkdir(parents=True, exist_ok=True)
        with open(tmp, "w") as f:
            f.write(text)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, self.path)


class CheckpointOutput(Output):
    """Hands the run's state to a writer thread every `every_s` (10 Hz by default), at once on a
    reset, and writes it one last time when measurement stops. The loop never waits for the disk."""

    def __init__(self, store: Checkpoint, every_s: float = 0.1, clock=time.monotonic, reference_s: float = 1.0):
        self.store = store
        self.every_s = every_s
        self.reference_s = reference_s        # the reference image at most this often (it is 50 kB)
        self.clock = clock
        self._last: float | None = None
        self._last_ref: float | None = None
        self._ref_seq = None
        self._ref_d = None                    # the distance of the reference last handed to the writer
        self.reference_step_m = 1e-3
        self._ref_meta = None                 # what the reference on disk is (written by the thread only)
        self._pending: dict | None = None
        self._pending_ref = None
        self._wake = threading.Condition()
        self._closing = False
        self.error: str | None = None         # the latest write failure, None once a write succeeds
        self.saved_unix_s: float | None = None
        self._thread = threading.Thread(target=self._writer, name="checkpoint", daemon=True)
        self._thread.start()

    def _writer(self):
        while True:
            with self._wake:
                while self._pending is None and not self._closing:
                    self._wake.wait()
                state, self._pending = self._pending, None
                ref, self._pending_ref = self._pending_ref, None
                if state is None:
                    return
            self._write(state, ref)

    def _write(self, state: dict, ref=None):
        try:
            if ref is not None:               # the image first: the state must not name one not on disk
                img, meta = ref
                self.store.save_reference(img)
                self._ref_meta = meta
            if self._ref_meta is not None:
                state = dict(state, reference=self._ref_meta)
            self.store.save(state)
        except (OSError, ValueError) as exc:
            if self.error is None:
                _log.error("cannot write checkpoint %s: %s", self.store.path, exc)
            self.error = f"cannot write checkpoint {self.store.path}: {getattr(exc, 'strerror', None) or exc}"
        else:
            if self.error:
                _log.warning("checkpoint %s written again", self.store.path)
            self.error, self.saved_unix_s = None, time.time()

    def _hand_over(self, run):
        self._last = now = self.clock()
        ref = None
        get = getattr(run, "reference", None)
        found = get() if get else None
        if found is not None and found[0] != self._ref_seq and (
                self._last_ref is None or now - self._last_ref >= self.reference_s):
            d = found[2]["distance_m"]
            if self._ref_d is None or abs(d - self._ref_d) >= self.reference_step_m:   # a stopped
                self._ref_d, ref = d, found[1:]              # crawler does not rewrite the same wall
            self._ref_seq, self._last_ref = found[0], now
        with self._wake:
            self._pending = run.state()
            if ref is not None:
                self._pending_ref = ref
            self._wake.notify()

    def write(self, frame, estimate, run):
        if self._last is None or self.clock() - self._last >= self.every_s:
            self._hand_over(run)

    def reset(self, run):
        self.store.problem = None             # the operator has seen it: a new run
        self._hand_over(run)

    def report(self, status):
        problem = self.error or self.store.problem
        status["checkpoint"] = {"path": str(self.store.path), "saved_unix_s": self.saved_unix_s,
                                "error": problem}
        if problem and status.get("last_error") is None:
            status["last_error"] = problem

    def stop(self, run):
        """The last state, written now (synchronously: the process may be about to exit)."""
        self._shut_down()
        get = getattr(run, "reference", None)
        found = get() if get else None
        self._write(run.state(), None if found is None else found[1:])    # the newest, whatever was pending

    def _shut_down(self):
        with self._wake:
            self._closing = True
            self._pending = None
            self._wake.notify()
        self._thread.join(timeout=5.0)

    def close(self):
        if not self._closing:
            self._shut_down()
