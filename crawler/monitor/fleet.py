"""What the monitor knows about each crawler: pure state, no I/O and no clock of its own.

Every method takes `now` (time.monotonic() seconds) from the caller, so tests drive time by hand, and
the zenoh callback threads never touch this state: the watch loop feeds it from one thread.
"""

from __future__ import annotations

from dataclasses import dataclass

SILENT_AFTER_S = 2.0
TOPICS = ("distance", "speed", "status")


@dataclass(frozen=True)
class Event:
    """A change the operator must notice: new, silent, back, lost (tracking), tracking (regained)."""

    name: str
    kind: str
    detail: str = ""


@dataclass
class Crawler:
    """The latest of everything one crawler said, and when."""

    name: str
    first_seen: float
    last_seen: float | None = None        # last message of any topic (monotonic s)
    token: bool | None = None             # liveliness token: True present, False gone, None never seen
    messages: int = 0
    seq: int | None = None
    t_s: float | None = None
    distance_m: float | None = None
    speed_m_s: float | None = None
    quality: float | None = None
    tracking: bool | None = None
    tracks: int | None = None
    inliers: int | None = None
    fps: float | None = None
    led_level: float | None = None
    source: str | None = None
    run_id: str | None = None
    last_error: str | None = None
    sim_true_distance_m: float | None = None
    sim_err_m: float | None = None        # status distance_m - sim_true_distance_m, both of one frame
    lost_since: float | None = None       # when tracking was lost (monotonic s), None while tracking
    silent: str | None = None             # why it is silent, None while it talks

    def age(self, now: float) -> float:
        """Seconds since the last message; since it was first seen while it has said nothing yet."""
        return now - (self.last_seen if self.last_seen is not None else self.first_seen)


class FleetState:
    """Ingests samples of any number of crawlers and reports the changes worth a loud mark.

    A crawler is silent when its liveliness token is gone (the daemon stopped, or zenoh lost it) or when
    nothing arrived for more than `silent_after_s`; the token rule wins, so the last status a daemon
    sends on its way out does not bring it back. It talks again on the next message (or token).
    """

    def __init__(self, silent_after_s: float = SILENT_AFTER_S):
        self.silent_after_s = silent_after_s
        self.crawlers: dict[str, Crawler] = {}

    def _get(self, name: str, now: float, why: str, events: list) -> Crawler:
        c = self.crawlers.get(name)
        if c is None:
            c = self.crawlers[name] = Crawler(name, first_seen=now)
            events.append(Event(name, "new", why))
        return c

    def ingest(self, name: str, topic: str, payload: dict, now: float) -> list[Event]:
        """One message of `topic` (distance, speed, status) from crawler `name`."""
        events: list[Event] = []
        c = self._get(name, now, f"first {topic} message", events)
        c.last_seen = now
        c.messages += 1
        get = payload.get
        if topic == "distance":
            c.seq, c.t_s = get("seq", c.seq), get("t_s", c.t_s)
            c.distance_m, c.speed_m_s = get("distance_m", c.distance_m), get("speed_m_s")
            c.quality, c.tracks, c.inliers = get("quality"), get("tracks"), get("inliers")
            if "tracking" in payload:
                self._tracking(c, bool(payload["tracking"]), now, events)
        elif topic == "speed":
            c.speed_m_s = get("speed_m_s")
        elif topic == "status":
            c.fps, c.led_level, c.source = get("fps"), get("led_level"), get("source")
            c.run_id, c.last_error = get("run_id"), get("last_error")
            c.sim_true_distance_m = truth = get("sim_true_distance_m")
            # not the latest distance: that is up to a status period newer than the truth
            d = get("distance_m")
            c.sim_err_m = d - truth if d is not None and truth is not None else None
            if c.distance_m is None:          # no estimate seen yet: the status knows the distance too
                c.distance_m = get("distance_m")
        self._silence(c, now, events)
        return events

    def liveliness(self, name: str, alive: bool, now: float) -> list[Event]:
        """The crawler's token appeared (True) or went away (False)."""
        events: list[Event] = []
        c = self._get(name, now, "liveliness token", events)
        c.token = alive
        if alive and c.last_seen is None:
            c.first_seen = now                # count the silence from the token, not from an old sighting
        self._silence(c, now, events)
        return events

    def tick(self, now: float) -> list[Event]:
        """Silence by time: call a few times a second."""
        events: list[Event] = []
        for c in self.crawlers.values():
            self._silence(c, now, events)
        return events

    def rows(self) -> list[Crawler]:
        return [self.crawlers[n] for n in sorted(self.crawlers)]

    # -- transitions --------------------------------------------------------------------------------

    def _tracking(self, c: Crawler, tracking: bool, now: float, events: list):
        was = c.tracking
        c.tracking = tracking
        if not tracking and was is not False:
            c.lost_since = now
            events.append(Event(c.name, "lost", f"tracking lost at {_fmt(c.distance_m)} m"))
        elif tracking and was is False:
            gap = now - c.lost_since if c.lost_since is not None else 0.0
            c.lost_since = None
            events.append(Event(c.name, "tracking", f"tracking again after {gap:.1f} s"))

    def _silence(self, c: Crawler, now: float, events: list):
        if c.token is False:
            reason = "liveliness token gone"
        elif c.age(now) > self.silent_after_s:
            reason = (f"no message for {c.age(now):.1f} s" if c.last_seen is not None
                      else f"token but no message for {c.age(now):.1f} s")
        else:
            reason = None
        if reason and not c.silent:
            events.append(Event(c.name, "silent", reason))
        elif c.silent and not reason:
            events.append(Event(c.name, "back", "talking again"))
        c.silent = reason


def _fmt(x, digits=3) -> str:
    return "-" if x is None else f"{x:.{digits}f}"
