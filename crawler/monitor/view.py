"""Terminal text from a FleetState: the live table for a person, plain lines for a pipe or a log.

Pure functions of (state, time) -> str, so the tests read exactly what the operator reads.
"""

from __future__ import annotations

import time

from .fleet import Crawler, Event, FleetState

# ANSI: the live view redraws in place (cursor home, clear to end of line / screen) instead of
# clearing the screen, which flickers on slow laptop terminals.
HOME, CLEAR_SCREEN, CLEAR_EOL, CLEAR_EOS = "\x1b[H", "\x1b[2J", "\x1b[K", "\x1b[J"
HIDE_CURSOR, SHOW_CURSOR = "\x1b[?25l", "\x1b[?25h"
_RED, _YELLOW, _GREEN, _BOLD, _RESET = "\x1b[1;37;41m", "\x1b[1;30;43m", "\x1b[32m", "\x1b[1m", "\x1b[0m"

HEADER = ("NAME", "DIST m", "SPEED m/s", "QUAL", "TRACKS", "FPS", "LED", "AGE s", "SOURCE", "STATE")
_RIGHT = {"DIST m", "SPEED m/s", "QUAL", "TRACKS", "FPS", "LED", "AGE s", "SIM ERR mm"}


def iso(t_unix: float) -> str:
    """Local wall time with milliseconds, the way the operator's watch reads it."""
    ms = round(t_unix * 1000)
    return time.strftime("%Y-%m-%dT%H:%M:%S", time.localtime(ms // 1000)) + f".{ms % 1000:03d}"


def num(x, digits: int) -> str:
    return "-" if x is None else f"{x:.{digits}f}"


def state_text(c: Crawler, now: float) -> tuple[str, str]:
    """The STATE cell and its severity (silent > lost > ok): the one column to glance at."""
    if c.silent:
        return f"!! SILENT: {c.silent}", "silent"
    if c.tracking is False:
        lost = now - c.lost_since if c.lost_since is not None else 0.0
        return f"!! LOST {lost:.1f} s", "lost"
    if c.last_seen is None:
        return "waiting for data", "ok"
    if c.source == "replay-fallback":
        return "!! CAMERA FAILED, replaying", "lost"
    return "ok", "ok"


def row_cells(c: Crawler, now: float, sim: bool) -> list[str]:
    tracks = "-" if c.inliers is None else f"{c.inliers}/{c.tracks if c.tracks is not None else '?'}"
    cells = [c.name, num(c.distance_m, 4), num(c.speed_m_s, 3), num(c.quality, 2), tracks,
             num(c.fps, 1), num(c.led_level, 2), f"{c.age(now):.1f}", c.source or "-", state_text(c, now)[0]]
    if sim:
        cells.insert(-1, num(None if c.sim_err_m is None else c.sim_err_m * 1000, 1))
    return cells


def render(fleet: FleetState, now: float, *, key: str = "crawler/*", t_unix: float | None = None,
           events=(), note: str = "", color: bool = False) -> str:
    """The live view: one header line, one row per crawler, its last errors, the recent events.

    `events` are (t_unix, Event) pairs, newest last; `note` is a free line (recording, duration).
    """
    rows = fleet.rows()
    sim = any(c.sim_true_distance_m is not None for c in rows)
    header = list(HEADER)
    if sim:
        header.insert(-1, "SIM ERR mm")
    table = [header] + [row_cells(c, now, sim) for c in rows]
    widths = [max(len(r[i]) for r in table) for i in range(len(header) - 1)]

    def line(cells, severity=None):
        out = [cell.rjust(w) if header[i] in _RIGHT else cell.ljust(w)
               for i, (cell, w) in enumerate(zip(cells, widths))]
        state = cells[-1]
        if color and severity:
            state = {"silent": _RED, "lost": _YELLOW, "ok": _GREEN}[severity] + state + _RESET
        return "  ".join(out + [state])

    stamp = time.strftime("%H:%M:%S", time.localtime(t_unix if t_unix is not None else time.time()))
    silent = sum(1 for c in rows if c.silent)
    lost = sum(1 for c in rows if not c.silent and c.tracking is False)
    title = f"crawler-monitor  {key}  {len(rows)} crawler{'s' if len(rows) != 1 else ''}  {stamp}"
    if silent or lost:
        title += f"  !! {silent} silent, {lost} lost"
    lines = [(_BOLD + title + _RESET) if color else title, ""]
    if not rows:
        lines.append(f"waiting for crawlers on {key} ... (none heard yet)")
    else:
        lines.append(line(header))
        lines += [line(cells, state_text(c, now)[1]) for c, cells in zip(rows, table[1:])]
    errors = [f"{c.name}: last error: {c.last_error}" for c in rows if c.last_error]
    if errors:
        lines += [""] + errors
    if events:
        lines += ["", "recent:"] + [f"  {time.strftime('%H:%M:%S', time.localtime(t))}  {event_text(e)}"
                                    for t, e in events]
    if note:
        lines += ["", note]
    return "\n".join(lines) + "\n"


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
    "distance": ("seq", "t_s", "distance_m", "speed_m_s", "quality", "tracking", "inliers", "tracks"),
    "status": ("source", "fps", "frames", "tracking", "distance_m", "led_level", "uptime_s", "last_error",
               "run_id", "sim_true_distance_m"),
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
