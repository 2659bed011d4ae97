"""The inspection side of a run: the footage counter and the coded observations. Pure: no I/O.

Inspection reports (NASSCO PACP, EN 13508-2) code each observation with its distance from the start
manhole, the video time, a clock position and, for continuous defects, a start and a finish; the
footage counter is zeroed at the start manhole or preset to a chainage, shown in metres or feet to a
tenth. The counter counts the crawler's own travel from where it was zeroed (reverse counts back);
the survey direction (downstream or upstream, relative to the flow) is recorded with the run, it
does not change the sign. The daemon keeps all of this with the run (checkpoint), carries it in
every distance message, and the laptop's crawler-monitor checks its arguments with the same
functions before sending.
"""

from __future__ import annotations

import math
import re
import time
from dataclasses import asdict, dataclass, field

M_PER_FT = 0.3048
UNITS = ("m", "ft")
DIRECTIONS = ("downstream", "upstream")
KINDS = ("point", "start", "finish")
CODE_RE = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.+-]{0,15}$")
NOTE_MAX = 200
MAX_FOOTAGE_M = 100_000.0


class BadArgument(ValueError):
    """An inspection command's argument is malformed; the message says what would do."""


def footage_text(footage_m: float | None, unit: str | None) -> str:
    """The footage as an inspection overlay shows it: metres or feet to a tenth."""
    if footage_m is None:
        return "-"
    if unit == "ft":
        return f"{footage_m / M_PER_FT:.1f} ft"
    return f"{footage_m:.1f} m"


def distance_arg(text) -> float:
    if isinstance(text, bool):
        raise BadArgument(f"{text!r} is not a distance (a number like 12.40)")
    try:
        x = float(text)
    except (TypeError, ValueError):
        raise BadArgument(f"{text!r} is not a distance (a number like 12.40)") from None
    if not math.isfinite(x) or abs(x) > MAX_FOOTAGE_M:
        raise BadArgument(f"{text!r} is not a plausible distance (|d| <= {MAX_FOOTAGE_M:g})")
    return x


def code_arg(text) -> str:
    if not isinstance(text, str) or not CODE_RE.match(text):
        raise BadArgument(f"observation code {text!r}: 1 to 16 letters, digits, _ . + -, starting with a "
                          "letter or digit (e.g. FL, BAB, TFA)")
    return text


def clock_arg(text) -> int:
    if isinstance(text, bool):
        raise BadArgument(f"clock {text!r} is not a whole hour 1..12")
    try:
        clock = int(str(text).lstrip("@"))
    except ValueError:
        raise BadArgument(f"clock {text!r} is not a whole hour 1..12") from None
    if not 1 <= clock <= 12:
        raise BadArgument(f"clock {clock} is outside 1..12 (12 is the crown, 6 the invert)")
    return clock


def note_arg(text) -> str:
    if not isinstance(text, str) or len(text) > NOTE_MAX or any(ord(ch) < 32 for ch in text):
        raise BadArgument(f"note {str(text)[:40]!r}: at most {NOTE_MAX} characters, no control characters")
    return text


def choice_arg(name: str, value, choices) -> str:
    if value not in choices:
        raise BadArgument(f"{name} {value!r} must be one of {', '.join(choices)}")
    return value


@dataclass
class Inspection:
    """The footage counter and the observations of one run."""

    unit: str = "m"
    direction: str = "downstream"
    preset_m: float = 0.0             # the footage at the zero point
    zero_at_m: float = 0.0            # the crawler's distance when the counter was zeroed or preset
    observations: list = field(default_factory=list)

    def footage_m(self, distance_m: float) -> float:
        return self.preset_m + (distance_m - self.zero_at_m)

    def fields(self, distance_m: float) -> dict:
        """What every distance message carries of the inspection."""
        f = self.footage_m(distance_m)
        return {"footage_m": round(f, 6), "footage": footage_text(f, self.unit), "unit": self.unit,
                "direction": self.direction}

    def new_run(self):
        """An operator reset: the counter from 0, no observations (the old run's stay in its log)."""
        self.preset_m = self.zero_at_m = 0.0
        self.observations = []

    def command(self, verb: str, args: dict, distance_m: float, t_s: float, run_id: str):
        """(reply, observation or None) for zero, preset, units, direction, mark, observations."""
        if verb in ("zero", "preset"):
            if verb == "zero":
                self.preset_m = 0.0
            elif "distance_m" in args:
                self.preset_m = distance_arg(args["distance_m"])
            else:
                if "distance" not in args:
                    raise BadArgument("preset needs distance (in the current unit) or distance_m")
                self.preset_m = distance_arg(args["distance"]) * (M_PER_FT if self.unit == "ft" else 1.0)
            self.zero_at_m = distance_m
            return {"cmd": verb, **self.fields(distance_m)}, None
        if verb == "units":
            self.unit = choice_arg("unit", args.get("unit"), UNITS)
            return {"cmd": verb, **self.fields(distance_m)}, None
        if verb == "direction":
            self.direction = choice_arg("direction", args.get("direction"), DIRECTIONS)
            return {"cmd": verb, **self.fields(distance_m)}, None
        if verb == "mark":
            obs = self._observation(args, distance_m, t_s, run_id)
            return {"cmd": verb, "observation": obs}, obs
        if verb == "observations":
            return {"cmd": verb, "run_id": run_id, "observations": list(self.observations)}, None
        raise BadArgument(f"unknown command {verb!r}")

    def _observation(self, args: dict, distance_m: float, t_s: float, run_id: str) -> dict:
        obs = {"id": len(self.observations) + 1, "run_id": run_id, "t_unix": round(time.time(), 3),
               "t_s": round(t_s, 6), "distance_m": round(distance_m, 6),
               "footage_m": round(self.footage_m(distance_m), 6), "unit": self.unit,
               "code": code_arg(args.get("code")),
               "clock": clock_arg(args["clock"]) if args.get("clock") not in (None, "") else None,
               "kind": choice_arg("kind", args.get("kind", "point"), KINDS),
               "note": note_arg(args["note"]) if args.get("note") else None}
        self.observations.append(obs)
        return obs

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> "Inspection":
        """Back from a checkpoint, every field checked (ValueError names the bad one)."""
        ins = cls(unit=choice_arg("unit", d.get("unit", "m"), UNITS),
                  direction=choice_arg("direction", d.get("direction", "downstream"), DIRECTIONS),
                  preset_m=distance_arg(d.get("preset_m", 0.0)), zero_at_m=distance_arg(d.get("zero_at_m", 0.0)))
        obs = d.get("observations", [])
        if not isinstance(obs, list) or not all(isinstance(o, dict) and "code" in o for o in obs):
            raise BadArgument("observations must be a list of observations")
        ins.observations = obs
        return ins
