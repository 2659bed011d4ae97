"""What the wall looks like: procedural concrete, procedural masonry, or a grey image.

A pattern maps global texel rows x cols (float64 1-D coordinates, see texture.py) to (detail,
shading): detail with about zero mean and unit std, scaled by the texture contrast, and a
multiplicative shading ~1 (large faint stains). Each wraps exactly around the circumference
(`tex.n_cols` texels) and none repeats along the pipe.
"""
from __future__ import annotations

import os

import cv2
import numpy as np

from .config import ConfigError
from .texture import COARSE, hash_uniform, soft_step, value_noise

# The look of concrete: (cell size in texels, amplitude) per layer. Tuned by eye against photos of
# cast concrete: fine sand grain, mottling at a few mm to cm, dark air-void pores, pale aggregate
# specks, sparse larger bugholes, and large faint stains.
CONCRETE = {
    "grain": ((2.0, 0.55), (4.0, 0.45), (8.0, 0.40)),              # full resolution
    "mottle": ((16.0, 0.35), (32.0, 0.30), (64.0, 0.25), (128.0, 0.20)),  # coarse grid
    "pores": {"cells": (7.0, 3.5), "threshold": 0.76, "soft": 0.05, "depth": -0.55},
    "voids": {"cells": (26.0, 9.0), "threshold": 0.79, "soft": 0.04, "depth": -0.7},
    "specks": {"cells": (13.0, 6.5), "threshold": 0.25, "soft": 0.05, "lift": 0.40},
    "stains": ((700.0, 0.12), (2300.0, 0.12)),                      # multiplicative, coarse grid
    "detail_mean": -0.012, "detail_std": 0.29,  # normalise the summed layers (measured, seed-independent)
}
# Masonry: per-block shade, mortar depth, fired-clay grain, chipped joint edges (all in detail units
# before normalisation, which is measured on a sample of the wall itself).
MASONRY = {"block_shade": 1.0, "mortar": -2.6, "surface": 1.3,     # surface: concrete-like grain and pores
           "edge_soft_mm": 1.5, "edge_chip_mm": 1.2, "chip_cell_mm": 6.0}
IMAGE_FADE = 0.2           # an image layer fades out over this share of its cells, towards each end


