"""Zenoh: the crawler's distance, speed and status out to the operator, control requests in.

Key expressions, all under `crawler/<name>/` (docs/topics.md has every payload field):
  distance  JSON per published estimate: t_s, distance_m, speed_m_s, quality, tracking, seq, ...
  speed     JSON: t_s, speed_m_s, seq
  status    JSON about once a second
  alive     liveliness token: present while the daemon runs
  control   queryable: cmd=reset | cmd=led&level=0.5 | cmd=status (selector parameters or a JSON payload)

The network is never allowed to stop measurement: if the session cannot be opened the link retries in
the background and publishing is a no-op meanwhile; once a session exists, zenoh itself reconnects to
peers that come back.
"""

from __future__ import annotations

import json
import logging
import re
import threading
import time
from concurrent.futures import Future, TimeoutError as FutureTimeout
from pathlib import Path

from .errors import BadConfig
from .ports import Output

_log = logging.getLogger(__name__)

from .zenoh_flags import ZENOH_MODES  # noqa: F401  (one list of modes)


def zenoh_message(exc) -> str:
    """zenoh's error text without the Rust source locations it appends."""
    return re.sub(r" at /\S+?:\d+\.?", "", str(exc)).strip()


def _check_ports(kind: str, endpoints) -> None:
    """zenoh parses endpoints but accepts any port for `connect` (it just never connects): refuse it."""
    for e in endpoints:
        m = re.match(r"^(tcp|udp|tls|quic|ws)/.*:(\d+)(?:[?#].*)?$", str(e))
        if m and not 0 < int(m.group(2)) < 65536:
            raise BadConfig(f"[zenoh] {kind} endpoint {e!r}: port {m.group(2)} must be 1..65535")


def make_zenoh_config(mode: str | None = "peer", listen=(), connect=(), config_file: str | None = None,
                      multicast: bool = True):
    """One place that turns flags/TOML into a zenoh.Config, naming the culprit when it fails."""
    import zenoh

    _check_ports("listen", listen)
    _check_ports("connect", connect)

    if config_file:
        path = Path(config_file)
        if not path.is_file():
            raise BadConfig(f"[zenoh] config = {config_file!r}: no such file (a zenoh JSON5 config)")
        try:
            conf = zenoh.Config.from_file(str(path))
        except Exception as exc:   # zenoh raises its own ZError
            raise BadConfig(f"[zenoh] config = {config_file!r} is not a valid zenoh config: "
                            f"{zenoh_message(exc)}") from None
    else:
        conf = zenoh.Config()
    if mode is None and not config_file:
        mode = "peer"
    try:
        if mode is not None:     # else the config file's own mode stands
            conf.insert_json5("mode", json.dumps(mode))
        if listen:
            conf.insert_json5("listen/endpoints", json.dumps(list(listen)))
        if connect:
            conf.insert_json5("connect/endpoints", json.dumps(list(connect)))
        if not multicast:
            conf.insert_json5("scouting/multicast/enabled", "false")
    except Exception as exc:
        raise BadConfig(f"zenoh endpoints listen={list(listen)} connect={list(connect)} rejected: "
                        f"{zenoh_message(exc)}; an endpoint looks like tcp/192.168.1.10:7447") from None
    return conf


