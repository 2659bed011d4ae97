"""What the monitor knows about each crawler: pure state, no I/O and no clock of its own.

Every method takes `now` (time.monotonic() seconds) from the caller, so tests drive time by hand, and
the zenoh callback threads never touch this state: the watch loop feeds it from one thread.
"""

from __future__ import annotations

from dataclasses import dataclass, field

SILENT_AFTER_S = 2.0
TOPICS = ("distance", "speed", "status", "observations")
from ..inspection import footage_text  # noqa: F401  (the view and the report use it from here)


@dataclass(frozen=True)
class Event:
    """A change the operator must notice: new, silent, back, lost, tracking, bridged, slip, mark."""

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
    sigma_m: float | None = None          # 1-sigma uncertainty of distance_m
    speed_m_s: float | None = None
    quality: float | None = None
    tracking: bool | None = None
    bridged: bool = False                 # the distance is carried by a motion model, not measured
    slip: bool = False                    # the wheel slips against the vision estimate
    basis: str | None = None              # distance.source: vision | fused | wheel | model
    wheel_distance_m: float | None = None
    unmeasured_s: float = 0.0             # seconds of the run whose distance is not in distance_m (a restart)
    footage_m: float | None = None        # the footage counter: preset + distance since zero
    unit: str | None = None               # m | ft
    direction: str | None = None          # downstream | upstream
    footage: str | None = None            # as the overlay shows it, "12.4 m"
    tracks: int | None = None
    inliers: int | None = None
    fps: float | None = None
    led_level: float | None = None
    source: str | None = None             # status.source: camera | sim | replay | replay-fallback
    run_id: str | None = None
    last_error: str | None = None
    observation_count: int | None = None  # status.observations: how many the daemon holds for the run
    observations: dict = field(default_factory=dict)    # id -> observation of the current run
    sim_true_distance_m: float | None = None
    sim_err_m: float | None = None        # status distance_m - sim_true_distance_m, both of one frame
    lost_since: float | None = None       # when tracking was lost (monotonic s), None while tracking
    silent: str | None = None             # why it is silent, None while it talks

    def age(self, now: float) -> float:
        """Seconds since the last message; since it was first seen while it has said nothing yet."""
        return now - (self.last_seen if self.last_seen is not None else self.first_seen)

    def missing_observations(self) -> bool:
        """The daemon holds more observations of this run than the monitor has seen (it joined late)."""
        return self.observation_count is not None and self.observation_count > len(self.observations)

    def latest_observations(self, n: int) -> list[dict]:
        return sorted(self.observations.values(), key=lambda o: (o.get("t_unix") or 0, str(o.get("id"))))[-n:]


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
        """One message of `topic` (distance, speed, status, observations) from crawler `name`."""
        events: list[Event] = []
        c = self._get(name, now, f"first {topic} message", events)
        c.last_seen = now
        c.messages += 1
        if topic == "distance":
            self._distance(c, payload, now, events)
        elif topic == "speed":
            c.speed_m_s = payload.get("speed_m_s")
        elif topic == "status":
            self._status(c, payload)
        elif topic == "observations":
            self.observation(name, payload, events)
        self._silence(c, now, events)
        return events

    def observation(self, name: str, obs: dict, events: list | None = None) -> bool:
        """One observation (published, in a mark reply, or from the run's list); False if known already."""
        c = self.crawlers.get(name)
        if c is None or obs.get("id") is None:
            return False
        self._new_run(c, obs.get("run_id"))
        if obs["id"] in c.observations:
            return False
        c.observations[obs["id"]] = obs
        if events is not None:
            events.append(Event(name, "mark", observation_text(obs)))
        return True

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

    # -- topics -------------------------------------------------------------------------------------

    def _distance(self, c: Crawler, p: dict, now: float, events: list):
        get = p.get
        c.seq, c.t_s = get("seq", c.seq), get("t_s", c.t_s)
        c.distance_m, c.speed_m_s = get("distance_m", c.distance_m), get("speed_m_s")
        c.sigma_m, c.basis = get("sigma_m"), get("source", c.basis)
        c.quality, c.tracks, c.inliers = get("quality"), get("tracks"), get("inliers")
        c.wheel_distance_m = get("wheel_distance_m")
        c.unmeasured_s = get("unmeasured_s") or 0.0
        c.footage_m, c.footage = get("footage_m", c.footage_m), get("footage", c.footage)
        c.unit, c.direction = get("unit", c.unit), get("direction", c.direction)
        self._new_run(c, get("run_id"))
        if "tracking" in p:
            self._tracking(c, bool(p["tracking"]), now, events)
        bridged, slip = bool(get("bridged", False)), bool(get("slip", False))
        if bridged and not c.bridged:
            by = "the wheel" if c.basis == "wheel" else "the motion model"
            events.append(Event(c.name, "bridged", f"camera blind: distance carried by {by} from "
                                                   f"{_fmt(c.distance_m)} m"))
        if slip and not c.slip:
            events.append(Event(c.name, "slip", f"wheel slipping at {_fmt(c.distance_m)} m"))
        c.bridged, c.slip = bridged, slip

    def _status(self, c: Crawler, p: dict):
        get = p.get
        c.fps, c.led_level, c.source = get("fps"), get("led_level"), get("source")
        self._new_run(c, get("run_id"))
        c.last_error = get("last_error")
        c.observation_count = get("observations", c.observation_count)
        c.sim_true_distance_m = truth = get("sim_true_distance_m")
        # not the latest distance: that is up to a status period newer than the truth
        d = get("distance_m")
        c.sim_err_m = d - truth if d is not None and truth is not None else None
        if c.distance_m is None:              # no estimate seen yet: the status knows the distance too
            c.distance_m = d

    @staticmethod
    def _new_run(c: Crawler, run_id):
        """A reset starts a new run: its observations start again."""
        if run_id is not None and run_id != c.run_id:
            if c.run_id is not None:
                c.observations = {}
                c.observation_count = None
            c.run_id = run_id

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


def observation_text(o: dict) -> str:
    """`#3 FL @3 start 12.4 m "crack at joint"`: one line per observation for events and the view."""
    parts = [f"#{o.get('id')}", str(o.get("code", "?"))]
    if o.get("clock") is not None:
        parts.append(f"@{o['clock']}")
    if o.get("kind") in ("start", "finish"):
        parts.append(o["kind"])
    parts.append(footage_text(o.get("footage_m", o.get("distance_m")), o.get("unit")))
    if o.get("note"):
        parts.append(repr(str(o["note"])))
    return " ".join(parts)


def _fmt(x, digits=3) -> str:
    return "-" if x is None else f"{x:.{digits}f}"
