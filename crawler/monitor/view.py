"""Terminal output from a FleetState: the live rich table for a person, plain lines for a pipe or a log.

`render()` builds a rich renderable from (state, time) and nothing else, and `render_text()` turns it
into the exact text a terminal shows, so the tests read what the operator reads. The plain lines need
no library at all.
"""

from __future__ import annotations

import io
import time

from .deps import require
from .fleet import Crawler, Event, FleetState, footage_text, observation_text

HEADER = ("NAME", "DISTANCE m", "FOOTAGE", "SPEED m/s", "QUAL", "TRACKS", "FPS", "LED", "AGE s", "SOURCE",
          "OBS", "STATE")
_RIGHT = {"DISTANCE m", "FOOTAGE", "SPEED m/s", "QUAL", "TRACKS", "FPS", "LED", "AGE s", "OBS", "SIM ERR mm"}
STYLES = {"silent": "bold white on red", "lost": "bold black on yellow", "warn": "bold black on yellow",
          "ok": "green"}
DIRECTIONS = {"downstream": "DS", "upstream": "US"}
NARROW = 130                    # below this many columns the table leaves out the tracker's details
DETAILS = ("QUAL", "TRACKS", "FPS", "LED", "AGE s", "SIM ERR mm")


def iso(t_unix: float) -> str:
    """Local wall time with milliseconds, the way the operator's watch reads it."""
    ms = round(t_unix * 1000)
    return time.strftime("%Y-%m-%dT%H:%M:%S", time.localtime(ms // 1000)) + f".{ms % 1000:03d}"


def num(x, digits: int) -> str:
    return "-" if x is None else f"{x:.{digits}f}"


def state_text(c: Crawler, now: float) -> tuple[str, str]:
    """The STATE cell and its severity (silent > lost > warn > ok): the one column to glance at."""
    if c.silent:
        return f"!! SILENT: {c.silent}", "silent"
    marks = []
    if c.tracking is False:
        lost = now - c.lost_since if c.lost_since is not None else 0.0
        marks.append(f"LOST {lost:.1f} s")
    if c.bridged:
        marks.append("BRIDGED")
    if c.slip:
        marks.append("SLIP")
    if c.source == "replay-fallback":
        marks.append("CAMERA FAILED, replaying")
    if c.unmeasured_s:
        marks.append(f"{c.unmeasured_s:.1f} s UNMEASURED (restart)")
    if marks:
        return "!! " + ", ".join(marks), ("lost" if c.tracking is False else "warn")
    if c.last_seen is None:
        return "waiting for data", "ok"
    return "ok", "ok"


def distance_cell(c: Crawler) -> str:
    """`12.3456 ±0.012`: the distance and its 1-sigma uncertainty, both in metres."""
    text = num(c.distance_m, 4)
    if c.sigma_m is not None and c.distance_m is not None:
        text += f" ±{c.sigma_m:.3f}"
    return text


def footage_cell(c: Crawler) -> str:
    """`40.7 ft US`: the counter as the overlay shows it, then the direction of the survey."""
    text = c.footage or footage_text(c.footage_m, c.unit)
    if text != "-" and c.direction in DIRECTIONS:
        text += " " + DIRECTIONS[c.direction]
    return text


def source_cell(c: Crawler) -> str:
    """What the distance rests on (vision, fused, wheel, model) and, unless a camera, the input."""
    parts = [p for p in (c.basis, None if c.source == "camera" else c.source) if p]
    return "/".join(parts) or "-"


def row_cells(c: Crawler, now: float, sim: bool) -> list[str]:
    tracks = "-" if c.inliers is None else f"{c.inliers}/{c.tracks if c.tracks is not None else '?'}"
    count = c.observation_count if c.observation_count is not None else len(c.observations)
    cells = [c.name, distance_cell(c), footage_cell(c), num(c.speed_m_s, 3), num(c.quality, 2), tracks,
             num(c.fps, 1), num(c.led_level, 2), f"{c.age(now):.1f}", source_cell(c), str(count),
             state_text(c, now)[0]]
    if sim:
        cells.insert(-1, num(None if c.sim_err_m is None else c.sim_err_m * 1000, 1))
    return cells


def title_text(fleet: FleetState, now: float, key: str, t_unix: float | None) -> str:
    rows = fleet.rows()
    stamp = time.strftime("%H:%M:%S", time.localtime(t_unix if t_unix is not None else time.time()))
    silent = sum(1 for c in rows if c.silent)
    lost = sum(1 for c in rows if not c.silent and c.tracking is False)
    title = f"crawler-monitor  {key}  {len(rows)} crawler{'s' if len(rows) != 1 else ''}  {stamp}"
    if silent or lost:
        title += f"  !! {silent} silent, {lost} lost"
    return title


def render(fleet: FleetState, now: float, *, key: str = "crawler/*", t_unix: float | None = None,
           events=(), note: str = "", prompt: str = "", width: int = 200):
    """The live view: title, one table row per crawler, last errors, observations, events, prompt.

    `events` are (t_unix, Event) pairs, newest last; `note` is a free line (recording, keys);
    `prompt` is the line being typed after the mark key; on a terminal narrower than NARROW columns
    the QUAL, TRACKS, FPS, LED, AGE and SIM ERR columns are left out, and STATE wraps rather than
    squeezing the numbers.
    """
    rich_table = require("rich.table", "the live view", "--plain prints lines without it")
    from rich import box
    from rich.console import Group
    from rich.text import Text

    rows = fleet.rows()
    sim = any(c.sim_true_distance_m is not None for c in rows)
    header = list(HEADER)
    if sim:
        header.insert(-1, "SIM ERR mm")
    keep = [i for i, h in enumerate(header) if width >= NARROW or h not in DETAILS]
    parts = [Text(title_text(fleet, now, key, t_unix), style="bold"), Text("")]
    if not rows:
        parts.append(Text(f"waiting for crawlers on {key} ... (none heard yet)"))
    else:
        table = rich_table.Table(box=box.SIMPLE_HEAD, pad_edge=False, show_edge=False, collapse_padding=True)
        cells = [[row_cells(c, now, sim)[i] for i in keep] for c in rows]
        if width < NARROW:                  # the reason a crawler is silent is in the events below
            cells = [r[:-1] + ["!! SILENT" if c.silent else r[-1]] for c, r in zip(rows, cells)]
        for j, i in enumerate(keep):
            last = j == len(keep) - 1
            table.add_column(header[i], justify="right" if header[i] in _RIGHT else "left", no_wrap=not last,
                             min_width=None if last else max(len(r[j]) for r in cells + [[header[k] for k in keep]]))
        for c, row in zip(rows, cells):
            table.add_row(*row[:-1], Text(row[-1], style=STYLES[state_text(c, now)[1]]))
        parts.append(table)
    errors = [f"{c.name}: last error: {c.last_error}" for c in rows if c.last_error]
    if errors:
        parts += [Text("")] + [Text(e, style="red") for e in errors]
    marks = [f"  {c.name} {observation_text(o)}" for c in rows for o in c.latest_observations(3)]
    if marks:
        parts += [Text(""), Text("observations:")] + [Text(m) for m in marks[-6:]]
    if events:
        parts += [Text(""), Text("recent:")] + [Text(f"  {time.strftime('%H:%M:%S', time.localtime(t))}  "
                                                     f"{event_text(e)}") for t, e in events]
    if prompt:
        parts += [Text(""), Text(prompt, style="bold reverse")]
    if note:
        parts += [Text(""), Text(note)]
    return Group(*parts)


def render_text(renderable, width: int = 160, color: bool = False) -> str:
    """What a terminal `width` columns wide shows for `renderable` (ANSI colours only with `color`)."""
    from rich.console import Console

    out = io.StringIO()
    console = Console(file=out, width=width, force_terminal=color, color_system="standard" if color else None,
                      legacy_windows=False)
    console.print(renderable)
    return out.getvalue()


def event_text(e: Event) -> str:
    return f"{e.name} {e.kind.upper()} {e.detail}".rstrip()


def plain_line(t_unix: float, name: str, topic: str, payload: dict) -> str:
    """One line per update for a pipe or a log file: `TIME NAME TOPIC key=value ...`."""
    keys = _PLAIN_KEYS.get(topic)
    fields = payload.items() if keys is None else ((k, payload.get(k)) for k in keys if k in payload)
    body = " ".join(f"{k}={_plain(v)}" for k, v in fields)
    return f"{iso(t_unix)} {name} {topic} {body}".rstrip()


def plain_event(t_unix: float, e: Event) -> str:
    return f"{iso(t_unix)} {event_text(e)}"


_PLAIN_KEYS = {
    "distance": ("seq", "t_s", "distance_m", "sigma_m", "speed_m_s", "quality", "tracking", "bridged", "slip",
                 "source", "footage", "inliers", "tracks"),
    "status": ("source", "fps", "frames", "tracking", "distance_m", "led_level", "uptime_s", "last_error",
               "run_id", "observations", "sim_true_distance_m"),
    "observations": ("id", "t_s", "distance_m", "footage_m", "unit", "code", "clock", "kind", "note"),
}


def _plain(v) -> str:
    if v is None:
        return "null"
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float):
        return f"{v:.6g}"
    s = str(v)
    return repr(s) if (" " in s or not s) else s
