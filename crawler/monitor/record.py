"""The monitor's record: every message it received, one line (or MCAP message) each, flushed as written.

Three formats, chosen by the file's suffix:
  .csv    one row per message, the fixed COLUMNS below (a field a topic does not carry is empty),
          booleans as 1/0, so a spreadsheet opens it as is
  .jsonl  {"time", "t_unix", "name", "topic", "data"}: `data` is the payload exactly as received
  .mcap   MCAP with a JSON Schema per topic (mcap_record.py), for Foxglove and the robotics tools

Topics: distance, speed, status, observations (the daemon's payloads), alive (liveliness: data
{"alive": bool}) and event (the monitor's own marks: data {"event": "silent"|"back"|..., "detail"}).
A CSV or JSONL file that exists is appended to (a restarted monitor must not wipe the record of the
morning); `t_unix` keeps the runs apart. An observation's own `t_unix` (when the daemon stamped it)
is read back as `observed_t_unix`, since `t_unix` is always the arrival at the laptop.
"""

from __future__ import annotations

import csv
import io
import json
import math
import os
from pathlib import Path

from ..errors import CrawlerError
from .view import iso

SUFFIXES = (".csv", ".jsonl", ".mcap")
COLUMNS = ("time", "t_unix", "name", "topic",
           "seq", "frame", "t_s", "distance_m", "sigma_m", "speed_m_s", "quality", "tracking", "bridged", "slip",
           "tracks", "inliers", "lateral_m", "wheel_distance_m", "wheel_scale", "footage_m", "unit", "direction",
           "footage", "fps", "frames", "uptime_s", "led_level", "source", "run_id", "last_error", "observations",
           "sim_true_distance_m", "id", "observed_t_unix", "code", "clock", "kind", "note",
           "alive", "event", "detail")
_PAYLOAD_COLUMNS = COLUMNS[4:]
_BOOL = {"tracking", "alive", "bridged", "slip"}
_TEXT = {"time", "name", "topic", "source", "run_id", "last_error", "event", "detail", "unit", "direction",
         "footage", "code", "kind", "note", "id"}


class RecordError(CrawlerError, ValueError):
    """A record file that cannot be written or read back; the message names the file (and line)."""


def record_format(path: str | Path) -> str:
    suffix = Path(path).suffix.lower()
    if suffix not in SUFFIXES:
        raise RecordError(f"record file {str(path)!r}: the suffix must be .csv, .jsonl or .mcap (it picks the "
                          "format)")
    return suffix[1:]


def open_record(path: str | Path):
    """The writer for `path`'s format: RecordWriter (CSV, JSONL) or McapRecordWriter."""
    if record_format(path) == "mcap":
        from .mcap_record import McapRecordWriter

        return McapRecordWriter(path)
    return RecordWriter(path)


def flat(t_unix: float, name: str, topic: str, data: dict) -> dict:
    """A message as one flat row {t_unix, name, topic, <payload fields>}, as read_records returns it."""
    row = dict(data)
    if topic == "observations" and "t_unix" in row:
        row["observed_t_unix"] = row.pop("t_unix")
    row.update(t_unix=t_unix, name=name, topic=topic)
    return row


