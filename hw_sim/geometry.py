"""Pure geometry of a camera inside a round pipe, in the frames of docs/conventions.md.

World: x lateral (car's right), y along the pipe (travel), z up, wall x^2 + z^2 = r^2.
Camera: OpenCV axes; tilt t pitches the optical axis toward +y. Nothing here keeps state, so the
renderer, the tests and the docs can all check the same formulas.
"""
from __future__ import annotations

import math

import cv2
import numpy as np


def camera_height(diameter_m: float, car_width_m: float, offset_m: float) -> float:
    """Thesis Eq. 3.4: camera-to-crown distance of a car whose wheels touch the wall at x = +-w/2."""
    r = diameter_m / 2
    return r + math.sqrt(4 * r * r - car_width_m**2) / 2 - offset_m


def pinhole(width: int, height: int, hfov_deg: float, vfov_deg: float) -> tuple[float, float, float, float]:
    """(fx, fy, cx, cy) of a sensor whose FOV spans its full width/height (pixel centres at integers)."""
    fx = (width / 2) / math.tan(math.radians(hfov_deg) / 2)
    fy = (height / 2) / math.tan(math.radians(vfov_deg) / 2)
    return fx, fy, (width - 1) / 2, (height - 1) / 2


def window_intrinsics(K: tuple[float, float, float, float], window: tuple[int, int, int, int],
                      out_size: tuple[int, int]) -> tuple[float, float, float, float]:
    """Intrinsics of an output frame that shows sensor rectangle `window` scaled to `out_size`.

    Inverts u = x0 + (u' + 0.5) * w / W' - 0.5: u' = (u - x0 + 0.5) * W'/w - 0.5.
    """
    fx, fy, cx, cy = K
    x0, y0, w, h = window
    sx, sy = out_size[0] / w, out_size[1] / h
    return fx * sx, fy * sy, (cx - x0 + 0.5) * sx - 0.5, (cy - y0 + 0.5) * sy - 0.5


def output_to_sensor(u: np.ndarray, v: np.ndarray, window: tuple[int, int, int, int],
                     out_size: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """Sensor pixel seen by output pixel (u', v') of a cropped/scaled window."""
    x0, y0, w, h = window
    return x0 + (u + 0.5) * w / out_size[0] - 0.5, y0 + (v + 0.5) * h / out_size[1] - 0.5


def normalised_grid(K: tuple[float, float, float, float], window: tuple[int, int, int, int],
                    out_size: tuple[int, int],
                    distortion: tuple[float, ...] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Normalised image coordinates (xn, yn), each (H', W') float64, of every output pixel's ray.

    With distortion the sensor pixel is a *distorted* observation, so it is undistorted
    (cv2.undistortPointsIter, run to convergence) to get the ray.
    """
    W, H = out_size
    u, v = output_to_sensor(np.arange(W, dtype=np.float64), np.arange(H, dtype=np.float64), window, out_size)
    fx, fy, cx, cy = K
    if distortion is None or not any(distortion):
        xn = np.broadcast_to((u - cx) / fx, (H, W))
        yn = np.broadcast_to(((v - cy) / fy)[:, None], (H, W))
        return np.ascontiguousarray(xn), np.ascontiguousarray(yn)
    uu, vv = np.meshgrid(u, v)
    pts = np.stack([uu.ravel(), vv.ravel()], axis=1).reshape(-1, 1, 2)
    Km = np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1]], dtype=np.float64)
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12)
    und = cv2.undistortPointsIter(pts, Km, np.asarray(distortion, np.float64), None, None, crit)
    und = und.reshape(H, W, 2)
    return np.ascontiguousarray(und[..., 0]), np.ascontiguousarray(und[..., 1])


def ray_directions(xn: np.ndarray, yn: np.ndarray, tilt_rad: float):
    """World direction (dx, dy, dz) = xn*x_c + yn*y_c + z_c of rays through normalised points."""
    st, ct = math.sin(tilt_rad), math.cos(tilt_rad)
    return -xn, st - yn * ct, ct + yn * st


def intersect_wall(cam_x: float, cam_z: float, d: tuple[np.ndarray, np.ndarray, np.ndarray], r: float):
    """Where rays from (cam_x, *, cam_z) leave the pipe: (lam, X, Y_rel, Z), point = cam + lam*d.

    Solves (cam_x + lam dx)^2 + (cam_z + lam dz)^2 = r^2 for the positive root (the camera is
    inside, so c < 0 and exactly one root is positive).
    """
    dx, dy, dz = d
    a = dx * dx + dz * dz
    b = cam_x * dx + cam_z * dz            # half the linear coefficient
    c = cam_x * cam_x + cam_z * cam_z - r * r
    lam = (-b + np.sqrt(b * b - a * c)) / a
    return lam, cam_x + lam * dx, lam * dy, cam_z + lam * dz


def wall_arc(X: np.ndarray, Z: np.ndarray, r: float) -> np.ndarray:
    """Arc length s from the crown, positive toward -x (image right at tilt 0)."""
    return r * np.arctan2(-X, Z)


def wall_coords(xn, yn, tilt_rad: float, cam_x: float, cam_z: float, r: float):
    """(y_rel, s, range, cos_incidence) of each pixel's wall point; y_rel is axial, from the camera."""
    d = ray_directions(xn, yn, tilt_rad)
    lam, X, Y, Z = intersect_wall(cam_x, cam_z, d, r)
    norm = np.sqrt(d[0] ** 2 + d[1] ** 2 + d[2] ** 2)
    rng = lam * norm
    cos_inc = (X * d[0] + Z * d[2]) / (r * norm)   # outward wall normal (X, 0, Z)/r
    return Y, wall_arc(X, Z, r), rng, cos_inc


def led_gain(rng: np.ndarray, cos_inc: np.ndarray, H: float, tilt_rad: float) -> np.ndarray:
    """LED at the camera: cos(incidence)/range^2, 1 at the undisturbed principal ray (crown line)."""
    ct = math.cos(tilt_rad)
    ref = ct / (H / ct) ** 2
    return (cos_inc / (rng * rng)) / ref


def vignette(xn: np.ndarray, yn: np.ndarray) -> np.ndarray:
    """cos^4 of the field angle: 1 on the optical axis."""
    q = 1.0 / (1.0 + xn * xn + yn * yn)
    return q * q


def centre_column_speed(theta_rad, tilt_rad: float, H: float, fy: float):
    """Image speed (px per metre of travel) of the centre column at ray angle theta below the axis.

    Along x = 0 the wall is the straight crown line at height H, so v = fy tan(theta) and the wall
    point is y = H tan(t - theta): dv/dy = fy cos^2(t - theta) / (H cos^2 theta).
    """
    return fy * np.cos(tilt_rad - theta_rad) ** 2 / (H * np.cos(theta_rad) ** 2)
