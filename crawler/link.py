"""Zenoh: the crawler's distance, speed and status out to the operator, commands in.

Key expressions, all under `crawler/<name>/` (docs/topics.md has every payload field):
  distance    JSON per published estimate: t_s, distance_m, speed_m_s, quality, tracking, seq, ...
  speed       JSON: t_s, speed_m_s, seq
  status      JSON about once a second; also a queryable that answers a get with the status now
  alive       liveliness token: present while the daemon runs
  cmd/<verb>  queryables: cmd/reset, cmd/led?level=0.5 (selector parameters or a JSON payload)

Commands and status have keys of their own, so an access-control list can let everyone read and
only the operator command. Queries are received on channels and answered from a worker thread (never
from inside a zenoh callback), and every query is dropped once answered, so the asker's get() ends
at once. All payloads are strict JSON with the application/json encoding.

The network is never allowed to stop measurement: if the session cannot be opened the link retries in
the background and publishing is a no-op meanwhile; once a session exists, zenoh itself reconnects to
peers that come back.
"""

from __future__ import annotations

import json
import logging
import math
import threading
import time

from .commands import CommandQueue, CommandRefused, parse_arguments
from .ports import Output
from .zenoh_config import make_zenoh_config, zenoh_message  # noqa: F401  (the monitor imports it here)

_log = logging.getLogger(__name__)
STATUS_WAIT_S = 0.5      # a status query waits this long for the loop, then gets the last status


def strict_json(payload: dict) -> str:
    """JSON without NaN/Infinity (not JSON); a non-finite number becomes null."""
    try:
        return json.dumps(payload, allow_nan=False)
    except ValueError:
        return json.dumps(_finite(payload), allow_nan=False)


