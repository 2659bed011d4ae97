"""The record as MCAP (the `mcap` package): one JSON channel per crawler and topic, with JSON Schemas.

Channels are named like the daemon's keys, `crawler/<name>/<topic>` (topics distance, speed, status,
observations, and the monitor's alive and event), each with the schema of schemas.py. Messages carry
the payload exactly as received; log and publish time are the arrival at the laptop (ns since the
epoch). The file is written unchunked and flushed per message, so a crash loses nothing written:
reading stops at a half-written last record and keeps the rest.
"""

from __future__ import annotations

import io
import json
import os
import struct
from pathlib import Path

from .. import __version__
from .deps import require
from .schemas import BY_TOPIC, channel_topic, schema_bytes, split_channel_topic

MAGIC = b"\x89MCAP0\r\n"
PROFILE = ""                                  # no ROS profile: plain JSON messages


def _error(message: str):
    from .record import RecordError

    return RecordError(message)


class McapRecordWriter:
    """Appends nothing: a new MCAP file per run (MCAP cannot be appended to)."""

    format = "mcap"

    def __init__(self, path: str | Path, fsync_every_s: float = 1.0):
        writer = require("mcap.writer", "an MCAP record", "record to .csv or .jsonl instead")
        self.path = Path(path)
        self.rows = 0
        self.fsync_every_s = fsync_every_s
        self._last_sync = 0.0
        self._schemas: dict[str, int] = {}
        self._channels: dict[tuple[str, str], int] = {}
        try:
            if self.path.exists() and self.path.stat().st_size > 0:
                raise _error(f"{self.path}: exists, and an MCAP file cannot be appended to; choose a new file")
            self._f = self.path.open("wb")
        except OSError as exc:
            raise _error(f"cannot write record {str(self.path)!r}: {exc.strerror}") from None
        self._w = writer.Writer(self._f, use_chunking=False, compression=writer.CompressionType.NONE)
        self._w.start(profile=PROFILE, library=f"crawler-monitor {__version__}")
        self._f.flush()

    def _channel(self, name: str, topic: str) -> int:
        key = (name, topic)
        if key not in self._channels:
            if topic not in self._schemas:
                self._schemas[topic] = self._w.register_schema(BY_TOPIC[topic]["title"], "jsonschema",
                                                               schema_bytes(topic))
            self._channels[key] = self._w.register_channel(channel_topic(name, topic), "json",
                                                           self._schemas[topic], {"crawler": name})
        return self._channels[key]

    def write(self, t_unix: float, name: str, topic: str, data: dict):
        if topic not in BY_TOPIC:
            return
        t_ns = int(round(t_unix * 1e9))
        self._w.add_message(self._channel(name, topic), log_time=t_ns, publish_time=t_ns,
                            data=json.dumps(data).encode(), sequence=self.rows)
        self._f.flush()             # a crash of the monitor loses nothing that was written
        self.rows += 1
        if t_unix - self._last_sync >= self.fsync_every_s:
            self._last_sync = t_unix
            os.fsync(self._f.fileno())

    def close(self):
        if not self._f.closed:
            self._w.finish()        # the summary and footer: fast seeking for readers
            self._f.flush()
            os.fsync(self._f.fileno())
            self._f.close()


def read_mcap(path: Path) -> list[dict]:
    """Flat rows {t_unix, name, topic, <payload fields>} from an MCAP record, in file order."""
    stream_reader = require("mcap.stream_reader", "reading an MCAP record")
    records = require("mcap.records", "reading an MCAP record")
    exceptions = require("mcap.exceptions", "reading an MCAP record")
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise _error(f"cannot read record {str(path)!r}: {exc.strerror}") from None
    if not data.startswith(MAGIC):
        raise _error(f"{path}: not an MCAP file (it does not start with the MCAP magic)")
    finished = data.endswith(MAGIC) and len(data) > 2 * len(MAGIC)
    channels, out = {}, []
    try:
        for rec in stream_reader.StreamReader(io.BytesIO(data), skip_magic=False).records:
            if isinstance(rec, records.Channel):
                channels[rec.id] = split_channel_topic(rec.topic)
            elif isinstance(rec, records.Message) and channels.get(rec.channel_id):
                out.append(_row(path, channels[rec.channel_id], rec))
    except (exceptions.McapError, struct.error, EOFError, ValueError, MemoryError) as exc:   # bad bytes
        if finished:                # a complete file that does not read is damaged, not a crash's tail
            raise _error(f"{path}: damaged MCAP record after {len(out)} messages ({exc!r})") from None
    return out


def _row(path: Path, name_topic: tuple[str, str], msg) -> dict:
    name, topic = name_topic
    try:
        data = json.loads(msg.data)
    except ValueError:
        raise _error(f"{path}: message {msg.sequence} on crawler/{name}/{topic} is not JSON") from None
    from .record import flat

    return flat(msg.log_time / 1e9, name, topic, data if isinstance(data, dict) else {})