def _coarse_grid(rows, cols):
    """The COARSE grid's sample coordinates of rows x cols.

    Samples sit at global texel coordinates r0 + COARSE*j + (COARSE-1)/2, which is where
    cv2.resize(INTER_LINEAR) puts source pixel centres, so every tile interpolates the same global
    samples and the result is seamless (rows/cols start on a multiple of COARSE).
    """
    half = (COARSE - 1) / 2
    return (rows[0] + COARSE * np.arange(len(rows) // COARSE) + half,
            cols[0] + COARSE * np.arange(len(cols) // COARSE) + half)


def _upsample(v, rows, cols) -> np.ndarray:
    return cv2.resize(np.asarray(v, np.float32), (len(cols), len(rows)), interpolation=cv2.INTER_LINEAR)


def _coarse_layers(rows, cols, n_cols, seed, layers, salt0):
    """Sum of value-noise layers (zero mean) on the COARSE grid, upsampled bilinearly to rows x cols."""
    cr, cc = _coarse_grid(rows, cols)
    return _upsample(sum(a * (value_noise(cr, cc, L, n_cols, seed, salt0 + i) - 0.5)
                         for i, (L, a) in enumerate(layers)), rows, cols)


def stains(rows, cols, n_cols, seed) -> np.ndarray:
    """Large faint multiplicative shading (0.14-0.46 m), ~1."""
    cr, cc = _coarse_grid(rows, cols)
    return _upsample(1 + sum(a * 2 * (value_noise(cr, cc, L, n_cols, seed, 20 + i) - 0.5)
                             for i, (L, a) in enumerate(CONCRETE["stains"])), rows, cols)


def _grain(rows, cols, n_cols, seed, layers, salt0):
    return sum(a * (value_noise(rows, cols, L, n_cols, seed, salt0 + i) - 0.5) for i, (L, a) in enumerate(layers))


class Concrete:
    """Cast concrete: grain, mottling, pores, bugholes, aggregate specks, stains."""

    def __init__(self, seed: int):
        self.seed = seed

    def detail(self, rows, cols, tex):
        s, n, C = self.seed, tex.n_cols, CONCRETE
        d = _grain(rows, cols, n, s, C["grain"], 0)
        d += _coarse_layers(rows, cols, n, s, C["mottle"], 10)
        stain = stains(rows, cols, n, s)
        for salt, name in ((30, "pores"), (50, "voids")):
            p = C[name]
            pn = (2 * value_noise(rows, cols, p["cells"][0], n, s, salt)
                  + value_noise(rows, cols, p["cells"][1], n, s, salt + 1)) / 3
            d += p["depth"] * soft_step(pn, p["threshold"], p["soft"])
        k = C["specks"]
        kn = (2 * value_noise(rows, cols, k["cells"][0], n, s, 40)
              + value_noise(rows, cols, k["cells"][1], n, s, 41)) / 3
        d += k["lift"] * (1 - soft_step(kn, k["threshold"], k["soft"]))
        return (d - C["detail_mean"]) / C["detail_std"], stain


class _Normalised:
    """A pattern whose raw detail is standardised by its mean and std on a sample of the wall."""

    def _calibrate(self, tex) -> None:
        rows = np.arange(0, 4 * 128, dtype=np.float64)
        cols = np.arange(0, min(tex.n_cols, 2048), dtype=np.float64)
        d = self._raw(rows, cols, tex)
        self._mean, self._std = float(d.mean()), max(float(d.std()), 1e-6)

    def detail(self, rows, cols, tex):
        if getattr(self, "_std", None) is None:
            self._calibrate(tex)
        return (self._raw(rows, cols, tex) - self._mean) / self._std, stains(rows, cols, tex.n_cols, self.seed)


class Masonry(_Normalised):
    """Blocks in running bond (long side along the pipe), mortar joints with chipped edges, a shade
    per block, fired-clay grain. A whole number of courses fits around the pipe."""

    def __init__(self, seed: int, brick_mm: tuple[float, float], mortar_mm: float, mm_per_texel: float):
        self.seed, self.brick_mm, self.mortar_mm, self.mm = seed, brick_mm, mortar_mm, mm_per_texel
        self._surface = Concrete(seed + 1)

    def _raw(self, rows, cols, tex):
        M, s, n = MASONRY, self.seed, tex.n_cols
        mm_c = tex.m_per_texel_circ * 1000
        courses = max(2, round(n * mm_c / (self.brick_mm[1] + self.mortar_mm)))
        course_cols = n / courses
        period_rows = (self.brick_mm[0] + self.mortar_mm) / self.mm
        chip = M["edge_chip_mm"] * (value_noise(rows, cols, M["chip_cell_mm"] / self.mm, n, s, 70) - 0.5)
        j = np.floor(cols / course_cols) % courses                 # course index, wraps with the columns
        v_mm = (cols - np.floor(cols / course_cols) * course_cols) * mm_c   # across the course, from its joint
        shift = (j % 2) * period_rows / 2                          # running bond
        along = rows[:, None] + shift[None, :]
        i = np.floor(along / period_rows)
        u_mm = (along - i * period_rows) * self.mm                 # along the block, from its joint
        soft = M["edge_soft_mm"]
        half = self.mortar_mm / 2

        def joint(x_mm, period_mm):                                # 1 in the joint, 0 on the block
            dist = np.minimum(np.abs(x_mm - half), np.abs(x_mm - half - period_mm))   # from a joint's centre
            return 1 - soft_step(dist + chip, half, soft)
        mortar = np.maximum(joint(u_mm, period_rows * self.mm), joint(v_mm[None, :], course_cols * mm_c))
        shade = hash_uniform(s, 60, i.astype(np.int64), np.broadcast_to(j.astype(np.int64), i.shape)) - 0.5
        surface = self._surface.detail(rows, cols, tex)[0]
        return (1 - mortar) * M["block_shade"] * shade + mortar * M["mortar"] + M["surface"] * surface


def resolve_image(path: str) -> str:
    """A texture image's file: a path, or `skimage:NAME` for scikit-image's bundled samples
    (brick, gravel, grass: photographs, for benchmarks; scikit-image is not a dependency)."""
    if not path.startswith("skimage:"):
        return path
    try:
        import skimage
    except ImportError:
        raise ConfigError("texture_image", path, "needs scikit-image: pip install 'crawlerd[textures]' "
                          "(or pip install scikit-image)") from None
    return os.path.join(os.path.dirname(skimage.__file__), "data", path.split(":", 1)[1] + ".png")


def load_grey(path: str) -> np.ndarray:
    """The image as float32 grey, or a ConfigError naming texture_image."""
    file = resolve_image(path)
    img = cv2.imread(file, cv2.IMREAD_UNCHANGED) if os.path.isfile(file) else None
    if img is None:
        raise ConfigError("texture_image", path, "is not a readable image file (PNG, JPEG, TIFF, ...)")
    if img.ndim == 3:
        img = cv2.cvtColor(img[:, :, :3], cv2.COLOR_BGR2GRAY)
    if min(img.shape[:2]) < 16 or float(img.std()) == 0:
        raise ConfigError("texture_image", path, f"is {img.shape[1]}x{img.shape[0]} and flat or under 16 px")
    return img.astype(np.float32)


def seamless(img: np.ndarray) -> np.ndarray:
    """The image made periodic without a seam: its periodic component (Moisan's periodic plus smooth
    decomposition, "Periodic plus smooth image decomposition", 2011), the image less the smooth field
    whose Laplacian is the jump across its borders. It repeats with the image's own size and nothing
    shorter: the cross-fade with a half-shifted copy this replaced made every tile repeat at half its
    height (a photographed wall every 102 mm: tracks took that alias across a drop of frames)."""
    u = img.astype(np.float64)
    m, n = u.shape
    v = np.zeros_like(u)
    v[0, :], v[-1, :] = u[-1, :] - u[0, :], u[0, :] - u[-1, :]
    v[:, 0] += u[:, -1] - u[:, 0]
    v[:, -1] += u[:, 0] - u[:, -1]
    den = (2 * np.cos(2 * np.pi * np.arange(m) / m)[:, None] + 2 * np.cos(2 * np.pi * np.arange(n) / n)[None, :] - 4)
    den[0, 0] = 1.0
    smooth = np.fft.fft2(v) / den
    smooth[0, 0] = 0.0
    return (u - np.real(np.fft.ifft2(smooth))).astype(np.float32)


class ImageTexture(_Normalised):
    """A grey image laid over the wall in random pieces: along the pipe, cells one image long, each
    showing the (seamless) image from its own random offset, and a second such layer, the image
    turned 180 deg, in cells staggered by half; each layer fades out towards its cells' ends, where
    the other shows (variance-preserving). A whole number of images fits around the pipe (exact
    wrap); along it nothing repeats with a period, as on a real wall. Pieces of the one photograph
    still recur at random distances (a 60 mm patch's best match within 0.4 m correlates 0.4-0.5 in
    the median, over 0.9 for a few %), where the old cross-fade repeated every half image (0.99)."""

    def __init__(self, seed: int, path: str, mm_per_px: float, mm_per_texel: float):
        tile = seamless(load_grey(path))
        self.seed, self.mm, self.mm_per_px = seed, mm_per_texel, mm_per_px
        self.tiles = (tile, np.ascontiguousarray(tile[::-1, ::-1]))
        self.h, self.w = tile.shape
        self.mean = float(tile.mean())

    def _layer(self, rows, cols, tex, which: int):
        """One layer: its image sampled at rows x cols, and the share each row shows of it."""
        around = max(1, round(tex.n_cols * tex.m_per_texel_circ * 1000 / (self.w * self.mm_per_px)))
        y = rows * self.mm / self.mm_per_px + which * self.h / 2              # image rows along the pipe
        cell = np.floor(y / self.h)
        dr, dc = (hash_uniform(self.seed, 90 + 2 * which + k, cell, 0).astype(np.float64) * size
                  for k, size in ((0, self.h), (1, self.w)))
        x = cols * around * self.w / tex.n_cols                                # image columns around
        mx = ((x[None, :] + dc[:, None]) % self.w).astype(np.float32)
        my = np.broadcast_to(((y + dr) % self.h).astype(np.float32)[:, None], (len(rows), len(cols)))
        img = cv2.remap(self.tiles[which], mx, np.ascontiguousarray(my), cv2.INTER_LINEAR,
                        borderMode=cv2.BORDER_WRAP) - self.mean
        u = y / self.h - cell                                                  # where in its cell
        return img, soft_step(np.minimum(u, 1 - u), 0.25 - IMAGE_FADE / 2, IMAGE_FADE).astype(np.float32)

    def _raw(self, rows, cols, tex):
        a, m = self._layer(rows, cols, tex, 0)
        b, _ = self._layer(rows, cols, tex, 1)       # (its share is 1 - a's: its cells' ends are a's middles)
        m = m[:, None]
        return (a * m + b * (1 - m)) / np.sqrt(m * m + (1 - m) ** 2)


def make_pattern(cfg, mm_per_texel: float):
    """The pattern SimConfig.texture names."""
    if cfg.texture == "masonry":
        return Masonry(cfg.seed, cfg.brick_mm, cfg.mortar_mm, mm_per_texel)
    if cfg.texture == "image":
        return ImageTexture(cfg.seed, cfg.texture_image, cfg.image_mm_per_px, mm_per_texel)
    return Concrete(cfg.seed)