class ZenohLink:
    """Publishers, liveliness token and the control queryable of one crawler."""

    def __init__(self, name: str, zenoh_config, on_command=None, retry_s: float = 2.0):
        self.name = name
        self.prefix = f"crawler/{name}"
        self._config = zenoh_config
        self._on_command = on_command
        self.retry_s = retry_s
        self.session = None
        self._pubs = {}
        self._decls = []
        self._lock = threading.Lock()
        self._closed = threading.Event()
        self._retry = None
        self.last_error = None
        self.seq = 0

    # -- life ---------------------------------------------------------------------------------------

    def open(self):
        """Try to open now; on failure keep measuring and retry in the background."""
        if not self._try_open():
            self._retry = threading.Thread(target=self._retry_loop, name="zenoh-retry", daemon=True)
            self._retry.start()
        return self

    def _try_open(self) -> bool:
        import zenoh

        try:
            session = zenoh.open(self._config)
            pubs = {k: session.declare_publisher(f"{self.prefix}/{k}") for k in ("distance", "speed", "status")}
            decls = [session.liveliness().declare_token(f"{self.prefix}/alive"),
                     session.declare_queryable(f"{self.prefix}/control", self._on_query)]
        except Exception as exc:
            if self.last_error is None:
                _log.warning("zenoh session cannot be opened (%s); measuring anyway, retrying every %.0f s",
                             exc, self.retry_s)
            self.last_error = f"zenoh: {exc}"
            return False
        with self._lock:
            if self._closed.is_set():
                session.close()
                return True
            self.session, self._pubs, self._decls = session, pubs, decls
        if self.last_error:
            _log.warning("zenoh session open after retrying")
        self.last_error = None
        return True

    def _retry_loop(self):
        while not self._closed.wait(self.retry_s):
            if self._try_open():
                return

    def close(self):
        self._closed.set()
        with self._lock:
            session, self.session = self.session, None
            self._pubs, decls, self._decls = {}, self._decls, []
        if session is not None:
            for d in decls:
                try:
                    d.undeclare()
                except Exception:
                    pass
            session.close()

    @property
    def connected(self) -> bool:
        return self.session is not None

    # -- out ----------------------------------------------------------------------------------------

    def _put(self, key: str, payload: dict):
        pub = self._pubs.get(key)
        if pub is None:
            return
        try:
            pub.put(json.dumps(payload))
        except Exception as exc:   # never let the network stop the frame loop
            self.last_error = f"zenoh put {key}: {exc}"

    def publish_estimate(self, est: dict):
        self.seq += 1
        self._put("distance", dict(est, seq=self.seq))
        self._put("speed", {"t_s": est["t_s"], "speed_m_s": est["speed_m_s"], "seq": self.seq})

    def publish_status(self, status: dict):
        self._put("status", status)

    # -- in -----------------------------------------------------------------------------------------

    def _on_query(self, query):
        """Runs on a zenoh thread: parse, hand to the frame loop, reply with its answer or an error."""
        try:
            request = parse_request(query)
            if self._on_command is None:
                raise ValueError("this crawler takes no commands")
            answer = self._on_command(request)
            # on our own key: a wildcard query (crawler/*/control) then gets one reply per crawler
            query.reply(f"{self.prefix}/control", json.dumps(dict(answer, ok=True)))
        except Exception as exc:   # a malformed request must never reach the daemon
            try:
                query.reply_err(json.dumps({"ok": False, "error": str(exc)}))
            except Exception:
                _log.debug("reply_err failed", exc_info=True)


def parse_request(query) -> dict:
    """A control request from selector parameters (`?cmd=led;level=0.3`) and/or a JSON object payload."""
    request = {}
    params = str(query.parameters or "")
    for part in params.replace(";", "&").split("&"):
        if part:
            key, _, value = part.partition("=")
            request[key.strip()] = value.strip()
    if query.payload is not None:
        raw = query.payload.to_string()
        if raw.strip():
            try:
                body = json.loads(raw)
            except ValueError:
                raise ValueError(f"payload {raw[:60]!r} is not JSON") from None
            if not isinstance(body, dict):
                raise ValueError(f"payload {raw[:60]!r} must be a JSON object")
            request.update(body)
    if "cmd" not in request:
        raise ValueError("missing cmd; use cmd=reset, cmd=led with level=0..1, or cmd=status")
    return request


class CommandQueue:
    """Hands control requests from zenoh threads to the frame loop and waits for its answer."""

    def __init__(self, timeout_s: float = 2.0):
        self.timeout_s = timeout_s
        self._items: list[tuple[dict, Future]] = []
        self._lock = threading.Lock()

    def submit(self, request: dict) -> dict:
        fut: Future = Future()
        with self._lock:
            self._items.append((request, fut))
        try:
            return fut.result(self.timeout_s)
        except FutureTimeout:
            raise RuntimeError(f"crawler busy: no answer within {self.timeout_s:g} s "
                               "(is the camera delivering frames?)") from None

    def drain(self, handle):
        """Frame loop: answer every pending request with handle(request) -> dict (or its exception)."""
        with self._lock:
            items, self._items = self._items, []
        for request, fut in items:
            try:
                fut.set_result(handle(request))
            except Exception as exc:
                fut.set_exception(exc)


class ZenohOutput(Output):
    """The link as the loop's output: estimates at most `publish_hz`, the status at `status_hz` and
    once more when measurement stops (so the operator sees the lights go out)."""

    def __init__(self, link: ZenohLink, publish_hz: float = 30.0, status_hz: float = 1.0,
                 clock=time.monotonic):
        self.link = link
        self.publish_every_s, self.status_every_s = 1.0 / publish_hz, 1.0 / status_hz
        self.clock = clock
        self._last_pub = self._last_status = -float("inf")

    def __enter__(self):
        self.link.open()
        return self

    def write(self, frame, estimate, run):
        now = self.clock()
        if now - self._last_pub >= self.publish_every_s:
            self._last_pub = now
            self.link.publish_estimate(dict(estimate.as_dict(), name=run.name))
        if now - self._last_status >= self.status_every_s:
            self._last_status = now
            self.link.publish_status(run.status())

    def report(self, status):
        if status.get("last_error") is None:
            status["last_error"] = self.link.last_error

    def stop(self, run):
        self.link.publish_status(run.status())

    def close(self):
        self.link.close()
