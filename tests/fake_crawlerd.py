"""An emulated crawlerd on loopback Zenoh, speaking the protocol of issue 15 as the daemon will.

A real zenoh session per crawler, listening on its own loopback port: publishers on
crawler/<name>/{distance,speed,status,observations}, the liveliness token crawler/<name>/alive, and the
queryables crawler/<name>/status and crawler/<name>/cmd/* answered from a worker thread (a channel
handler, never zenoh calls inside a callback). The state kept is what the daemon keeps with the run:
distance, footage preset and zero point, unit, direction, run id, observations.
"""

from __future__ import annotations

import json
import math
import threading
import time

import zenoh

from crawler.link import make_zenoh_config

M_PER_FT = 0.3048


def parse(query) -> dict:
    """Arguments from selector parameters (`?level=0.4`) and/or a JSON object payload."""
    args = {}
    for part in str(query.parameters or "").replace(";", "&").split("&"):
        if part:
            k, _, v = part.partition("=")
            args[k] = v
    if query.payload is not None and query.payload.to_string().strip():
        body = json.loads(query.payload.to_string())
        if not isinstance(body, dict):
            raise ValueError("the payload must be a JSON object")
        args.update(body)
    return args


class FakeCrawler:
    def __init__(self, name: str, port: int, speed_m_s: float = 0.5, refuse: tuple = ()):
        self.name, self.port, self.speed = name, port, speed_m_s
        self.refuse = set(refuse)             # verbs this crawler refuses ("busy"), to test errors
        self.handled: list[tuple[str, dict]] = []
        self.published: list[dict] = []
        self.distance_m = 0.0
        self.zero_at_m, self.preset_m = 0.0, 0.0
        self.unit, self.direction = "m", "downstream"
        self.run = 1
        self.observations: list[dict] = []
        self.seq = self.frame = 0
        self.t_s = 0.0
        self.lock = threading.Lock()
        conf = make_zenoh_config("peer", listen=[f"tcp/127.0.0.1:{port}"], multicast=False)
        self.session = zenoh.open(conf)
        key = f"crawler/{name}"
        self.pubs = {t: self.session.declare_publisher(f"{key}/{t}")
                     for t in ("distance", "speed", "status", "observations")}
        self.token = self.session.liveliness().declare_token(f"{key}/alive")
        self.queryables = [self.session.declare_queryable(f"{key}/status"),
                           self.session.declare_queryable(f"{key}/cmd/*")]
        self._stop = threading.Event()
        self._worker = threading.Thread(target=self._serve, daemon=True)
        self._worker.start()

    @property
    def run_id(self) -> str:
        return f"{self.name}-run{self.run}"

    # -- state --------------------------------------------------------------------------------------

    def footage_m(self) -> float:
        sign = 1.0 if self.direction == "downstream" else -1.0
        return round(self.preset_m + sign * (self.distance_m - self.zero_at_m), 6)

    def footage(self) -> str:
        f = self.footage_m()
        return f"{f / M_PER_FT:.1f} ft" if self.unit == "ft" else f"{f:.1f} m"

    def status(self) -> dict:
        return {"name": self.name, "source": "sim", "fps": 50.0, "frames": self.frame, "led_level": 0.5,
                "distance_m": round(self.distance_m, 6), "last_error": None, "run_id": self.run_id,
                "observations": len(self.observations)}

    def publish(self, tracking=True, bridged=False, slip=False, dt=0.02):
        """One frame: the distance advances unless tracking is lost and nothing bridges it."""
        with self.lock:
            self.frame += 1
            self.t_s = round(self.t_s + dt, 6)
            if tracking or bridged:
                self.distance_m += self.speed * dt
            self.seq += 1
            sigma = 0.002 + 0.001 * self.distance_m + (0.05 if bridged else 0.0)
            e = {"seq": self.seq, "name": self.name, "frame": self.frame, "t_s": self.t_s,
                 "distance_m": round(self.distance_m, 6), "sigma_m": round(sigma, 6),
                 "speed_m_s": self.speed if (tracking or bridged) else None, "quality": 0.9 if tracking else 0.0,
                 "tracking": tracking, "bridged": bridged, "slip": slip,
                 "source": "model" if bridged else "vision", "tracks": 40, "inliers": 36 if tracking else 0,
                 "wheel_distance_m": None, "wheel_scale": None, "footage_m": self.footage_m(),
                 "unit": self.unit, "direction": self.direction, "footage": self.footage(), "run_id": self.run_id}
            self.pubs["distance"].put(json.dumps(e))
            self.pubs["speed"].put(json.dumps({"t_s": e["t_s"], "speed_m_s": e["speed_m_s"], "seq": self.seq}))
            self.published.append(e)
            if self.frame % 10 == 0:
                self.pubs["status"].put(json.dumps(self.status()))
        return e

    # -- commands -----------------------------------------------------------------------------------

    def _serve(self):
        while not self._stop.is_set():
            idle = True
            for q in self.queryables:
                query = q.try_recv()
                if query is not None:
                    idle = False
                    self._answer(query)
            if idle:
                time.sleep(0.005)

    def _answer(self, query):
        key = str(query.key_expr)
        verb = "status" if key.endswith("/status") else key.rsplit("/", 1)[-1]
        reply_key = f"crawler/{self.name}/status" if verb == "status" else f"crawler/{self.name}/cmd/{verb}"
        try:
            args = parse(query)
            self.handled.append((verb, args))
            with self.lock:
                body = self.status() if verb == "status" else self.command(verb, args)
            query.reply(reply_key, json.dumps(dict(body, ok=True)))
        except Exception as exc:
            query.reply_err(json.dumps({"ok": False, "error": str(exc), "name": self.name}))
        finally:
            query.drop()

    def command(self, verb: str, a: dict) -> dict:
        if verb in self.refuse:
            raise RuntimeError("crawler busy: no answer within 2 s (is the camera delivering frames?)")
        if verb == "reset":
            self.distance_m = self.zero_at_m = self.preset_m = 0.0
            self.run += 1
            self.observations = []
            return {"cmd": "reset", "distance_m": 0.0, "run_id": self.run_id}
        if verb == "led":
            level = float(a["level"])
            if not 0 <= level <= 1:
                raise ValueError(f"level {level} outside 0..1")
            return {"cmd": "led", "level": level}
        if verb in ("zero", "preset"):
            if verb == "zero":
                self.preset_m = 0.0
            elif "distance_m" in a:
                self.preset_m = float(a["distance_m"])
            else:
                self.preset_m = float(a["distance"]) * (M_PER_FT if self.unit == "ft" else 1.0)
            self.zero_at_m = self.distance_m
            return {"cmd": verb, "footage_m": self.footage_m(), "footage": self.footage(), "unit": self.unit}
        if verb == "units":
            if a.get("unit") not in ("m", "ft"):
                raise ValueError(f"unit {a.get('unit')!r}: m or ft")
            self.unit = a["unit"]
            return {"cmd": "units", "unit": self.unit, "footage": self.footage()}
        if verb == "direction":
            if a.get("direction") not in ("downstream", "upstream"):
                raise ValueError(f"direction {a.get('direction')!r}: downstream or upstream")
            self.zero_at_m, self.preset_m = self.distance_m, self.footage_m()
            self.direction = a["direction"]
            return {"cmd": "direction", "direction": self.direction}
        if verb == "mark":
            return {"cmd": "mark", "observation": self.mark(a)}
        if verb == "observations":
            return {"cmd": "observations", "run_id": self.run_id, "observations": list(self.observations)}
        raise ValueError(f"unknown command {verb!r}")

    def mark(self, a: dict) -> dict:
        if not a.get("code"):
            raise ValueError("mark needs a code")
        obs = {"id": len(self.observations) + 1, "run_id": self.run_id, "t_unix": time.time(),
               "t_s": self.t_s, "distance_m": round(self.distance_m, 6),
               "footage_m": self.footage_m(), "unit": self.unit, "code": a["code"],
               "clock": int(a["clock"]) if a.get("clock") is not None else None,
               "kind": a.get("kind", "point"), "note": a.get("note")}
        assert all(math.isfinite(v) for v in (obs["distance_m"], obs["footage_m"]))
        self.observations.append(obs)
        self.pubs["observations"].put(json.dumps(obs))
        return obs

    def close(self):
        self._stop.set()
        self._worker.join(5)
        try:
            self.token.undeclare()
        except Exception:
            pass
        self.session.close()
