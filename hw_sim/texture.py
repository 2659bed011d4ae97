"""The wall texture as tiles: generated lazily, cached, with seamless pyramids and exact wrap.

The texture is a pure function of the global texel (row, col): a WallPattern (hw_sim/patterns.py:
concrete, masonry, an image) gives its detail and shading, built from lattice value noise whose
lattice values are an integer hash of (seed, salt, ix, iy). Tiles are just windows onto that
function, so they join without seams, and columns wrap exactly around the circumference because
every layer has an integer number of cells (courses, image tiles) around it.

Row r is the texel whose centre is at y = (r + 0.5) * mm_per_texel along the pipe; column c the
one whose centre is at arc s = (c + 0.5) * mm_per_texel_circ from the crown.

Each tile also stores a small Gaussian pyramid (levels 1..3, built from a margin-padded tile so
the levels have no seams either): the renderer samples the level that matches a pixel's footprint
on the wall so that oblique views do not alias. Stretches (featureless, wet) change the contrast
and albedo of whole rows.
"""
from __future__ import annotations

import threading
from collections import OrderedDict
from dataclasses import dataclass

import cv2
import numpy as np

TILE = 512          # texels per tile side
LEVELS = 4          # pyramid levels 0..3: footprints up to ~11 texels per pixel stay unaliased
MARGIN = 32         # texels generated beyond each tile edge so pyrDown borders are cropped away
COARSE = 4          # smooth layers are evaluated every COARSE texels and interpolated bilinearly
WRAP_MULTIPLE = 16  # texels around the pipe are a multiple of this (tiles and pyramid levels align)
DETAIL_GAIN = 0.19  # texture std as a fraction of the mean albedo (contrast 1)
STRETCH_RAMP_M = 0.01   # contrast fades over 10 mm at each end of a featureless or wet stretch


def hash_uniform(seed: int, salt: int, iy: np.ndarray, ix: np.ndarray) -> np.ndarray:
    """Uniform [0, 1) float32 from integers (seed, salt, iy, ix): murmur3's fmix32 of a mix."""
    k = np.uint32((seed * 0x9E3779B1 + salt * 0x7FEB352D + 0x165667B1) & 0xFFFFFFFF)
    a = (np.asarray(iy, np.int64) & 0xFFFFFFFF).astype(np.uint32)
    b = (np.asarray(ix, np.int64) & 0xFFFFFFFF).astype(np.uint32)
    with np.errstate(over="ignore"):
        h = a * np.uint32(0x8DA6B343) ^ b * np.uint32(0xD8163841) ^ k
        h ^= h >> np.uint32(16)
        h *= np.uint32(0x85EBCA6B)
        h ^= h >> np.uint32(13)
        h *= np.uint32(0xC2B2AE35)
        h ^= h >> np.uint32(16)
    return (h >> np.uint32(8)).astype(np.float32) * np.float32(1.0 / (1 << 24))


def _fade(t: np.ndarray) -> np.ndarray:
    return t * t * t * (t * (t * 6 - 15) + 10)


def value_noise(rows: np.ndarray, cols: np.ndarray, cell: float, n_cols: int, seed: int, salt: int) -> np.ndarray:
    """Lattice value noise in [0, 1) on the grid rows x cols (1-D global texel coordinates).

    Axially a cell is `cell` texels; around the pipe there are round(n_cols / cell) cells, so the
    noise wraps after n_cols columns. Separable: interpolate along columns on the small lattice,
    then along rows, so the full-size work is two gathers and a lerp.
    """
    around = max(1, round(n_cols / cell))
    fy = rows / cell
    fx = cols * (around / n_cols)
    iy = np.floor(fy).astype(np.int64)
    ix = np.floor(fx).astype(np.int64)
    wy = _fade((fy - iy).astype(np.float32))
    wx = _fade((fx - ix).astype(np.float32))
    iy0, ix0 = iy.min(), ix.min()
    ly = np.arange(iy0, iy.max() + 2)
    lx = np.arange(ix0, ix.max() + 2) % around
    G = hash_uniform(seed, salt, ly[:, None], lx[None, :])
    jx = ix - ix0
    Gx = G[:, jx] * (1 - wx) + G[:, jx + 1] * wx
    jy = iy - iy0
    return Gx[jy] * (1 - wy)[:, None] + Gx[jy + 1] * wy[:, None]


def soft_step(x: np.ndarray, edge: float, soft: float) -> np.ndarray:
    t = np.clip((x - edge) / soft, 0.0, 1.0)
    return t * t * (3 - 2 * t)


def inside(y: np.ndarray, intervals, ramp: float = STRETCH_RAMP_M) -> np.ndarray:
    """How far each position y (m) is inside any interval a:b: 1 inside, 0 outside, a smooth
    `ramp` across each end."""
    w = np.zeros(np.shape(y), np.float32)
    for a, b in intervals:
        w = np.maximum(w, soft_step(y, a - ramp / 2, ramp) * (1 - soft_step(y, b - ramp / 2, ramp)))
    return w


@dataclass(frozen=True)
class Stretch:
    """Wall from a to b (m along the pipe) whose texture contrast and albedo are scaled."""
    a: float
    b: float
    contrast: float
    albedo: float = 1.0


