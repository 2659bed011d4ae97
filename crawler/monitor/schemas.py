"""JSON Schemas of what the monitor records and serves: one per topic, shared by MCAP and Foxglove.

The payloads are the daemon's (docs/topics.md); `alive` and `event` are the monitor's own. Fields a
daemon adds later pass (additionalProperties is left open), so an older monitor still records them.
"""

from __future__ import annotations

import json

_NUM = {"type": "number"}
_NUM_OR_NULL = {"type": ["number", "null"]}
_INT = {"type": "integer"}
_STR = {"type": "string"}
_STR_OR_NULL = {"type": ["string", "null"]}
_BOOL = {"type": "boolean"}


def _object(title: str, description: str, props: dict, required=()) -> dict:
    return {"$schema": "https://json-schema.org/draft/2020-12/schema", "title": title, "type": "object",
            "description": description, "properties": props, "required": list(required)}


DISTANCE = _object("crawler.Distance", "one estimate per published frame: distance along the pipe", {
    "seq": _INT, "name": _STR, "frame": _INT, "t_s": _NUM, "distance_m": _NUM, "sigma_m": _NUM_OR_NULL,
    "speed_m_s": _NUM_OR_NULL, "tracking": _BOOL, "bridged": _BOOL, "slip": _BOOL,
    "source": {"enum": ["vision", "fused", "wheel", "model"]}, "quality": _NUM, "tracks": _INT,
    "inliers": _INT, "lateral_m": _NUM_OR_NULL, "wheel_distance_m": _NUM_OR_NULL,
    "wheel_scale": _NUM_OR_NULL, "footage_m": _NUM_OR_NULL, "unit": {"enum": ["m", "ft"]},
    "direction": {"enum": ["downstream", "upstream"]}, "footage": _STR, "run_id": _STR_OR_NULL,
}, ("distance_m",))

SPEED = _object("crawler.Speed", "the speed along the pipe, with each distance",
                {"seq": _INT, "t_s": _NUM, "speed_m_s": _NUM_OR_NULL})

STATUS = _object("crawler.Status", "the daemon's state, about once a second", {
    "name": _STR, "source": _STR, "source_detail": _STR, "fps": _NUM, "frames": _INT, "tracks": _INT,
    "tracking": _BOOL, "distance_m": _NUM, "led_level": _NUM, "uptime_s": _NUM, "last_error": _STR_OR_NULL,
    "run_id": _STR_OR_NULL, "observations": _INT, "camera": {"type": "object"},
    "sim_true_distance_m": _NUM_OR_NULL, "dropped_frames": _INT, "drop_rate": _NUM, "workers": {"type": "object"},
})

OBSERVATION = _object("crawler.Observation", "a coded observation (PACP / EN 13508-2) stamped by the daemon", {
    "id": {"type": ["integer", "string"]}, "run_id": _STR_OR_NULL, "t_unix": _NUM, "t_s": _NUM_OR_NULL,
    "distance_m": _NUM, "footage_m": _NUM_OR_NULL, "unit": {"enum": ["m", "ft"]}, "code": _STR,
    "clock": {"type": ["integer", "null"], "minimum": 1, "maximum": 12},
    "kind": {"enum": ["point", "start", "finish"]}, "note": _STR_OR_NULL,
}, ("id", "code", "distance_m"))

EVENT = _object("crawler.Event", "the monitor's loud marks: new, silent, back, lost, tracking, bridged, slip, "
                "mark", {"event": _STR, "detail": _STR}, ("event",))

ALIVE = _object("crawler.Alive", "the daemon's liveliness token appeared (true) or went (false)",
                {"alive": _BOOL}, ("alive",))

BY_TOPIC = {"distance": DISTANCE, "speed": SPEED, "status": STATUS, "observations": OBSERVATION,
            "event": EVENT, "alive": ALIVE}


def schema_bytes(topic: str) -> bytes:
    return json.dumps(BY_TOPIC[topic], separators=(",", ":")).encode()


def channel_topic(name: str, topic: str) -> str:
    """The channel name in MCAP and Foxglove: the daemon's own key, `crawler/<name>/<topic>`."""
    return f"crawler/{name}/{topic}"


def split_channel_topic(channel: str) -> tuple[str, str] | None:
    parts = channel.split("/")
    if len(parts) == 3 and parts[0] == "crawler" and parts[2] in BY_TOPIC:
        return parts[1], parts[2]
    return None
