"""The fleet live in Foxglove: a Foxglove WebSocket server (foxglove-sdk) fed by the watch loop.

Each crawler's topics become JSON channels named like the daemon's keys (`crawler/<name>/distance`,
`speed`, `status`, `observations`, and the monitor's `alive` and `event`), advertised with the JSON
Schemas of schemas.py as the first message of each arrives. The server has its own foxglove Context,
so nothing else in the process logs into it. Open it in Foxglove: "Open connection", Foxglove
WebSocket, ws://HOST:PORT.
"""

from __future__ import annotations

import json

from .deps import require
from .schemas import BY_TOPIC, channel_topic

DEFAULT_PORT = 8765


class FoxgloveSink:
    """write(t_unix, name, topic, data) like a record, but to every connected Foxglove client."""

    def __init__(self, host: str = "127.0.0.1", port: int = DEFAULT_PORT):
        foxglove = require("foxglove", "--foxglove", "the watch runs without it")
        self._foxglove = foxglove
        self.context = foxglove.Context()
        try:
            self.server = foxglove.start_server(name="crawler-monitor", host=host, port=port,
                                                context=self.context)
        except Exception as exc:         # the port is taken, the host is not this machine's
            from ..errors import CrawlerError

            raise CrawlerError(f"--foxglove on {host}:{port}: cannot start the WebSocket server: {exc} "
                               "(another program on that port? try --foxglove-port)") from None
        self.port = self.server.port
        self.host = host
        self._channels = {}
        self.rows = 0

    @property
    def url(self) -> str:
        return f"ws://{self.host}:{self.port}"

    def _channel(self, name: str, topic: str):
        key = (name, topic)
        if key not in self._channels:
            self._channels[key] = self._foxglove.Channel(channel_topic(name, topic), schema=BY_TOPIC[topic],
                                                         context=self.context, metadata={"crawler": name})
        return self._channels[key]

    def write(self, t_unix: float, name: str, topic: str, data: dict):
        if topic not in BY_TOPIC:
            return
        self._channel(name, topic).log(json.dumps(data).encode(), log_time=int(round(t_unix * 1e9)))
        self.rows += 1

    def close(self):
        for ch in self._channels.values():
            ch.close()
        self._channels = {}
        self.server.stop()
