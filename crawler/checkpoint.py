"""The run's distance on disk, so a restarted daemon resumes instead of starting from zero.

Written atomically (temporary file, fsync, rename): a power cut leaves the old or the new file, never
half of one.
"""

from __future__ import annotations

import json
import logging
import os
import time
import uuid
from pathlib import Path

_log = logging.getLogger(__name__)


class Checkpoint:
    def __init__(self, directory: str | Path, every_s: float = 1.0, clock=time.monotonic):
        self.path = Path(directory) / "checkpoint.json"
        self.every_s = every_s
        self.clock = clock
        self._last = None
        self.run_id = uuid.uuid4().hex[:12]

    def load(self) -> dict | None:
        """The saved run, or None if there is none (or it is unreadable: logged, then ignored)."""
        try:
            data = json.loads(self.path.read_text())
            distance = float(data["distance_m"])
            self.run_id = str(data["run_id"])
        except FileNotFoundError:
            return None
        except (OSError, ValueError, KeyError, TypeError) as exc:
            _log.warning("checkpoint %s unreadable (%s); starting a new run from 0 m", self.path, exc)
            return None
        data["distance_m"] = distance
        return data

    def new_run(self):
        self.run_id = uuid.uuid4().hex[:12]

    def maybe_save(self, state: dict):
        now = self.clock()
        if self._last is None or now - self._last >= self.every_s:
            self.save(state)

    def save(self, state: dict):
        self._last = self.clock()
        data = dict(state, run_id=self.run_id, saved_unix_s=round(time.time(), 3))
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
