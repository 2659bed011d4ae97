"""The run's distance on disk, so a restarted daemon resumes instead of starting from zero.

Written atomically (temporary file, fsync, rename): a power cut leaves the old or the new file, never
half of one.
"""

from __future__ import annotations

import json
import logging
import os
import time
from pathlib import Path

from .ports import Output

_log = logging.getLogger(__name__)


class Checkpoint:
    """The state file in the state directory: load once at start, save as the run goes."""

    def __init__(self, directory: str | Path):
        self.path = Path(directory) / "checkpoint.json"

    def load(self) -> dict | None:
        """The saved run ({distance_m, run_id, ...}), or None if there is none (or it is unreadable:
        logged, then ignored)."""
        try:
            data = json.loads(self.path.read_text())
            data["distance_m"] = float(data["distance_m"])
            data["run_id"] = str(data["run_id"])
        except FileNotFoundError:
            return None
        except (OSError, ValueError, KeyError, TypeError) as exc:
            _log.warning("checkpoint %s unreadable (%s); starting a new run from 0 m", self.path, exc)
            return None
        return data

    def save(self, state: dict):
        data = dict(state, saved_unix_s=round(time.time(), 3))
        tmp = self.path.with_suffix(".tmp")
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            with open(tmp, "w") as f:
                json.dump(data, f)
                f.flush()
                os.fsync(f.fileno())
            os.replace(tmp, self.path)
        except OSError as exc:
            _log.warning("cannot write checkpoint %s: %s", self.path, exc)


class CheckpointOutput(Output):
    """Saves the run's state every `every_s`, at once on a reset, and when measurement stops."""

    def __init__(self, store: Checkpoint, every_s: float = 1.0, clock=time.monotonic):
        self.store = store
        self.every_s = every_s
        self.clock = clock
        self._last: float | None = None

    def _save(self, run):
        self._last = self.clock()
        self.store.save(run.state())

    def write(self, frame, estimate, run):
        if self._last is None or self.clock() - self._last >= self.every_s:
            self._save(run)

    def reset(self, run):
        self._save(run)

    def stop(self, run):
        self._save(run)
