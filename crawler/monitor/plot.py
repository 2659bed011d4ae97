"""A record as a picture (matplotlib): distance and speed over time, one colour per crawler.

The distance panel has the ±2 sigma band, the stretches the distance was carried by the wheel or
a motion model (bridged) and those it was held because tracking was lost, each shaded its own way, the observations
as markers and where a crawler went silent. series_from_records() is pure (records in, arrays out);
plot_figure() builds a matplotlib Figure with the object API (no pyplot, no global state).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import CrawlerError
from .deps import require

GAP_S = 2.0            # samples further apart than this are not joined: the crawler was silent
BRIDGED_COLOR, LOST_COLOR = "#f5a623", "#7f7f7f"
MARKERS = {"point": "v", "start": ">", "finish": "<"}


class NothingToPlot(CrawlerError, ValueError):
    """The record holds no distance messages."""


@dataclass
class Series:
    name: str
    t: np.ndarray                                  # seconds since the record's first row
    distance: np.ndarray
    sigma: np.ndarray                              # NaN where the daemon sent none
    speed: np.ndarray                              # NaN where the daemon sent null (tracking lost)
    tracking: np.ndarray
    bridged: np.ndarray
    t_sensor: np.ndarray                           # the daemon's t_s, to place observations exactly
    silent_at: list = field(default_factory=list)  # times the monitor marked it SILENT
    observations: list = field(default_factory=list)   # (t, distance_m, code, kind)

    def spans(self, flags: np.ndarray) -> list[tuple[float, float]]:
        """[start, end) of the stretches where `flags` holds; a stretch ends at the next sample without."""
        edges = np.diff(np.concatenate([[False], flags, [False]]).astype(np.int8))
        starts, ends = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
        last = len(self.t) - 1
        return [(float(self.t[a]), float(self.t[min(b, last)])) for a, b in zip(starts, ends)]

    def lost_spans(self):
        """Tracking lost and the distance held (not carried by a model)."""
        return self.spans(~self.tracking & ~self.bridged)

    def bridged_spans(self):
        return self.spans(self.bridged)


def _column(rows, key, default=math.nan) -> np.ndarray:
    return np.array([default if r.get(key) is None else float(r[key]) for r in rows], float)


def series_from_records(records: list[dict]) -> tuple[float, dict[str, Series]]:
    """(t0 = first row's unix time, name -> Series) from the distance rows of a record."""
    if not records:
        raise NothingToPlot("the record is empty")
    t0 = min(r["t_unix"] for r in records)
    by_name: dict[str, list] = {}
    for r in sorted((r for r in records if r["topic"] == "distance"), key=lambda r: r["t_unix"]):
        if r.get("distance_m") is not None:
            by_name.setdefault(r["name"], []).append(r)
    if not by_name:
        raise NothingToPlot("the record has no distance messages")
    out = {}
    for name, rows in by_name.items():
        out[name] = Series(name, _column(rows, "t_unix") - t0, _column(rows, "distance_m"),
                           _column(rows, "sigma_m"), _column(rows, "speed_m_s"),
                           np.array([bool(r.get("tracking", True)) for r in rows]),
                           np.array([bool(r.get("bridged", False)) for r in rows]), _column(rows, "t_s"))
    for r in records:
        s = out.get(r["name"])
        if s is None:
            continue
        if r["topic"] == "event" and r.get("event") == "silent":
            s.silent_at.append(r["t_unix"] - t0)
    for (name, _), o in unique_observations(records).items():
        s = out.get(name)
        if s is not None and o.get("distance_m") is not None:
            s.observations.append((observation_time(s, o, t0), float(o["distance_m"]), str(o.get("code", "?")),
                                   o.get("kind") or "point"))
    return t0, out


def unique_observations(records: list[dict]) -> dict:
    """(name, (run_id, id)) -> observation: each one once, however often it was received."""
    found = {}
    for r in records:
        if r["topic"] == "observations" and r.get("id") is not None:
            found.setdefault((r["name"], (r.get("run_id"), str(r["id"]))), r)
    return found


def observation_time(s: Series, o: dict, t0: float) -> float:
    """On the record's time axis: by its sensor time among the distance rows, which no clock offset
    between the Pi and the laptop can shift; else by when it was stamped or received."""
    ok = np.isfinite(s.t_sensor)
    t_s = o.get("t_s")
    if t_s is not None and ok.sum() >= 2 and s.t_sensor[ok][0] <= t_s <= s.t_sensor[ok][-1]:
        return float(np.interp(t_s, s.t_sensor[ok], s.t[ok]))
    stamped = o.get("observed_t_unix")
    return (stamped if stamped is not None else o["t_unix"]) - t0


def _gapped(t: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """NaN inserted where samples are more than GAP_S apart, so the line breaks there."""
    cut = np.flatnonzero(np.diff(t) > GAP_S) + 1
    return np.insert(t, cut, np.nan), np.insert(v, cut, np.nan)


def plot_figure(records: list[dict], size: tuple[int, int] = (1200, 800), title: str = ""):
    """Two panels sharing the time axis: distance [m] with ±2 sigma above, speed [m/s] below."""
    require("matplotlib", "plot and report", "the record itself is plain CSV/JSONL/MCAP")
    from matplotlib.figure import Figure

    t0, series = series_from_records(records)
    fig = Figure(figsize=(size[0] / 100, size[1] / 100), dpi=100, layout="constrained")
    ax_d, ax_v = fig.subplots(2, 1, sharex=True)
    colors = [f"C{i % 10}" for i in range(len(series))]
    for color, name in zip(colors, sorted(series)):
        _draw_series(ax_d, ax_v, series[name], color)
    ax_d.set_ylabel("distance [m]")
    ax_v.set_ylabel("speed [m/s]")
    ax_v.set_xlabel(f"time [s] since {time.strftime('%Y-%m-%d %H:%M:%S', time.localtime(t0))}")
    ax_v.axhline(0.0, color="0.6", lw=0.8)
    for ax in (ax_d, ax_v):
        ax.grid(True, color="0.9")
    ax_d.set_title(title or "crawler-monitor", loc="left")
    _legend(ax_d, series)
    return fig


def _draw_series(ax_d, ax_v, s: Series, color: str):
    for a, b in s.bridged_spans():
        for ax in (ax_d, ax_v):
            ax.axvspan(a, max(b, a + 0.02), color=BRIDGED_COLOR, alpha=0.25, lw=0, gid=f"bridged:{s.name}")
    for a, b in s.lost_spans():
        for ax in (ax_d, ax_v):
            ax.axvspan(a, max(b, a + 0.02), color=LOST_COLOR, alpha=0.25, lw=0, hatch="//", gid=f"lost:{s.name}")
    band = np.isfinite(s.sigma)
    if band.any():
        t, lo = _gapped(s.t, np.where(band, s.distance - 2 * s.sigma, np.nan))
        _, hi = _gapped(s.t, np.where(band, s.distance + 2 * s.sigma, np.nan))
        ax_d.fill_between(t, lo, hi, color=color, alpha=0.2, lw=0, gid=f"sigma:{s.name}")
    ax_d.plot(*_gapped(s.t, s.distance), color=color, lw=1.6, label=s.name, gid=f"distance:{s.name}")
    ax_v.plot(*_gapped(s.t, s.speed), color=color, lw=1.2, gid=f"speed:{s.name}")
    for t in s.silent_at:
        for ax in (ax_d, ax_v):
            ax.axvline(t, color=color, ls="--", lw=1, gid=f"silent:{s.name}")
    for t, d, code, kind in s.observations:
        ax_d.plot([t], [d], MARKERS.get(kind, "v"), color=color, mec="black", ms=8, gid=f"observation:{s.name}")
        ax_d.annotate(code, (t, d), textcoords="offset points", xytext=(0, 8), ha="center", fontsize=7)


def _legend(ax, series: dict):
    """Legend entries for the shading and marks only when the record has them."""
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    handles = []
    if any(np.isfinite(s.sigma).any() for s in series.values()):
        handles.append(Patch(color="0.5", alpha=0.2, label="±2σ"))
    if any(s.bridged.any() for s in series.values()):
        handles.append(Patch(color=BRIDGED_COLOR, alpha=0.25, label="bridged (wheel or motion model)"))
    if any(s.lost_spans() for s in series.values()):
        handles.append(Patch(facecolor=LOST_COLOR, alpha=0.25, hatch="//", label="tracking lost (held)"))
    if any(s.silent_at for s in series.values()):
        handles.append(Line2D([], [], color="0.3", ls="--", label="went silent"))
    if any(s.observations for s in series.values()):
        handles.append(Line2D([], [], marker="v", color="0.5", mec="black", ls="", label="observation (▶ start, "
                              "◀ finish)"))
    lines, labels = ax.get_legend_handles_labels()
    ax.legend(lines + handles, labels + [h.get_label() for h in handles], loc="upper left", fontsize="small",
              ncols=2)


def save_plot(records: list[dict], out: Path, size=(1200, 800), title: str = ""):
    try:
        fig = plot_figure(records, size, title)
    except NothingToPlot as exc:
        raise NothingToPlot(f"nothing to plot: {exc}") from None
    try:
        fig.savefig(out, dpi=100)
    except OSError as exc:
        raise CrawlerError(f"cannot write {str(out)!r}: {exc.strerror}") from None


def figure_summary(records: list[dict]) -> str:
    _, series = series_from_records(records)
    span = max(float(np.nanmax(s.t)) for s in series.values())
    n_obs = sum(len(s.observations) for s in series.values())
    return (f"{len(series)} crawler(s) {', '.join(sorted(series))}, {span:.1f} s, "
            f"{n_obs} observation(s)")
