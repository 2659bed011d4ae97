"""A record as a picture: distance and speed over time, one line per crawler, tracking-lost shaded.

Drawn with OpenCV (already a dependency; matplotlib is not). plot_records() is pure: records in,
BGR image out; `crawler-monitor plot` only reads the file and writes the PNG.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import cv2
import numpy as np

from ..errors import CrawlerError

# tab10, as BGR: distinct for the usual colour blindness and on a projector
PALETTE = [(180, 119, 31), (14, 127, 255), (44, 160, 44), (40, 39, 214), (189, 103, 148),
           (75, 86, 140), (194, 119, 227), (127, 127, 127), (34, 189, 188), (207, 190, 23)]
WHITE, BLACK, GRID, AXIS = (255, 255, 255), (30, 30, 30), (225, 225, 225), (90, 90, 90)
FONT = cv2.FONT_HERSHEY_SIMPLEX
GAP_S = 2.0            # samples further apart than this are not joined: the crawler was silent


class NothingToPlot(CrawlerError, ValueError):
    """The record holds no distance messages."""


@dataclass
class Series:
    name: str
    t: list = field(default_factory=list)          # seconds since the record's first row
    distance: list = field(default_factory=list)
    speed: list = field(default_factory=list)      # NaN where the daemon sent null (tracking lost)
    tracking: list = field(default_factory=list)
    silent_at: list = field(default_factory=list)  # times the monitor marked it SILENT

    def lost_spans(self) -> list[tuple[float, float]]:
        """[start, end) times of tracking-lost stretches; a stretch ends at the next tracked sample."""
        spans, start = [], None
        for t, ok in zip(self.t, self.tracking):
            if not ok and start is None:
                start = t
            elif ok and start is not None:
                spans.append((start, t))
                start = None
        if start is not None:
            spans.append((start, self.t[-1]))
        return spans


def line_color(i: int) -> tuple[int, int, int]:
    return PALETTE[i % len(PALETTE)]


def series_from_records(records: list[dict]) -> tuple[float, dict[str, Series]]:
    """(t0 = first row's unix time, name -> Series) from the distance rows of a record."""
    if not records:
        raise NothingToPlot("the record is empty")
    t0 = min(r["t_unix"] for r in records)
    out: dict[str, Series] = {}
    for r in sorted((r for r in records if r["topic"] == "distance"), key=lambda r: r["t_unix"]):
        if r.get("distance_m") is None:
            continue
        s = out.setdefault(r["name"], Series(r["name"]))
        s.t.append(r["t_unix"] - t0)
        s.distance.append(float(r["distance_m"]))
        v = r.get("speed_m_s")
        s.speed.append(math.nan if v is None else float(v))
        s.tracking.append(bool(r.get("tracking", True)))
    if not out:
        raise NothingToPlot("the record has no distance messages")
    for r in records:
        if r["topic"] == "event" and r.get("event") == "silent" and r["name"] in out:
            out[r["name"]].silent_at.append(r["t_unix"] - t0)
    return t0, out


def nice_ticks(lo: float, hi: float, target: int = 6) -> list[float]:
    """Round tick values (1, 2, 5 x 10^k steps) covering [lo, hi]."""
    if not hi > lo:
        lo, hi = lo - 0.5, hi + 0.5
    raw = (hi - lo) / max(target, 1)
    mag = 10 ** math.floor(math.log10(raw))
    step = next(m * mag for m in (1, 2, 5, 10) if m * mag >= raw)
    first = math.ceil(lo / step - 1e-9) * step
    ticks, k = [], 0
    while first + k * step <= hi + 1e-9 * step:
        ticks.append(round(first + k * step, 12))
        k += 1
    return ticks


def tick_label(v: float, step: float) -> str:
    decimals = max(0, -math.floor(math.log10(step) + 1e-9)) if step > 0 else 0
    text = f"{v:.{decimals}f}"
    return "0" if text.strip("-0.") == "" else text


def _padded(lo, hi, pad=0.06):
    if not math.isfinite(lo) or not math.isfinite(hi):
        return 0.0, 1.0
    if hi - lo < 1e-9:
        return lo - 0.5, hi + 0.5
    d = (hi - lo) * pad
    return lo - d, hi + d


class _Panel:
    """One axes rectangle: data -> pixel mapping, grid, ticks, shading, lines."""

    def __init__(self, img, box, xlim, ylim, ylabel, show_xlabels):
        self.img, self.box = img, box
        x0, y0, x1, y1 = box
        self.xt = nice_ticks(*xlim)
        self.yt = nice_ticks(*ylim, target=6)
        self.xlim = (min(xlim[0], self.xt[0]), max(xlim[1], self.xt[-1])) if self.xt else xlim
        self.ylim = (min(ylim[0], self.yt[0]), max(ylim[1], self.yt[-1]))
        self.ylabel, self.show_xlabels = ylabel, show_xlabels

    def px(self, t):
        x0, _, x1, _ = self.box
        return x0 + (np.asarray(t, float) - self.xlim[0]) / (self.xlim[1] - self.xlim[0]) * (x1 - x0)

    def py(self, v):
        _, y0, _, y1 = self.box
        return y1 - (np.asarray(v, float) - self.ylim[0]) / (self.ylim[1] - self.ylim[0]) * (y1 - y0)

    def frame(self):
        img, (x0, y0, x1, y1) = self.img, self.box
        xs = self.xt[1] - self.xt[0] if len(self.xt) > 1 else 1.0
        ys = self.yt[1] - self.yt[0] if len(self.yt) > 1 else 1.0
        for v in self.yt:
            y = int(round(float(self.py(v))))
            cv2.line(img, (x0, y), (x1, y), GRID, 1)
            cv2.line(img, (x0 - 5, y), (x0, y), AXIS, 1)
            label = tick_label(v, ys)
            (w, h), _ = cv2.getTextSize(label, FONT, 0.45, 1)
            cv2.putText(img, label, (x0 - 9 - w, y + h // 2), FONT, 0.45, BLACK, 1, cv2.LINE_AA)
        for v in self.xt:
            x = int(round(float(self.px(v))))
            cv2.line(img, (x, y0), (x, y1), GRID, 1)
            cv2.line(img, (x, y1), (x, y1 + 5), AXIS, 1)
            if self.show_xlabels:
                label = tick_label(v, xs)
                (w, h), _ = cv2.getTextSize(label, FONT, 0.45, 1)
                cv2.putText(img, label, (x - w // 2, y1 + 10 + h), FONT, 0.45, BLACK, 1, cv2.LINE_AA)
        if self.ylim[0] < 0 < self.ylim[1]:
            y = int(round(float(self.py(0.0))))
            cv2.line(img, (x0, y), (x1, y), (170, 170, 170), 1)
        cv2.putText(img, self.ylabel, (x0 + 6, y0 - 8), FONT, 0.55, BLACK, 1, cv2.LINE_AA)

    def border(self):
        x0, y0, x1, y1 = self.box
        cv2.rectangle(self.img, (x0, y0), (x1, y1), AXIS, 1)

    def shade(self, spans, color, alpha=0.22):
        x0, y0, x1, y1 = self.box
        for a, b in spans:
            xa = int(np.clip(np.floor(float(self.px(a))), x0 + 1, x1 - 1))
            xb = int(np.clip(np.ceil(float(self.px(b))), x0 + 1, x1 - 1))
            xb = max(xb, xa + 2)                    # a single lost frame still shows
            roi = self.img[y0 + 1:y1, xa:xb]
            roi[:] = (roi * (1 - alpha) + np.array(color) * alpha).astype(np.uint8)

    def mark(self, times, color):
        """A dashed vertical line where the crawler went silent."""
        x0, y0, x1, y1 = self.box
        for t in times:
            x = int(round(float(self.px(t))))
            if x0 < x < x1:
                for y in range(y0 + 2, y1 - 2, 10):
                    cv2.line(self.img, (x, y), (x, min(y + 5, y1 - 2)), color, 1)

    def line(self, t, v, color):
        """Joined where consecutive samples are close in time and finite; broken across gaps."""
        t, v = np.asarray(t, float), np.asarray(v, float)
        ok = np.isfinite(v)
        breaks = np.ones(len(t), bool)
        breaks[1:] = (np.diff(t) > GAP_S) | ~ok[1:] | ~ok[:-1]
        pts = np.stack([self.px(t), self.py(v)], axis=1)
        x0, y0, x1, y1 = self.box
        for idx in np.split(np.arange(len(t)), np.flatnonzero(breaks)):
            idx = idx[ok[idx]]
            if len(idx) == 0:
                continue
            p = np.round(pts[idx] * 16).astype(np.int32)        # 4 fractional bits: smooth slopes
            if len(idx) == 1:
                cv2.circle(self.img, tuple(int(c) for c in p[0]), 2 * 16, color, -1, cv2.LINE_AA, shift=4)
            else:
                cv2.polylines(self.img, [p], False, color, 2, cv2.LINE_AA, shift=4)


def plot_records(records: list[dict], size: tuple[int, int] = (1200, 800), title: str = "") -> np.ndarray:
    """Two stacked panels sharing the time axis: distance [m] above, speed [m/s] below."""
    width, height = size
    if width < 400 or height < 300:
        raise ValueError(f"plot size {width}x{height} is too small (at least 400x300)")
    t0, series = series_from_records(records)
    names = sorted(series)
    img = np.full((height, width, 3), WHITE, np.uint8)

    tmax = max(max(s.t) for s in series.values())
    xlim = (0.0, tmax if tmax > 0 else 1.0)
    d = np.concatenate([s.distance for s in series.values()])
    v = np.concatenate([s.speed for s in series.values()])
    v = v[np.isfinite(v)]
    dlim = _padded(float(d.min()), float(d.max()))
    vlim = _padded(min(0.0, float(v.min())) if len(v) else 0.0, max(0.0, float(v.max())) if len(v) else 1.0)

    left, right, top, bottom, gap = 80, 24, 78, 62, 46
    ph = (height - top - bottom - gap) // 2
    boxes = [(left, top, width - right, top + ph), (left, top + ph + gap, width - right, top + 2 * ph + gap)]
    panels = [_Panel(img, boxes[0], xlim, dlim, "distance [m]", False),
              _Panel(img, boxes[1], xlim, vlim, "speed [m/s]", True)]
    for p in panels:
        p.frame()
    for i, name in enumerate(names):
        spans = series[name].lost_spans()
        for p in panels:
            p.shade(spans, line_color(i))
    for i, name in enumerate(names):
        s = series[name]
        panels[0].line(s.t, s.distance, line_color(i))
        panels[1].line(s.t, s.speed, line_color(i))
        for p in panels:
            p.mark(s.silent_at, line_color(i))
    for p in panels:
        p.border()

    start = time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(t0))
    xlabel = f"time [s] since {start}"
    (w, _), _ = cv2.getTextSize(xlabel, FONT, 0.55, 1)
    cv2.putText(img, xlabel, ((boxes[1][0] + boxes[1][2] - w) // 2, height - 14), FONT, 0.55, BLACK, 1,
                cv2.LINE_AA)
    cv2.putText(img, title or "crawler-monitor", (left, 30), FONT, 0.7, BLACK, 1, cv2.LINE_AA)
    _legend(img, names, series, width - right, 52)
    return img


def _legend(img, names, series, x_right, y):
    """Right-aligned on the title line: a line swatch per crawler, then the shading's meaning."""
    entries = [(n, line_color(i), "line") for i, n in enumerate(names)]
    if any(not all(s.tracking) for s in series.values()):
        entries.append(("tracking lost", (150, 150, 150), "box"))
    if any(s.silent_at for s in series.values()):
        entries.append(("went silent", (90, 90, 90), "dash"))
    x = x_right
    for label, color, kind in reversed(entries):
        (w, h), _ = cv2.getTextSize(label, FONT, 0.5, 1)
        x -= w
        cv2.putText(img, label, (x, y), FONT, 0.5, BLACK, 1, cv2.LINE_AA)
        x -= 30
        if kind == "line":
            cv2.line(img, (x, y - h // 2), (x + 24, y - h // 2), color, 3, cv2.LINE_AA)
        elif kind == "dash":
            for yy in range(y - h - 2, y + 3, 5):
                cv2.line(img, (x + 12, yy), (x + 12, yy + 2), color, 1)
        else:
            roi = img[y - h - 2:y + 3, x:x + 24]
            roi[:] = (roi * 0.78 + np.array(color) * 0.22).astype(np.uint8)
        x -= 18
