"""The Zenoh glue: a session built like crawlerd's, subscriptions that only enqueue, commands and queries.

Callbacks run on zenoh's own (non-daemon) threads; they timestamp the sample and put it on a queue,
nothing else, so all state lives in the watch loop's thread. Whoever opens a session closes it in a
`finally` (or a `with`): an open session keeps the interpreter from exiting.

Keys (docs/topics.md): the daemon publishes `crawler/<name>/{distance,speed,status,observations}` and
holds the token `crawler/<name>/alive`; it answers a GET on `crawler/<name>/status` and commands on
`crawler/<name>/cmd/<verb>` (arguments as a JSON object payload).
"""

from __future__ import annotations

import json
import queue
import re
import time
from dataclasses import dataclass

from ..errors import CrawlerError
from ..zenoh_config import make_zenoh_config
from .fleet import TOPICS

NAME_RE = re.compile(r"^[A-Za-z0-9_-]+$")
VERBS = ("reset", "led", "zero", "preset", "units", "direction", "mark", "observations")


class NoAnswer(CrawlerError, TimeoutError):
    """No crawler answered a command or query in time."""


class DaemonError(CrawlerError, RuntimeError):
    """The crawler answered a command with an error."""


@dataclass(frozen=True)
class Received:
    """One sample off the network: wall and monotonic time of arrival, who, what, the payload."""

    t_unix: float
    t_mono: float
    name: str
    topic: str               # distance | speed | status | observations | alive | reply
    payload: object          # raw JSON bytes; `alive`: True (token PUT) / False (DELETE); `reply`: a dict


def open_session(args):
    """zenoh.open() with the crawlerd flags; BadConfig for bad flags, CrawlerError if zenoh refuses."""
    import zenoh

    conf = make_zenoh_config(args.zenoh_mode, args.listen, args.connect, args.zenoh_config,
                             multicast=not args.no_multicast)
    try:
        return zenoh.open(conf)
    except zenoh.ZError as exc:
        raise CrawlerError(f"cannot open a zenoh session ({args.zenoh_mode}, listen={args.listen}, "
                           f"connect={args.connect}): {exc}") from None


def name_of(key_expr) -> str:
    """`crawler/<name>/<topic...>` -> name."""
    parts = str(key_expr).split("/")
    return parts[1] if len(parts) > 2 else str(key_expr)


class Feed:
    """Subscribes to every topic of `name` (or `*`) and to its liveliness token."""

    def __init__(self, session, name: str = "*", maxsize: int = 100_000):
        self.queue: queue.Queue[Received] = queue.Queue(maxsize)
        self.dropped = 0
        self._decls = [session.declare_subscriber(f"crawler/{name}/{topic}", self._sample_cb(topic))
                       for topic in TOPICS]
        self._decls.append(session.liveliness().declare_subscriber(f"crawler/{name}/alive", self._on_token,
                                                                   history=True))

    def put(self, item: Received):
        """Also used by the command worker threads: their replies join the same stream."""
        try:
            self.queue.put_nowait(item)
        except queue.Full:                  # the loop is stuck: drop rather than block zenoh's rx thread
            self.dropped += 1

    def _sample_cb(self, topic: str):
        def on_sample(sample):
            self.put(Received(time.time(), time.monotonic(), name_of(sample.key_expr), topic,
                              sample.payload.to_bytes()))
        return on_sample

    def _on_token(self, sample):
        import zenoh

        alive = sample.kind == zenoh.SampleKind.PUT
        self.put(Received(time.time(), time.monotonic(), name_of(sample.key_expr), "alive", alive))

    def close(self):
        for d in self._decls:
            try:
                d.undeclare()
            except Exception:               # already gone with the session
                pass
        self._decls = []


def command_key(name: str, verb: str) -> str:
    return f"crawler/{name}/cmd/{verb}"


def command(session, name: str, verb: str, args: dict | None, timeout_s: float) -> list[tuple[str, dict]]:
    """One command to `crawler/<name>/cmd/<verb>`; [(crawler, reply dict with "ok" True or False)]."""
    return query(session, command_key(name, verb), name, args, timeout_s)


def status(session, name: str, timeout_s: float) -> list[tuple[str, dict]]:
    """The status of `name` (or of every crawler, `*`) through the queryable beside its publisher."""
    return query(session, f"crawler/{name}/status", name, None, timeout_s)


def query(session, key: str, name: str, args: dict | None, timeout_s: float) -> list[tuple[str, dict]]:
    """GET `key` with `args` as a JSON payload; [(crawler name or '?', reply dict)].

    A query sent right after the session opened may find no route to the queryable yet (declarations
    arrive asynchronously), so an empty answer that came back early is retried until the timeout. A
    query that did reach a daemon is never repeated: `reset` must not run twice.
    """
    import zenoh

    payload = json.dumps(args) if args else None
    deadline = time.monotonic() + timeout_s
    while True:
        remaining = deadline - time.monotonic()
        if remaining <= 0:
            return []
        replies = []
        # no consolidation: with `*` every crawler replies on its own key, but keep all replies anyway
        for reply in session.get(key, timeout=remaining, payload=payload,
                                 consolidation=zenoh.ConsolidationMode.NONE):
            if reply.ok is not None:
                body = _decode(reply.ok.payload, True)
                replies.append((_replier(name, str(reply.ok.key_expr), body), body))
            else:
                body = _decode(reply.err.payload, False)
                replies.append((_replier(name, "", body), body))
        if replies:
            return replies
        time.sleep(min(0.1, max(0.0, deadline - time.monotonic())))


def _replier(asked: str, key: str, body: dict) -> str:
    """Who answered: the name asked for, else a concrete reply key, else the body's name."""
    if asked != "*":
        return asked
    name = name_of(key) if key else "*"
    if name != "*":
        return name
    return str(body.get("name") or "?")


def _decode(payload, ok: bool) -> dict:
    text = payload.to_string() if payload is not None else ""
    try:
        body = json.loads(text)
    except ValueError:
        body = None
    if not isinstance(body, dict):
        body = {"ok": ok, ("reply" if ok else "error"): text}
    body.setdefault("ok", ok)
    if not ok:
        body["ok"] = False
    return body