class RecordWriter:
    """Appends rows to a CSV or JSONL record; each row is flushed, and fsync'd about once a second."""

    def __init__(self, path: str | Path, fsync_every_s: float = 1.0):
        self.path = Path(path)
        self.format = record_format(self.path)
        self.rows = 0
        self.fsync_every_s = fsync_every_s
        self._last_sync = 0.0
        try:
            new = not self.path.exists() or self.path.stat().st_size == 0
            if not new and self.format == "csv":
                with self.path.open(encoding="utf-8", errors="replace") as f:
                    first = f.readline().strip()
                if first != ",".join(COLUMNS):
                    raise RecordError(f"{self.path}: exists with other columns; choose a new file to record to")
            self._f = self.path.open("a", encoding="utf-8", newline="")
        except OSError as exc:
            raise RecordError(f"cannot write record {str(self.path)!r}: {exc.strerror}") from None
        if self.format == "csv":
            self._csv = csv.writer(self._f, lineterminator="\n")
            if new:
                self._csv.writerow(COLUMNS)
                self._f.flush()

    def write(self, t_unix: float, name: str, topic: str, data: dict):
        if self.format == "csv":
            fields = flat(t_unix, name, topic, data)
            row = {"time": iso(t_unix), "t_unix": f"{t_unix:.3f}", "name": name, "topic": topic}
            row.update((k, _cell(fields[k])) for k in _PAYLOAD_COLUMNS if k in fields)
            self._csv.writerow([row.get(k, "") for k in COLUMNS])
        else:
            self._f.write(json.dumps({"time": iso(t_unix), "t_unix": round(t_unix, 3), "name": name,
                                      "topic": topic, "data": data}) + "\n")
        self._f.flush()             # a crash of the monitor loses nothing that was written
        self.rows += 1
        if t_unix - self._last_sync >= self.fsync_every_s:   # a power cut loses at most ~1 s
            self._last_sync = t_unix
            os.fsync(self._f.fileno())

    def close(self):
        if not self._f.closed:
            self._f.flush()
            os.fsync(self._f.fileno())
            self._f.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def _cell(v) -> str:
    if v is None:
        return ""
    if isinstance(v, bool):
        return "1" if v else "0"
    if isinstance(v, (dict, list)):
        return json.dumps(v)
    return str(v)


def read_records(path: str | Path) -> list[dict]:
    """A record back as flat dicts {t_unix, name, topic, <payload fields>}; RecordError names the bad line."""
    path = Path(path)
    fmt = record_format(path)
    if not path.is_file():
        raise RecordError(f"no such record file: {str(path)!r}")
    if fmt == "mcap":
        from .mcap_record import read_mcap

        return read_mcap(path)
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise RecordError(f"cannot read record {str(path)!r}: {exc}") from None
    return _read_csv(path, text) if fmt == "csv" else _read_jsonl(path, text)


def _read_jsonl(path: Path, text: str) -> list[dict]:
    out = []
    for lineno, line in enumerate(text.splitlines(), 1):
        if not line.strip():
            continue
        try:
            obj = json.loads(line)
        except ValueError:
            if lineno == len(text.splitlines()) and not text.endswith("\n"):
                break               # the half-written last line of a crash: keep the rest
            raise RecordError(f"{path}:{lineno}: not a JSON line: {line[:60]!r}") from None
        if not isinstance(obj, dict) or not {"t_unix", "name", "topic"} <= obj.keys():
            raise RecordError(f"{path}:{lineno}: not a crawler-monitor record (needs t_unix, name, topic)")
        data = obj.get("data")
        out.append(flat(_number(obj["t_unix"], path, lineno), str(obj["name"]), str(obj["topic"]),
                        data if isinstance(data, dict) else {}))
    return out


def _read_csv(path: Path, text: str) -> list[dict]:
    reader = csv.reader(io.StringIO(text))
    header = next(reader, None)
    if header is None or not {"t_unix", "name", "topic"} <= set(header):
        raise RecordError(f"{path}:1: not a crawler-monitor CSV (the header needs t_unix, name, topic)")
    out = []
    lines = text.splitlines()
    for cells in reader:
        lineno = reader.line_num
        if not cells:
            continue
        if len(cells) != len(header):
            if lineno == len(lines) and not text.endswith("\n"):
                break               # the half-written last line of a crash
            raise RecordError(f"{path}:{lineno}: {len(cells)} cells, the header has {len(header)}")
        row = {}
        for key, cell in zip(header, cells):
            if cell == "":
                continue
            if key in _TEXT:
                row[key] = cell
            elif key in _BOOL:
                row[key] = cell in ("1", "true", "True")
            else:
                row[key] = _number(cell, path, lineno, key)
        if "t_unix" not in row:
            raise RecordError(f"{path}:{lineno}: empty t_unix")
        out.append(row)
    return out


def _number(v, path, lineno, key="t_unix") -> float:
    try:
        x = float(v)
    except (TypeError, ValueError):
        raise RecordError(f"{path}:{lineno}: {key} = {v!r} is not a number") from None
    if not math.isfinite(x) and key == "t_unix":
        raise RecordError(f"{path}:{lineno}: t_unix = {v!r} is not finite")
    return x