def _finite(v):
    if isinstance(v, float) and not math.isfinite(v):
        return None
    if isinstance(v, dict):
        return {k: _finite(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_finite(x) for x in v]
    return v


class ZenohLink:
    """Publishers, liveliness token, the status and command queryables of one crawler."""

    def __init__(self, name: str, zenoh_config, commands: CommandQueue | None = None, retry_s: float = 2.0):
        self.name = name
        self.prefix = f"crawler/{name}"
        self._config = zenoh_config
        self.commands = commands
        self.retry_s = retry_s
        self.session = None
        self._pubs = {}
        self._decls = []
        self._workers: list[threading.Thread] = []
        self._lock = threading.Lock()
        self._closed = threading.Event()
        self._retry = None
        self.last_error = None
        self.last_status: dict | None = None
        self.seq = 0
        self._session_listeners = []

    def on_session(self, callback):
        """callback(session) once a session is open (now, or after a retry): for more declarations."""
        self._session_listeners.append(callback)
        if self.session is not None:
            callback(self.session)

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
        except Exception as exc:
            if self.last_error is None:
                _log.warning("zenoh session cannot be opened (%s); measuring anyway, retrying every %.0f s",
                             zenoh_message(exc), self.retry_s)
            self.last_error = f"zenoh: {zenoh_message(exc)}"
            return False
        try:
            json_enc = zenoh.Encoding.APPLICATION_JSON
            pubs = {k: session.declare_publisher(f"{self.prefix}/{k}", encoding=json_enc)
                    for k in ("distance", "speed", "status", "observations", "events")}
            queryables = [session.declare_queryable(f"{self.prefix}/status"),
                          session.declare_queryable(f"{self.prefix}/cmd/*")]
            decls = [session.liveliness().declare_token(f"{self.prefix}/alive"), *queryables]
        except Exception as exc:
            session.close()               # a declare that fails must not leave the port held
            self.last_error = f"zenoh: {zenoh_message(exc)}"
            _log.error("zenoh declarations failed (%s); retrying", self.last_error)
            return False
        with self._lock:
            if self._closed.is_set():
                session.close()
                return True
            recovered, self.last_error = self.last_error, None
            self.session, self._pubs, self._decls = session, pubs, decls
            self._workers = [threading.Thread(target=self._serve, args=(q,), name=f"zenoh-{i}", daemon=True)
                             for i, q in enumerate(queryables)]
            for w in self._workers:
                w.start()
        if recovered:
            _log.warning("zenoh session open after retrying")
        for callback in self._session_listeners:
            try:
                callback(session)
            except Exception as exc:
                self.last_error = f"zenoh: {zenoh_message(exc)}"
                _log.error("zenoh declarations failed: %s", self.last_error)
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
            workers, self._workers = self._workers, []
        if session is not None:
            # the liveliness token first (the operator sees us go); the queryables go with the session:
            # undeclaring one while its worker blocks in recv() aborts the process ("Already borrowed")
            try:
                decls[0].undeclare()
            except Exception:
                pass
            session.close()               # a blocked recv() now raises and the workers end
        for w in workers:
            w.join(timeout=2.0)

    @property
    def connected(self) -> bool:
        return self.session is not None

    # -- out ----------------------------------------------------------------------------------------

    def _put(self, key: str, payload: dict):
        pub = self._pubs.get(key)
        if pub is None:
            return
        try:
            pub.put(strict_json(payload))
        except Exception as exc:   # never let the network stop the frame loop
            self.last_error = f"zenoh put {key}: {exc}"

    def publish_estimate(self, est: dict):
        self.seq += 1
        self._put("distance", dict(est, seq=self.seq))
        self._put("speed", {"t_s": est["t_s"], "speed_m_s": est["speed_m_s"], "seq": self.seq})

    def publish(self, topic: str, payload: dict):
        self._put(topic, payload)

    def publish_status(self, status: dict):
        self.last_status = status
        self._put("status", status)

    # -- in -----------------------------------------------------------------------------------------

    def _serve(self, queryable):
        """A worker thread: take each query off the queryable's channel, answer it, drop it."""
        while not self._closed.is_set():
            try:
                query = queryable.recv()
            except Exception:             # undeclared or the session closed: done
                return
            try:
                self._answer(query)
            finally:
                query.drop()              # finalise now: the asker's get() ends with our reply

    def _answer(self, query):
        import zenoh

        key = str(query.key_expr)
        verb = key.rsplit("/", 1)[-1]
        try:
            payload = query.payload.to_string() if query.payload is not None else None
            args = parse_arguments(str(query.parameters or ""), payload)
            answer = self._status() if key.endswith("/status") else self._command(verb, args)
            # on our own concrete key: a wildcard query (crawler/*/...) gets one reply per crawler
            reply_key = f"{self.prefix}/status" if key.endswith("/status") else f"{self.prefix}/cmd/{verb}"
            query.reply(reply_key, strict_json(dict(answer, ok=True)), encoding=zenoh.Encoding.APPLICATION_JSON)
        except Exception as exc:          # a malformed request never reaches the daemon
            try:
                query.reply_err(strict_json({"ok": False, "error": str(exc)}),
                                encoding=zenoh.Encoding.APPLICATION_JSON)
            except Exception:
                _log.debug("reply_err failed", exc_info=True)

    def _command(self, verb: str, args: dict) -> dict:
        if self.commands is None:
            raise CommandRefused("this crawler takes no commands")
        return self.commands.submit(dict(args, cmd=verb))

    def _status(self) -> dict:
        if self.commands is not None:
            try:
                return self.commands.submit({"cmd": "status"}, timeout_s=STATUS_WAIT_S)
            except TimeoutError:
                pass
        if self.last_status is None:
            raise TimeoutError("no status yet: the crawler has not measured a frame")
        return dict(self.last_status, stale=True)


class ZenohOutput(Output):
    """The link as the loop's output: estimates at most `publish_hz`, the status at `status_hz` and
    once more when measurement stops (so the operator sees the lights go out)."""

    def __init__(self, link: ZenohLink, publish_hz: float = 30.0, status_hz: float = 1.0,
                 clock=time.monotonic, control: str = "open"):
        self.link = link
        self.control = control          # "open" or "authenticated": who may send commands
        self.publish_every_s, self.status_every_s = 1.0 / publish_hz, 1.0 / status_hz
        self.clock = clock
        self._next_pub = self._last_status = -float("inf")

    def __enter__(self):
        self.link.open()
        return self

    def write(self, frame, estimate, run):
        now = self.clock()
        if now >= self._next_pub:
            # on a schedule, not "a period since the last": 60 fps thinned to 30 Hz is every other
            # frame, not every third one whenever a frame comes a little early
            due = self._next_pub + self.publish_every_s
            self._next_pub = due if due > now else now + self.publish_every_s     # (after a stall: no burst)
            self.link.publish_estimate(run.describe(estimate))
        if now - self._last_status >= self.status_every_s:
            self._last_status = now
            self.link.publish_status(run.status())

    def report(self, status):
        status["control"] = self.control
        if status.get("last_error") is None:
            status["last_error"] = self.link.last_error

    def note(self, topic, payload):
        self.link.publish(topic, payload)

    def stop(self, run):
        self.link.publish_status(run.status())

    def close(self):
        self.link.close()
