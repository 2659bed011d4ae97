"""Camera, mount and the three image-to-wall projections. Pure math: no I/O, no logging.

Frames and signs follow docs/conventions.md: the camera looks up at the crown, image top toward
travel, positive tilt pitches the optical axis forward. A wall point is ``(s, y)``: arc ``s`` from
the crown (positive toward image right) and axial ``y`` ahead of the camera, both in metres.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import cv2
import numpy as np

from .errors import BadConfig, BadGeometry

METHODS = ("pixel", "plane", "cylinder")
# OpenCV's default 5 iterations leave ~1e-5 px; 20 reach machine precision for lens-like distortion
_UNDISTORT_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 20, 1e-12)


def camera_height(pipe_diameter_m: float, car_width_m: float, camera_offset_m: float) -> float:
    """Thesis Eq. 3.4: distance from the camera up to the crown for a car riding the pipe bottom."""
    r = pipe_diameter_m / 2.0
    if pipe_diameter_m <= 0:
        raise BadGeometry(f"[mount] pipe_diameter_m = {pipe_diameter_m} must be > 0")
    if car_width_m <= 0:
        raise BadGeometry(f"[mount] car_width_m = {car_width_m} must be > 0")
    if car_width_m >= pipe_diameter_m:
        raise BadGeometry(
            f"[mount] car_width_m = {car_width_m} is not smaller than pipe_diameter_m = "
            f"{pipe_diameter_m}: the car cannot ride inside this pipe; measure the wheel track "
            "(outer contact points) and the pipe's inner diameter")
    h = r + math.sqrt(4 * r * r - car_width_m ** 2) / 2.0 - camera_offset_m
    if not 0 < h < pipe_diameter_m:
        raise BadGeometry(
            f"[mount] camera_offset_m = {camera_offset_m} puts the camera outside the pipe "
            f"(height below the crown would be {h:.4f} m, must be between 0 and {pipe_diameter_m})")
    return h


@dataclass(frozen=True)
class Camera:
    """Pinhole intrinsics of the frames the odometry sees (after any sensor crop and scaling)."""

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    distortion: tuple[float, ...] = ()
    hflip: bool = False
    vflip: bool = False
    readout_s: float = 0.0   # rolling shutter: top row to bottom row

    @classmethod
    def from_fov(cls, width: int, height: int, vfov_deg: float, hfov_deg: float, **kw) -> "Camera":
        """The thesis way: focal lengths from the field of view, principal point at the centre."""
        fx = (width / 2.0) / math.tan(math.radians(hfov_deg) / 2.0)
        fy = (height / 2.0) / math.tan(math.radians(vfov_deg) / 2.0)
        return cls(width, height, fx, fy, (width - 1) / 2.0, (height - 1) / 2.0, **kw)

    def window(self, x0: float, y0: float, w: float, h: float, out_w: int, out_h: int) -> "Camera":
        """The camera seen through a sensor sub-rectangle scaled to out_w x out_h (pixel centres kept)."""
        sx, sy = out_w / w, out_h / h
        return replace(self, width=out_w, height=out_h, fx=self.fx * sx, fy=self.fy * sy,
                       cx=(self.cx - x0 + 0.5) * sx - 0.5, cy=(self.cy - y0 + 0.5) * sy - 0.5,
                       readout_s=self.readout_s * (h / self.height))

    def with_size(self, width: int, height: int) -> "Camera":
        """The same lens at another output resolution of the same field of view."""
        return self.window(0, 0, self.width, self.height, width, height)

    @property
    def matrix(self) -> np.ndarray:
        return np.array([[self.fx, 0, self.cx], [0, self.fy, self.cy], [0, 0, 1]], dtype=np.float64)

    def normalise(self, pts: np.ndarray) -> np.ndarray:
        """Frame pixels (N, 2) -> undistorted normalised (xn, yn) in the canonical orientation."""
        pts = np.asarray(pts, dtype=np.float64).reshape(-1, 2)
        if self._distorted:
            xy = cv2.undistortPointsIter(pts.reshape(-1, 1, 2), self.matrix,
                                         np.asarray(self.distortion, np.float64), None, None,
                                         _UNDISTORT_CRITERIA).reshape(-1, 2)
        else:
            xy = (pts - self._centre) * self._inv_focal
        return xy * self._flip_signs if self.hflip or self.vflip else xy

    def to_pixels(self, xy: np.ndarray) -> np.ndarray:
        """Inverse of normalise: canonical normalised (N, 2) -> frame pixels, distortion applied."""
        xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2) * self._flip_signs
        if any(self.distortion):
            obj = np.column_stack([xy, np.ones(len(xy))]).reshape(-1, 1, 3)
            px, _ = cv2.projectPoints(obj, np.zeros(3), np.zeros(3), self.matrix,
                                      np.asarray(self.distortion, np.float64))
            return px.reshape(-1, 2)
        return xy * (self.fx, self.fy) + (self.cx, self.cy)

    def row_time(self, v: np.ndarray) -> np.ndarray:
        """Seconds after the top row at which (continuous) frame row v was exposed."""
        return self.readout_s * np.asarray(v) / max(self.height - 1, 1)

    @property
    def _distorted(self) -> bool:
        return any(self.distortion)

    @property
    def _centre(self) -> np.ndarray:
        return np.array([self.cx, self.cy])

    @property
    def _inv_focal(self) -> np.ndarray:
        return np.array([1.0 / self.fx, 1.0 / self.fy])

    @property
    def _flip_signs(self) -> np.ndarray:
        return np.array([-1.0 if self.hflip else 1.0, -1.0 if self.vflip else 1.0])


@dataclass(frozen=True)
class Mount:
    """Where the camera sits in the pipe: radius, height below the crown, forward tilt, and how far
    it is off the pipe's vertical mid-plane (+: toward image right; the car's weave, which only
    the cylinder sees: to a plane or the pixel method it is a shift along the arc)."""

    pipe_radius_m: float
    height_m: float
    tilt_rad: float = 0.0
    sway_m: float = 0.0

    @classmethod
    def from_car(cls, pipe_diameter_m: float, car_width_m: float, camera_offset_m: float,
                 tilt_deg: float = 0.0) -> "Mount":
        h = camera_height(pipe_diameter_m, car_width_m, camera_offset_m)
        return cls(pipe_diameter_m / 2.0, h, math.radians(tilt_deg))

    @classmethod
    def from_height(cls, pipe_diameter_m: float, height_m: float, tilt_deg: float = 0.0) -> "Mount":
        if pipe_diameter_m <= 0:
            raise BadGeometry(f"[mount] pipe_diameter_m = {pipe_diameter_m} must be > 0")
        if not 0 < height_m < pipe_diameter_m:
            raise BadGeometry(
                f"[mount] height_m = {height_m} puts the camera outside the pipe; it must be between "
                f"0 and pipe_diameter_m = {pipe_diameter_m}")
        return cls(pipe_diameter_m / 2.0, height_m, math.radians(tilt_deg))

    @property
    def tilt_deg(self) -> float:
        return math.degrees(self.tilt_rad)

    def ray(self, xy: np.ndarray) -> np.ndarray:
        """World direction (N, 3) of the rays through canonical normalised points (N, 2)."""
        xn, yn = xy[:, 0], xy[:, 1]
        st, ct = math.sin(self.tilt_rad), math.cos(self.tilt_rad)
        return np.column_stack([-xn, st - yn * ct, ct + yn * st])

    def to_camera(self, rel: np.ndarray) -> np.ndarray:
        """World vectors relative to the camera (N, 3) -> canonical normalised points (N, 2)."""
        st, ct = math.sin(self.tilt_rad), math.cos(self.tilt_rad)
        xc = -rel[:, 0]
        yc = -ct * rel[:, 1] + st * rel[:, 2]
        zc = st * rel[:, 1] + ct * rel[:, 2]
        return np.column_stack([xc / zc, yc / zc])


class Projection:
    """Maps canonical normalised image points to wall coordinates (s, y) and back."""

    name = ""

    def __init__(self, mount: Mount):
        self.mount = mount

    def to_wall(self, xy: np.ndarray) -> np.ndarray:
        raise NotImplementedError

    def to_image(self, sy: np.ndarray) -> np.ndarray:
        raise NotImplementedError

    def incidence_deg(self, xy: np.ndarray) -> np.ndarray:
        """Angle between each ray and the wall normal where it lands (90 = grazing, NaN = miss)."""
        raise NotImplementedError

    @property
    def roll_radius_m(self) -> float:
        """Radius that turns arc displacement into roll about the pipe axis (0: no roll model)."""
        return 0.0


class PixelProjection(Projection):
    """Thesis Method 1 (Eq. 3.1): a constant H metres per unit of normalised image coordinate.

    Exact only for a camera square to a flat wall; kept as the thesis's baseline.
    """

    name = "pixel"

    def to_wall(self, xy):
        h = self.mount.height_m
        return _pairs(h * xy[:, 0], -h * xy[:, 1])

    def to_image(self, sy):
        h = self.mount.height_m
        return np.column_stack([sy[:, 0] / h, -sy[:, 1] / h])

    def incidence_deg(self, xy):
        return np.degrees(np.arctan(np.hypot(xy[:, 0], xy[:, 1])))


class PlaneProjection(Projection):
    """Thesis Method 2 generalised: each ray meets the tangent plane at the crown, any tilt, any pixel."""

    name = "plane"

    def to_wall(self, xy):
        d = self.mount.ray(xy)
        with np.errstate(divide="ignore", invalid="ignore"):
            t = np.where(d[:, 2] > 0, self.mount.height_m / d[:, 2], np.nan)
        return _pairs(-t * d[:, 0], t * d[:, 1])

    def to_image(self, sy):
        rel = np.column_stack([-sy[:, 0], sy[:, 1], np.full(len(sy), self.mount.height_m)])
        return self.mount.to_camera(rel)

    def incidence_deg(self, xy):
        d = self.mount.ray(xy)
        cos_i = d[:, 2] / np.linalg.norm(d, axis=1)
        return np.where(cos_i > 0, np.degrees(np.arccos(np.clip(cos_i, -1, 1))), np.nan)


class CylinderProjection(Projection):
    """Exact: each ray meets the pipe's real cylinder x^2 + z^2 = r^2 from inside."""

    name = "cylinder"

    @property
    def roll_radius_m(self):
        return self.mount.pipe_radius_m

    def _hit(self, xy):
        """Ray parameter and hit point; only the x and z components matter for the circle."""
        r, xc = self.mount.pipe_radius_m, -self.mount.sway_m
        zc = r - self.mount.height_m
        st, ct = math.sin(self.mount.tilt_rad), math.cos(self.mount.tilt_rad)
        xn, yn = xy[:, 0], xy[:, 1]
        dz = ct + yn * st
        a = xn * xn + dz * dz          # dx = -xn
        b = zc * dz - xc * xn
        # camera inside the pipe: c < 0, so the positive root always exists unless the ray is axial
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (np.sqrt(b * b - a * (xc * xc + zc * zc - r * r)) - b) / a
        if not a.all():
            t[a <= 1e-12] = np.nan
        return t, xc - t * xn, zc + t * dz, st - yn * ct

    def to_wall(self, xy):
        t, x, z, dy = self._hit(xy)
        return _pairs(self.mount.pipe_radius_m * np.arctan2(-x, z), t * dy)

    def to_image(self, sy):
        r = self.mount.pipe_radius_m
        phi = sy[:, 0] / r
        rel = np.column_stack([self.mount.sway_m - r * np.sin(phi), sy[:, 1],
                               r * np.cos(phi) - (r - self.mount.height_m)])
        return self.mount.to_camera(rel)

    def incidence_deg(self, xy):
        t, x, z, _ = self._hit(xy)
        d = self.mount.ray(xy)
        cos_i = (d[:, 0] * x + d[:, 2] * z) / (np.linalg.norm(d, axis=1) * self.mount.pipe_radius_m)
        return np.degrees(np.arccos(np.clip(cos_i, -1, 1)))