class WallTexture:
    """The albedo of the whole wall (mean ~1), as lazily generated, LRU-cached tile pyramids."""

    def __init__(self, seed: int, mm_per_texel: float, circumference_m: float, contrast: float = 1.0,
                 stretches: tuple[Stretch, ...] = (), pattern=None, cache_tiles: int = 96):
        from .patterns import Concrete
        self.seed = seed
        self.m_per_texel = mm_per_texel / 1000.0
        n = circumference_m / self.m_per_texel
        self.n_cols = max(WRAP_MULTIPLE, WRAP_MULTIPLE * round(n / WRAP_MULTIPLE))
        self.m_per_texel_circ = circumference_m / self.n_cols
        self.contrast = contrast
        self.stretches = tuple(stretches)
        self.pattern = pattern or Concrete(seed)
        self.cache_tiles = cache_tiles
        self._cache: OrderedDict[tuple[int, int], list[np.ndarray]] = OrderedDict()
        self.tiles_generated = 0
        self._lock = threading.Lock()     # the fake's camera thread and its consumer share tiles
        self._pending: dict[tuple[int, int], threading.Event] = {}

    # --- the texture function -------------------------------------------------------------------
    def _rows_factors(self, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Per-row (contrast, albedo) factors: 1 and 1, changed inside the stretches."""
        c, a = np.ones(rows.shape, np.float32), np.ones(rows.shape, np.float32)
        y = (rows + 0.5) * self.m_per_texel
        for s in self.stretches:
            w = inside(y, [(s.a, s.b)])
            c *= 1 - (1 - s.contrast) * w
            a *= 1 - (1 - s.albedo) * w
        return c, a

    def detail(self, rows: np.ndarray, cols: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(detail, shading) on the grid rows x cols: detail ~ zero mean, unit std; shading ~ 1."""
        return self.pattern.detail(rows.astype(np.float64), cols.astype(np.float64), self)

    def albedo(self, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
        """Texture values on the grid of integer texel rows x cols (both contiguous runs whose first
        element and length are multiples of COARSE). Float32, mean ~1."""
        d, stain = self.detail(rows, cols)
        c, a = self._rows_factors(rows)
        gain = DETAIL_GAIN * self.contrast * c[:, None]
        return np.clip(stain * a[:, None] * (1 + gain * d), 0.02, 3.0).astype(np.float32)

    # --- tiles ----------------------------------------------------------------------------------
    def tile_width(self, tx: int) -> int:
        return min(TILE, self.n_cols - tx * TILE)

    def tile(self, tx: int, ty: int) -> list[np.ndarray]:
        """Pyramid [level0 (TILE x w), level1, ...] of tile column tx (0..n_tile_cols-1), row ty.

        Thread-safe: a tile is generated outside the lock (tens of ms), once; a second thread that
        needs the same tile meanwhile waits for it, others go on with cached ones."""
        key = (tx, ty)
        with self._lock:
            lv = self._cache.get(key)
            if lv is not None:
                self._cache.move_to_end(key)
                return lv
            pending = self._pending.get(key)
            mine = pending is None
            if mine:
                pending = self._pending[key] = threading.Event()
        if not mine:
            pending.wait()
            return self.tile(tx, ty)
        try:
            lv = self._make_tile(tx, ty)
            with self._lock:
                self._cache[key] = lv
                self.tiles_generated += 1
                while len(self._cache) > self.cache_tiles:
                    self._cache.popitem(last=False)
            return lv
        finally:
            with self._lock:
                del self._pending[key]
            pending.set()

    def _make_tile(self, tx: int, ty: int) -> list[np.ndarray]:
        w = self.tile_width(tx)
        rows = np.arange(ty * TILE - MARGIN, (ty + 1) * TILE + MARGIN)
        cols = np.arange(tx * TILE - MARGIN, tx * TILE + w + MARGIN)
        p = self.albedo(rows, cols)
        lv = [np.ascontiguousarray(p[MARGIN:-MARGIN, MARGIN:-MARGIN])]
        for k in range(1, LEVELS):
            p = cv2.pyrDown(p)
            m = MARGIN >> k
            lv.append(np.ascontiguousarray(p[m:-m, m:-m]))
        return lv

    def region(self, level: int, r0: int, r1: int, c0: int, c1: int) -> np.ndarray:
        """Pyramid level `level` over global level rows [r0, r1) and columns [c0, c1) (columns wrap).

        Level-k texel (i, j) is centred on level-0 texel coordinate (2^k i, 2^k j).
        """
        T = TILE >> level
        nc = self.n_cols >> level
        out = np.empty((r1 - r0, c1 - c0), np.float32)
        r = r0
        while r < r1:
            ty, ri = divmod(r, T)
            nr = min(T - ri, r1 - r)
            c = c0
            while c < c1:
                cm = c % nc
                tx, ci = divmod(cm, T)
                ncols = min((self.tile_width(tx) >> level) - ci, c1 - c)
                out[r - r0:r - r0 + nr, c - c0:c - c0 + ncols] = self.tile(tx, ty)[level][ri:ri + nr, ci:ci + ncols]
                c += ncols
            r += nr
        return out

    def ensure(self, level: int, r0: int, r1: int, c0: int, c1: int, budget: int = 1 << 30) -> int:
        """Generate (and cache) the tiles region(level, r0, r1, c0, c1) would read, at most
        `budget` new ones; returns how many it made."""
        T, nc = TILE >> level, self.n_cols >> level
        cols, c = set(), c0
        while c < c1 and len(cols) * T < nc + T:
            tx, ci = divmod(c % nc, T)
            cols.add(tx)
            c += (self.tile_width(tx) >> level) - ci
        made = 0
        for ty in range(r0 // T, (r1 - 1) // T + 1):
            for tx in sorted(cols):
                if made >= budget:
                    return made
                with self._lock:
                    cached = (tx, ty) in self._cache
                if not cached:
                    self.tile(tx, ty)
                    made += 1
        return made
