"""The inspection report of a record: the observation table with the distance and speed plots.

Observations are listed as inspection reports list them (PACP, EN 13508-2): distance and footage,
video time, code, clock position, continuous defects with start and finish paired, remarks. Each is
counted once however often it was received (published, in a mark reply, in a late laptop's list).
observation_rows() is pure; write_report() writes one self-contained HTML file (the plot embedded as
PNG) or a CSV of the same table.
"""

from __future__ import annotations

import base64
import csv
import html
import io
import time
from pathlib import Path

from ..errors import CrawlerError
from .fleet import footage_text
from .plot import NothingToPlot, plot_figure, unique_observations

CSV_COLUMNS = ("crawler", "run_id", "id", "distance_m", "footage", "unit", "video_time_s", "video_time",
               "time", "code", "clock", "kind", "continuous", "remarks")


def video_time(t_s) -> str:
    """`0:12:03.4`: the sensor (video) time as a player shows it."""
    if t_s is None:
        return "-"
    tenths = round(float(t_s) * 10)
    h, rest = divmod(tenths, 36000)
    m, rest = divmod(rest, 600)
    return f"{h}:{m:02d}:{rest // 10:02d}.{rest % 10}"


def observation_rows(records: list[dict]) -> list[dict]:
    """The table: one row per observation, continuous start/finish paired per crawler, run and code."""
    obs = sorted(unique_observations(records).items(),
                 key=lambda kv: (kv[0][0], _stamp(kv[1]), str(kv[1].get("id"))))
    rows, open_starts, pairs = [], {}, 0
    for (name, _), o in obs:
        kind = o.get("kind") or "point"
        row = {"crawler": name, "run_id": o.get("run_id") or "", "id": o.get("id"),
               "distance_m": o.get("distance_m"), "unit": o.get("unit") or "m",
               "footage": footage_text(o.get("footage_m", o.get("distance_m")), o.get("unit")),
               "video_time_s": o.get("t_s"), "video_time": video_time(o.get("t_s")),
               "time": _local(_stamp(o)), "code": o.get("code", ""), "clock": _clock(o.get("clock")),
               "kind": kind, "continuous": "", "remarks": [str(o["note"])] if o.get("note") else [],
               "_footage_m": _number(o.get("footage_m", o.get("distance_m")))}
        key = (name, o.get("run_id"), o.get("code"))
        if kind == "start":
            pairs += 1
            row["continuous"] = f"C{pairs} start"
            open_starts.setdefault(key, []).append(row)
        elif kind == "finish":
            if open_starts.get(key):
                start = open_starts[key].pop(0)
                label = start["continuous"].split()[0]
                row["continuous"] = f"{label} finish"
                length = _length(start, row)
                start["remarks"].append(f"continuous to {row['footage']}{length}")
                row["remarks"].append(f"continuous from {start['footage']}{length}")
            else:
                row["remarks"].append("finish without a start")
        rows.append(row)
    for starts in open_starts.values():
        for row in starts:
            row["remarks"].append("no finish recorded")
    for row in rows:
        row["remarks"] = "; ".join(row["remarks"])
        del row["_footage_m"]
    return rows


def _number(v):
    return None if v is None else float(v)


def _stamp(o: dict) -> float:
    s = o.get("observed_t_unix")
    return float(s if s is not None else o["t_unix"])


def _local(t_unix: float) -> str:
    return time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(t_unix))


def _clock(c) -> str:
    return "" if c is None else str(int(float(c)))


def _length(start: dict, finish: dict) -> str:
    """The length of a continuous defect, in the footage's unit to a tenth."""
    a, b = start["_footage_m"], finish["_footage_m"]
    return "" if a is None or b is None else f" ({footage_text(abs(b - a), finish['unit'])} long)"


def write_report(records: list[dict], out: Path, title: str) -> str:
    """Write `out` (.html or .csv); the one-line summary of what it holds."""
    rows = observation_rows(records)
    try:
        if out.suffix.lower() == ".csv":
            _write_csv(rows, out)
        else:
            out.write_text(_html(records, rows, title), encoding="utf-8")
    except OSError as exc:
        raise CrawlerError(f"cannot write {str(out)!r}: {exc.strerror}") from None
    names = sorted({r["crawler"] for r in rows})
    pairs = sum(1 for r in rows if r["continuous"].endswith("finish"))
    return f"{len(rows)} observation(s) of {len(names)} crawler(s), {pairs} continuous defect(s) paired"


def _write_csv(rows: list[dict], out: Path):
    with out.open("w", encoding="utf-8", newline="") as f:
        w = csv.DictWriter(f, CSV_COLUMNS, lineterminator="\n")
        w.writeheader()
        for r in rows:
            w.writerow({k: ("" if r[k] is None else r[k]) for k in CSV_COLUMNS})


def _plot_png(records: list[dict], title: str) -> str | None:
    try:
        fig = plot_figure(records, (1100, 700), title)
    except NothingToPlot:
        return None
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=100)
    return base64.b64encode(buf.getvalue()).decode()


_STYLE = ("body{font-family:sans-serif;margin:2em;color:#222}table{border-collapse:collapse;font-size:0.9em}"
          "th,td{border:1px solid #bbb;padding:0.3em 0.6em;text-align:left}td.n{text-align:right}"
          "th{background:#eee}img{max-width:100%}")
_HEADINGS = (("crawler", "crawler", ""), ("distance_m", "distance m", "n"), ("footage", "footage", "n"),
             ("video_time", "video time", "n"), ("code", "code", ""), ("clock", "clock", "n"),
             ("continuous", "continuous", ""), ("remarks", "remarks", ""), ("time", "time", ""))


def _directions(records: list[dict]) -> dict:
    """Each crawler's survey direction as its last distance message had it."""
    out = {}
    for r in records:
        if r.get("topic") == "distance" and r.get("direction"):
            out[r.get("name")] = r["direction"]
    return out


def _html(records: list[dict], rows: list[dict], title: str) -> str:
    esc = html.escape
    head = "".join(f"<th>{esc(text)}</th>" for _, text, _ in _HEADINGS)
    body = []
    for r in rows:
        cells = []
        for key, _, cls in _HEADINGS:
            v = r[key]
            v = "" if v is None else (f"{v:.2f}" if key == "distance_m" else str(v))
            cells.append(f"<td class='{cls}'>{esc(v)}</td>" if cls else f"<td>{esc(v)}</td>")
        body.append("<tr>" + "".join(cells) + "</tr>")
    table = (f"<table><tr>{head}</tr>{''.join(body)}</table>" if rows
             else "<p>No observations in this record.</p>")
    png = _plot_png(records, title)
    plot = (f"<img alt='distance and speed over time' src='data:image/png;base64,{png}'>" if png
            else "<p>No distance messages to plot.</p>")
    span = ""
    if records:
        span = f"{_local(min(r['t_unix'] for r in records))} to {_local(max(r['t_unix'] for r in records))}"
    surveys = "; ".join(f"{name}: {d}" for name, d in sorted(_directions(records).items()))
    surveys = f"<p>Survey direction: {esc(surveys)}</p>" if surveys else ""
    return (f"<!DOCTYPE html><html><head><meta charset='utf-8'><title>{esc(title)}</title>"
            f"<style>{_STYLE}</style></head><body><h1>{esc(title)}</h1><p>{esc(span)}</p>{surveys}"
            f"<h2>Observations</h2>{table}<h2>Distance and speed</h2>{plot}</body></html>\n")