def make_projection(method: str, mount: Mount) -> Projection:
    """The projection named by [odometry] method (validated in settings.py)."""
    return {"pixel": PixelProjection, "plane": PlaneProjection, "cylinder": CylinderProjection}[method](mount)


def _pairs(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(N, 2) from two (N,) arrays; cheaper than np.column_stack on the per-frame path."""
    out = np.empty((len(a), 2))
    out[:, 0] = a
    out[:, 1] = b
    return out


def roi_outline(roi: tuple[int, int, int, int], n: int = 9) -> np.ndarray:
    """Pixels along the border of an ROI (x, y, w, h): where geometry is worst."""
    x, y, w, h = roi
    xs = np.linspace(x, x + w - 1, n)
    ys = np.linspace(y, y + h - 1, n)
    return np.vstack([np.column_stack([xs, np.full(n, y)]), np.column_stack([xs, np.full(n, y + h - 1)]),
                      np.column_stack([np.full(n, x), ys]), np.column_stack([np.full(n, x + w - 1), ys])])


def check_distortion(camera: Camera, roi) -> None:
    """Refuse distortion coefficients that fold the image over itself inside the ROI.

    A lens model that is not invertible there turns every tracked point into nonsense metres.
    """
    if not any(camera.distortion):
        return
    pts = roi_outline(roi, 17)
    back = camera.to_pixels(camera.normalise(pts))
    err = np.abs(back - pts).max() if np.isfinite(back).all() else np.inf
    if err > 0.01:
        raise BadConfig(f"[camera] distortion = {list(camera.distortion)} cannot be undone inside the ROI "
                        f"(a point comes back {err:.3g} px away); check the coefficients and their order "
                        "[k1, k2, p1, p2, k3]")


def check_view(camera: Camera, projection: Projection, roi, max_incidence_deg: float) -> float:
    """Refuse an ROI whose rays miss the wall or graze it; return the worst incidence in degrees.

    The thesis warns its Eq. 3.3 overflows as the view turns parallel to the wall; long before that,
    a pixel spans centimetres of wall and the measurement is worthless.
    """
    pts = roi_outline(roi)
    xy = camera.normalise(pts)
    inc = projection.incidence_deg(xy)
    if np.any(~np.isfinite(inc)):
        bad = pts[~np.isfinite(inc)][0]
        raise BadGeometry(
            f"[mount] tilt_deg = {projection.mount.tilt_deg:g} puts part of the ROI {list(roi)} above the "
            f"horizon (pixel ({bad[0]:.0f}, {bad[1]:.0f}) never meets the wall); lower the tilt or move "
            "[odometry] roi toward the bottom of the frame")
    worst = float(np.max(inc))
    if worst > max_incidence_deg:
        i = int(np.argmax(inc))
        raise BadGeometry(
            f"[mount] tilt_deg = {projection.mount.tilt_deg:g} with ROI {list(roi)} views the wall at "
            f"{worst:.1f} deg from its normal at pixel ({pts[i][0]:.0f}, {pts[i][1]:.0f}), more than "
            f"[odometry] max_incidence_deg = {max_incidence_deg:g}; lower the tilt or move the ROI "
            "toward the bottom of the frame")
    return worst
