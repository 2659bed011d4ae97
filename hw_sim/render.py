"""The Simulator: frames of the textured pipe wall as the crawler's camera sees them.

Every output pixel's ray is intersected with the cylinder once (axial y and arc s of its wall
point, in texels); a frame is then one cv2.remap of the texture shifted by the car's distance
(and roll). Rays are recomputed per frame only when bounce, pitch jitter or sway move the camera.
Pixels whose footprint on the wall spans several texels (far rows of a tilted camera) sample a
coarser texture pyramid level, blended linearly between levels, so that they blur instead of
aliasing.

Motion blur: travel along the pipe is a rigid shift of the wall in texture space, the same for
every pixel whatever the perspective, so averaging sub-frames over the exposure equals sampling the
texture box-filtered along its rows over the distance travelled. That is done exactly (one remap
instead of many). Camera wobble during the exposure (pitch jitter, roll, sway, bounce) is not a
rigid texture shift; it is averaged over sub-frame renders, as many as keep each step under ~1 px.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Iterator

import cv2
import numpy as np

from . import geometry as geo
from .config import SimConfig, SimError
from .light import led_light
from .motion import Motion, sine
from .patterns import make_pattern
from .pose import PoseModel, keyframes
from .texture import LEVELS, Stretch, WallTexture, inside

LOD_BIAS = 0.5          # start blending in level 1 at a footprint of 2^0.5 texels per pixel
MAX_BLUR_SAMPLES = 16
MAX_REGION_TEXELS = 64_000_000   # a guard: a view needing more texture than this is refused


@dataclass(frozen=True)
class Frame:
    """One output frame. index counts frames in the output stream; sensor_index counts all
    frames the sensor produced, dropped ones included."""
    index: int
    sensor_index: int
    t_s: float
    image: np.ndarray
    distance_m: float
    speed_m_s: float


@dataclass
class _View:
    """Per-pixel wall coordinates of one camera pose, in texels relative to the camera."""
    R: np.ndarray           # axial texel offset y_rel / m_per_texel, float32 (h, w)
    C: np.ndarray           # circumferential texel coordinate s / m_per_texel_circ, float32 (h, w)
    gain: np.ndarray | None  # lighting x vignetting, float32 (h, w), or None when both are off
    rmin: np.ndarray        # per-row min / max of R (for the texture region a band needs)
    rmax: np.ndarray
    spec: tuple | None = None   # (v0, v1, u0, u1, lobe): the wet highlight's pixels, or None


@dataclass
class _Level:
    """Rows [a, b) of the image sampled from pyramid level k, with blend weights (None: all 1)."""
    k: int
    a: int
    b: int
    weight: np.ndarray | None


class Simulator:
    """Renders a SimConfig. Deterministic: the same config and t give the same image."""

    def __init__(self, cfg: SimConfig):
        self.cfg = cfg
        self.radius_m = cfg.radius_m
        self.camera_height_m = cfg.H_m
        self.tilt_rad = math.radians(cfg.tilt_deg)
        self.width, self.height = cfg.out_size
        K = geo.pinhole(cfg.width, cfg.height, cfg.hfov_deg, cfg.vfov_deg)
        fx, fy, cx, cy = geo.window_intrinsics(K, cfg.window_px, cfg.out_size)
        self.intrinsics = {"fx": fx, "fy": fy, "cx": cx, "cy": cy}
        self.distortion = tuple(cfg.distortion) if cfg.distortion else (0.0,) * 5
        self._xn, self._yn = geo.normalised_grid(K, cfg.window_px, cfg.out_size, cfg.distortion)
        self.motion = Motion(cfg.profile, cfg.speed_m_s, cfg.duration_s, cfg.accel_m_s2,
                             cfg.stopgo_period_s, cfg.stopgo_dwell_s)
        stretches = tuple(Stretch(a, b, cfg.featureless_contrast) for a, b in cfg.featureless) + tuple(
            Stretch(a, b, cfg.wet_contrast, cfg.wet_albedo) for a, b in cfg.wet_patches)
        self.texture = WallTexture(cfg.seed, cfg.mm_per_texel, 2 * math.pi * self.radius_m, cfg.contrast,
                                   stretches, make_pattern(cfg, cfg.mm_per_texel))
        self.poses = PoseModel(cfg, self.motion)
        self._dynamic = self.poses.moves
        self._K = K
        self._view0 = self._view(self.tilt_rad, self.camera_height_m, 0.0)
        self._levels, self._plans = self._plan_levels(self._view0), {}
        self._level_maps = self._scaled_maps(self._view0)
        self._check_region(self._view0)
        self.blur_samples = self._blur_samples()

    # --- ground truth -------------------------------------------------------------------------------
    def distance_at(self, t_s: float) -> float:
        """True distance travelled at time t (m, forward positive)."""
        return self.motion.distance(t_s)

    def speed_at(self, t_s: float) -> float:
        return self.motion.speed(t_s)

    # --- frame schedule -----------------------------------------------------------------------------
    def schedule(self) -> tuple[np.ndarray, np.ndarray]:
        """(sensor frame times, kept mask): frames at k/fps for 0 <= k/fps <= duration; dropped
        frames are drawn from the seed or fall in dropped_bursts, never the first."""
        n = int(math.floor(self.cfg.duration_s * self.cfg.fps + 1e-9)) + 1
        t = np.arange(n) / self.cfg.fps
        keep = np.random.default_rng([self.cfg.seed, 0xD0]).random(n) >= self.cfg.drop_prob
        for a, b in self.cfg.dropped_bursts:
            keep &= ~((t >= a) & (t < b))
        keep[0] = True
        return t, keep

    def frames(self) -> Iterator[Frame]:
        """Rendered frames in stream order, dropped ones left out (their timestamps leave gaps)."""
        t, keep = self.schedule()
        idx = 0
        for k in np.flatnonzero(keep):
            ts = float(t[k])
            yield Frame(idx, int(k), ts, self.render(ts), self.distance_at(ts), self.speed_at(ts))
            idx += 1

    # --- rendering ----------------------------------------------------------------------------------
    def render(self, t_s: float) -> np.ndarray:
        """The uint8 (height, width) frame whose top row is mid-exposure at t_s, with every
        configured disturbance: blur, rolling shutter, camera motion, light, blackouts, flicker, noise."""
        c = self.cfg
        acc = self.render_linear(t_s)
        scale = c.brightness * (1.0 + float(sine(t_s, c.flicker_amp, c.flicker_hz)))
        sigma = np.float32(c.noise_sigma)
        if c.led_blackouts:
            led = led_light(self.row_times(t_s), c.exposure_ms / 1000.0, c.led_blackouts, c.blackout_decay_ms / 1000)
            light = c.blackout_ambient + (1.0 - c.blackout_ambient) * led
            acc *= (light * scale).astype(np.float32)[:, None]
            sigma = np.sqrt(c.noise_sigma ** 2 + ((1.0 - led) * c.blackout_noise_sigma) ** 2).astype(np.float32)[:, None]
        else:
            acc *= np.float32(scale)
        if np.any(sigma > 0):
            rng = np.random.default_rng([c.seed, 0x5E, int(round(t_s * 1e6)) & 0xFFFFFFFFFFFF])
            acc += rng.standard_normal(acc.shape, dtype=np.float32) * sigma
        acc += np.float32(0.5)
        np.clip(acc, 0, 255, out=acc)
        return acc.astype(np.uint8)

    def row_times(self, t_s: float):
        """Mid-exposure time of each output row (rolling shutter), or t_s for all (global)."""
        if self.cfg.readout_ms <= 0:
            return np.full(self.height, t_s)
        return t_s + (self.cfg.readout_ms / 1000.0) * np.arange(self.height) / max(self.height - 1, 1)

    def render_linear(self, t_s: float) -> np.ndarray:
        """Float32 image of the wall albedo (mean ~1) times lighting/vignetting, blurred over the
        exposure: the frame at t_s before brightness, flicker, noise and quantisation."""
        exp = self.cfg.exposure_ms / 1000.0
        n = self.blur_samples
        if n == 1:
            return self._render_instant(t_s, exp)
        acc = None
        for j in range(n):
            img = self._render_instant(t_s + ((j + 0.5) / n - 0.5) * exp, exp / n)
            acc = img if acc is None else cv2.add(acc, img)
        acc *= np.float32(1.0 / n)
        return acc

    def pose(self, t_s: float) -> dict[str, float]:
        """Camera pose at t: tilt (rad), H (m), sway x (m), roll (rad)."""
        return self.poses.at(t_s)

    def truth(self, t_s: float) -> dict[str, float]:
        """Ground truth of the frame at t_s: distance, speed, true tilt and H, the LEDs' light,
        the share of the centre column over wet wall."""
        c = self.cfg
        led = led_light(self.row_times(t_s), c.exposure_ms / 1000.0, c.led_blackouts, c.blackout_decay_ms / 1000)
        wet = 0.0
        if c.wet_patches:
            pose = self.pose(t_s)
            y = c.start_m + self.distance_at(t_s) + self._centre_column_y(pose)
            wet = float(inside(y, c.wet_patches).mean())
        return {"distance_m": self.distance_at(t_s), "speed_m_s": self.speed_at(t_s),
                "tilt_deg": float(self.poses.tilt_deg(t_s)), "camera_height_m": float(self.poses.camera_height_m(t_s)),
                "led_light": float(led.mean()), "wet": wet}

    def _centre_column_y(self, pose) -> np.ndarray:
        """Axial wall position (m, from the camera) of the centre column's pixels at this pose."""
        col = self.width // 2
        y, _, _, _ = geo.wall_coords(self._xn[:, col], self._yn[:, col], pose["tilt"], pose["sway"],
                                     self.radius_m - pose["H"], self.radius_m)
        return y

    def _render_instant(self, tau: float, exposure: float = 0.0, posed: float | None = None) -> np.ndarray:
        """One camera pose at tau (or at `posed`); travel during `exposure` (s) is an axial box blur.
        A camera turned during a rolling shutter's readout: each band of rows at its own time's tilt."""
        c = self.cfg
        if posed is None and c.readout_ms > 0 and c.tilt_schedule:
            read = c.readout_ms / 1000.0
            swing = abs(np.diff(keyframes(np.array([tau, tau + read]), c.tilt_schedule, c.tilt_deg))[0])
            cut = np.linspace(0, self.height, min(64, int(swing / 0.02) + 1) + 1).astype(int)   # 0.02 deg a band
            if len(cut) > 2:
                mid = tau + read * (cut[:-1] + cut[1:] - 1) / 2 / (self.height - 1)
                return np.concatenate([self._render_instant(tau, exposure, t)[a:b] for a, b, t in zip(cut, cut[1:], mid)])
        tex = self.texture
        pose = self.pose(tau if posed is None else posed)
        if self._dynamic:
            view = self._view(pose["tilt"], pose["H"], pose["sway"])
            levels = self._levels_for(pose["tilt"], view)
            maps = self._scaled_maps(view, levels)
        else:
            view, maps, levels = self._view0, self._level_maps, self._levels
        rows_t = self.row_times(tau) if c.readout_ms > 0 else tau
        if exposure > 0:   # centre of the path travelled during the exposure, and its length
            d0 = self.motion.distance(np.asarray(rows_t) - exposure / 2)
            d1 = self.motion.distance(np.asarray(rows_t) + exposure / 2)
            off_r = (c.start_m + (d0 + d1) / 2) / tex.m_per_texel - 0.5
            blur = float(np.max(np.abs(d1 - d0))) / tex.m_per_texel
        else:
            off_r = (c.start_m + self.motion.distance(rows_t)) / tex.m_per_texel - 0.5
            blur = 0.0
        off_c = -self.radius_m * pose["roll"] / tex.m_per_texel_circ - 0.5
        out = None
        for lv, maps, (r0, r1, c0, c1), orow in self._bands(view, maps, off_r, off_c, levels):
            Rk, Ck = maps[0], maps[1]
            s = 0.5 ** lv.k
            region = self._blurred_region(lv.k, r0, r1, c0, c1, blur * s)
            if np.ndim(orow):
                mapy = Rk + (np.asarray(orow) * s - r0).astype(np.float32)[:, None]
            else:
                mapy = Rk + np.float32(orow * s - r0)
            mapx = Ck + np.float32(off_c * s - c0)
            img = cv2.remap(region, mapx, mapy, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
            if lv.weight is None:
                out = img
            else:
                if out is None:
                    out = np.zeros((self.height, self.width), np.float32)
                out[lv.a:lv.b] += lv.weight * img
        if view.gain is not None:
            out *= view.gain
        if view.spec is not None:
            self._add_highlight(out, view, off_r)
        return out

    def _add_highlight(self, out: np.ndarray, view: _View, off_r) -> None:
        """The LED's specular highlight, fixed in the image, where the wall under it is wet."""
        v0, v1, u0, u1, lobe = view.spec
        orow = off_r[v0:v1, None] if np.ndim(off_r) else off_r
        y = (view.R[v0:v1, u0:u1] + orow + 0.5) * self.texture.m_per_texel
        out[v0:v1, u0:u1] += lobe * inside(y, self.cfg.wet_patches)

    def _bands(self, view: _View, maps, off_r, off_c, levels=None):
        """Per pyramid level: its maps, the texture region [r0, r1) x [c0, c1) its rows need at
        these offsets, and its rows' axial offsets."""
        for lv, m in zip(levels or self._levels, maps):
            s = 0.5 ** lv.k
            orow = off_r[lv.a:lv.b] if np.ndim(off_r) else off_r
            rlo = float(np.min(view.rmin[lv.a:lv.b] + orow)) * s
            rhi = float(np.max(view.rmax[lv.a:lv.b] + orow)) * s
            cmin, cmax = m[2], m[3]
            yield lv, m, (math.floor(rlo) - 1, math.floor(rhi) + 3,
                          math.floor((cmin + off_c) * s) - 1, math.floor((cmax + off_c) * s) + 3), orow

    def prefetch(self, t_s: float, budget: int = 1 << 30) -> bool:
        """Generate the texture tiles a frame at t_s will need (the undisturbed view), at most
        `budget` new ones, so that rendering it later finds them cached. True: all are cached."""
        tex = self.texture
        off_r = (self.cfg.start_m + self.motion.distance(t_s)) / tex.m_per_texel - 0.5
        for lv, _, (r0, r1, c0, c1), _ in self._bands(self._view0, self._level_maps, off_r, -0.5):
            budget -= tex.ensure(lv.k, r0, r1, c0, c1, budget)
            if budget <= 0:
                return False
        return True

    def _blurred_region(self, k: int, r0: int, r1: int, c0: int, c1: int, length: float) -> np.ndarray:
        """Texture level k over [r0, r1) x [c0, c1), box-filtered along rows over `length` texels."""
        if length < 0.25:
            return self.texture.region(k, r0, r1, c0, c1)
        kern = axial_box(length)
        pad = len(kern) // 2
        region = self.texture.region(k, r0 - pad, r1 + pad, c0, c1)
        region = cv2.sepFilter2D(region, -1, np.ones(1, np.float32), kern, borderType=cv2.BORDER_REPLICATE)
        return region[pad:pad + r1 - r0]

    # --- geometry set-up ----------------------------------------------------------------------------
    def _view(self, tilt: float, H: float, sway: float) -> _View:
        c = self.cfg
        r = self.radius_m
        dt = np.float64 if not self._dynamic else np.float32   # float32 halves per-frame ray cost
        xn, yn = self._xn.astype(dt, copy=False), self._yn.astype(dt, copy=False)
        y, s, rng, cos_inc = geo.wall_coords(xn, yn, tilt, sway, r - H, r)
        R = (y / self.texture.m_per_texel).astype(np.float32)
        C = (s / self.texture.m_per_texel_circ).astype(np.float32)
        gain = None
        if c.lighting:
            gain = geo.led_gain(rng, cos_inc, self.camera_height_m, self.tilt_rad)
        if c.vignetting:
            v = geo.vignette(xn, yn)
            gain = v if gain is None else gain * v
        if gain is not None:
            gain = gain.astype(np.float32)
        spec = self._highlight(xn, yn, tilt) if c.wet_patches and c.wet_highlight > 0 else None
        return _View(R, C, gain, R.min(axis=1), R.max(axis=1), spec)

    def _highlight(self, xn, yn, tilt: float):
        """The highlight's lobe: wet_highlight x a Gaussian in the angle between each pixel's ray and
        the highlight's (the LED's mirror point: the ray square onto the wall; or a given pixel)."""
        c = self.cfg
        if c.wet_highlight_at is None:
            hx, hy = 0.0, math.tan(tilt)    # straight up to the crown (the wall normal, camera at x = 0)
        else:
            fx, fy, cx, cy = self._K
            hx, hy = (c.wet_highlight_at[0] - cx) / fx, (c.wet_highlight_at[1] - cy) / fy
        cos = (xn * hx + yn * hy + 1) / np.sqrt((xn * xn + yn * yn + 1) * (hx * hx + hy * hy + 1))
        angle = np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))
        lobe = c.wet_highlight * np.exp(-0.5 * (angle / c.wet_highlight_deg) ** 2)
        on = lobe > 1e-3 * c.wet_highlight
        if not on.any():
            return None
        rows, cols = np.flatnonzero(on.any(axis=1)), np.flatnonzero(on.any(axis=0))
        v0, v1, u0, u1 = rows[0], rows[-1] + 1, cols[0], cols[-1] + 1
        return v0, v1, u0, u1, lobe[v0:v1, u0:u1].astype(np.float32)

    def _plan_levels(self, v: _View) -> list[_Level]:
        """Pick a pyramid level per pixel from its footprint (texels per pixel) on the wall."""
        dRv, dRu = np.gradient(v.R.astype(np.float64))
        dCv, dCu = np.gradient(v.C.astype(np.float64))
        foot = np.maximum(np.hypot(dRu, dCu), np.hypot(dRv, dCv))
        lam = np.clip(np.log2(np.maximum(foot, 1e-9)) - LOD_BIAS, 0, LEVELS - 1)
        w = np.clip(1 - np.abs(lam[None] - np.arange(LEVELS)[:, None, None]), 0, 1)
        w[w < 1e-3] = 0                      # skip negligible levels, keep the weights summing to 1
        w /= w.sum(axis=0)
        levels = []
        for k in range(LEVELS):
            rows = np.flatnonzero(w[k].any(axis=1))
            if rows.size == 0:
                continue
            a, b = int(rows[0]), int(rows[-1]) + 1
            full = a == 0 and b == self.height and bool(np.all(w[k] == 1))
            levels.append(_Level(k, a, b, None if full else w[k, a:b].astype(np.float32)))
        return levels

    def _levels_for(self, tilt: float, view: _View) -> list[_Level]:
        """The pyramid plan of a moving camera: the first one, unless the tilt moved (a schedule)
        more than 1.5 deg from it; then one per whole degree, made once."""
        if abs(tilt - self.tilt_rad) < math.radians(1.5):
            return self._levels
        key = round(math.degrees(tilt))
        if key not in self._plans:
            self._plans[key] = self._plan_levels(view)
        return self._plans[key]

    def _scaled_maps(self, v: _View, levels=None):
        """Per level: (R, C) of its row band scaled to level-k texels, and the band's column span."""
        out = []
        for lv in levels or self._levels:
            s = np.float32(0.5 ** lv.k)
            C = v.C[lv.a:lv.b]
            out.append((v.R[lv.a:lv.b] * s, C * s, float(C.min()), float(C.max())))
        return out

    def _check_region(self, v: _View) -> None:
        total = 0
        for lv, (Rk, Ck, cmin, cmax) in zip(self._levels, self._level_maps):
            s = 0.5 ** lv.k
            total += (float(v.rmax[lv.a:lv.b].max() - v.rmin[lv.a:lv.b].min()) * s + 4) * ((cmax - cmin) * s + 4)
        if total > MAX_REGION_TEXELS:
            raise SimError(f"the view needs {total / 1e6:.0f} M texels of wall per frame; "
                           f"lower tilt_deg={self.cfg.tilt_deg:g} or raise mm_per_texel={self.cfg.mm_per_texel:g}")

    def _blur_samples(self) -> int:
        """Sub-frames for camera wobble during the exposure: about one per pixel it moves (the
        travel itself is blurred exactly, see the module docstring)."""
        c = self.cfg
        if c.exposure_ms <= 0:
            return 1
        if c.blur_samples:
            return c.blur_samples
        px_per_m = self.intrinsics["fy"] / self.camera_height_m   # at the crown, tilt 0
        px_per_rad = self.intrinsics["fy"]
        w = 2 * math.pi
        rate = (w * c.pitch_jitter_hz * 2.0 * math.radians(c.pitch_jitter_deg) * px_per_rad
                + w * c.roll_hz * math.radians(c.roll_deg) * self.radius_m * px_per_m
                + w * c.sway_hz * c.sway_mm / 1000 * px_per_m
                + w * c.bounce_hz * c.bounce_mm / 1000 * px_per_m * 0.5)   # px/s, upper bounds
        return int(min(MAX_BLUR_SAMPLES, max(1, math.ceil(rate * c.exposure_ms / 1000.0))))


def axial_box(length: float) -> np.ndarray:
    """Odd, symmetric taps of a box `length` texels long, each tap weighted by its overlap with
    the box (so fractional lengths blur smoothly); sums to 1."""
    half = length / 2
    m = int(math.ceil(half + 0.5))
    j = np.arange(-m, m + 1, dtype=np.float64)
    w = np.clip(np.minimum(j + 0.5, half) - np.maximum(j - 0.5, -half), 0, None)
    return (w / w.sum()).astype(np.float32)
