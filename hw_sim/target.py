"""Calibration targets seen by a distorted pinhole camera, with the intrinsics as ground truth.

A flat printed board (a checkerboard, or a ChArUco board from OpenCV's own generator) moves through
poses in front of a camera with OpenCV's radial/tangential distortion, as an operator waves it in
front of the crawler's lens. Each output pixel's ray (undistorted once, as the pipe renderer does)
meets the board's plane through the homography of the pose; the board texture is sampled there on a
supersampled grid and box-filtered to the pixel, so edges are anti-aliased the way a sensor
integrates them. Shares no code with crawler/: it is the instrument calibration is measured with.

    from hw_sim.target import Board, TargetCamera, board_poses, write_board_video
    cam = TargetCamera(640, 480, fx=520, fy=518, cx=322, cy=236, distortion=(-0.25, 0.08, 0, 0, 0))
    write_board_video("board.h264", Board("checkerboard", 10, 7, 0.025), cam, board_poses(cam, ...))
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from . import geometry as geo
from .errors import BadValue
from .io import H264Writer

TEXELS_PER_SQUARE = 96
MARGIN_SQUARES = 0.5                              # white paper around the squares
BLACK, WHITE, BACKGROUND = 35.0, 215.0, 120.0     # grey levels of the print and the room behind it


@dataclass(frozen=True)
class Board:
    """A printed board: `cols` x `rows` squares of `square_m`; ChArUco markers of `marker_m`."""

    kind: str                       # "checkerboard" or "charuco"
    cols: int
    rows: int
    square_m: float
    marker_m: float = 0.0
    dictionary: str = "DICT_6X6_250"

    def __post_init__(self):
        if self.kind not in ("checkerboard", "charuco"):
            raise BadValue(f"board kind {self.kind!r} must be checkerboard or charuco")
        if self.cols < 3 or self.rows < 3 or not self.square_m > 0:
            raise BadValue(f"board {self.cols}x{self.rows} squares of {self.square_m} m: need >= 3x3, size > 0")
        if self.kind == "charuco" and not 0 < self.marker_m < self.square_m:
            raise BadValue(f"marker_m = {self.marker_m} must be between 0 and square_m = {self.square_m}")

    @property
    def inner_corners(self) -> tuple[int, int]:
        return self.cols - 1, self.rows - 1

    @property
    def size_m(self) -> tuple[float, float]:
        return self.cols * self.square_m, self.rows * self.square_m


def board_texture(board: Board, texels_per_square: int = TEXELS_PER_SQUARE) -> np.ndarray:
    """The board as printed, float32 grey, one square = texels_per_square texels, top-left square black,
    on paper with a white margin of MARGIN_SQUARES squares (the quiet zone detectors need)."""
    n = texels_per_square
    if board.kind == "checkerboard":
        j, i = np.meshgrid(np.arange(board.cols * n) // n, np.arange(board.rows * n) // n)
        img = np.where((i + j) % 2 == 0, 0, 255).astype(np.uint8)
    else:
        img = _charuco_image(board, n)
    m = int(MARGIN_SQUARES * n)
    img = cv2.copyMakeBorder(img, m, m, m, m, cv2.BORDER_CONSTANT, value=255)
    return (BLACK + (WHITE - BLACK) * (img.astype(np.float32) / 255.0)).astype(np.float32)


def _charuco_image(board: Board, n: int) -> np.ndarray:
    """OpenCV's own drawing of the board (what an operator prints), on 4.6's API or 4.7's."""
    aruco = cv2.aruco
    dictionary = aruco.getPredefinedDictionary(getattr(aruco, board.dictionary))
    size = (board.cols * n, board.rows * n)
    if hasattr(aruco, "CharucoDetector"):        # OpenCV >= 4.7
        cb = aruco.CharucoBoard((board.cols, board.rows), board.square_m, board.marker_m, dictionary)
        return cb.generateImage(size, marginSize=0, borderBits=1)
    cb = aruco.CharucoBoard_create(board.cols, board.rows, board.square_m, board.marker_m, dictionary)
    return cb.draw(size, marginSize=0, borderBits=1)


@dataclass(frozen=True)
class TargetCamera:
    """Intrinsics (pixel centres at integers) and OpenCV distortion k1, k2, p1, p2, k3 of the frames."""

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    distortion: tuple[float, ...] = (0.0, 0.0, 0.0, 0.0, 0.0)

    @property
    def matrix(self) -> np.ndarray:
        return np.array([[self.fx, 0, self.cx], [0, self.fy, self.cy], [0, 0, 1]], dtype=np.float64)

    def project(self, pts_m: np.ndarray, rvec, tvec) -> np.ndarray:
        """Board-plane points (N, 3) in metres -> distorted pixels (N, 2)."""
        px, _ = cv2.projectPoints(np.asarray(pts_m, np.float64).reshape(-1, 1, 3), np.asarray(rvec, np.float64),
                                  np.asarray(tvec, np.float64), self.matrix, np.asarray(self.distortion, np.float64))
        return px.reshape(-1, 2)


class BoardRenderer:
    """Frames of one board seen by one camera; the per-pixel rays are computed once."""

    def __init__(self, board: Board, camera: TargetCamera, supersample: int = 2, blur_px: float = 0.6,
                 noise_sigma: float = 1.5, seed: int = 0):
        self.board, self.camera, self.ss = board, camera, supersample
        self.blur_px, self.noise_sigma = blur_px, noise_sigma
        self.texture = board_texture(board)
        self.texels_per_m = TEXELS_PER_SQUARE / board.square_m
        c = camera
        sub = (c.width * supersample, c.height * supersample)
        xn, yn = geo.normalised_grid((c.fx, c.fy, c.cx, c.cy), (0, 0, c.width, c.height), sub, c.distortion)
        self._rays = np.stack([xn.ravel(), yn.ravel(), np.ones(xn.size)])      # (3, N) on the sub-grid
        self._rng = np.random.default_rng(seed)

    def render(self, rvec, tvec) -> np.ndarray:
        """The uint8 frame of the board in pose (rvec, tvec): board frame -> camera frame, metres."""
        R = cv2.Rodrigues(np.asarray(rvec, np.float64))[0]
        plane = np.column_stack([R[:, 0], R[:, 1], np.asarray(tvec, np.float64).ravel()])
        uvw = np.linalg.inv(plane) @ self._rays                # board (X, Y, 1) up to scale, per ray
        c, s = self.camera, self.ss
        in_front = uvw[2] > 1e-12
        w = np.where(in_front, uvw[2], 1.0)
        off = MARGIN_SQUARES * TEXELS_PER_SQUARE - 0.5           # board origin -> texel centres
        mx = np.where(in_front, uvw[0] / w * self.texels_per_m + off, -1e6).astype(np.float32)
        my = np.where(in_front, uvw[1] / w * self.texels_per_m + off, -1e6).astype(np.float32)
        shape = (c.height * s, c.width * s)
        fine = cv2.remap(self.texture, mx.reshape(shape), my.reshape(shape), cv2.INTER_LINEAR,
                         borderMode=cv2.BORDER_CONSTANT, borderValue=BACKGROUND)
        img = cv2.resize(fine, (c.width, c.height), interpolation=cv2.INTER_AREA)    # box filter
        if self.blur_px > 0:
            img = cv2.GaussianBlur(img, (0, 0), self.blur_px)
        if self.noise_sigma > 0:
            img = img + self._rng.normal(0.0, self.noise_sigma, img.shape)
        return np.clip(np.rint(img), 0, 255).astype(np.uint8)


def _rotation(rx_deg: float, ry_deg: float, rz_deg: float) -> np.ndarray:
    rx, ry, rz = (math.radians(a) for a in (rx_deg, ry_deg, rz_deg))
    Rx = cv2.Rodrigues(np.array([rx, 0.0, 0.0]))[0]
    Ry = cv2.Rodrigues(np.array([0.0, ry, 0.0]))[0]
    Rz = cv2.Rodrigues(np.array([0.0, 0.0, rz]))[0]
    return Rz @ Ry @ Rx


def pose_looking_at(board: Board, camera: TargetCamera, u: float, v: float, distance_m: float,
                    rx_deg: float = 0.0, ry_deg: float = 0.0, rz_deg: float = 0.0):
    """(rvec, tvec) of the board turned by rx, ry, rz with its centre on pixel (u, v) at distance_m."""
    R = _rotation(rx_deg, ry_deg, rz_deg)
    xy = cv2.undistortPoints(np.array([[[u, v]]], np.float64), camera.matrix,
                             np.asarray(camera.distortion, np.float64)).ravel()
    ray = np.array([xy[0], xy[1], 1.0])
    centre = np.array([board.size_m[0] / 2, board.size_m[1] / 2, 0.0])
    t = distance_m * ray / np.linalg.norm(ray) - R @ centre
    return cv2.Rodrigues(R)[0].ravel(), t


def fully_in_view(board: Board, camera: TargetCamera, rvec, tvec, margin_px: float = 4.0) -> bool:
    """All four outer corners of the board's squares inside the frame, `margin_px` from its edges."""
    w, h = board.size_m
    px = camera.project(np.array([[0, 0, 0], [w, 0, 0], [0, h, 0], [w, h, 0]], float), rvec, tvec)
    return bool(((px[:, 0] >= margin_px) & (px[:, 0] <= camera.width - 1 - margin_px)
                 & (px[:, 1] >= margin_px) & (px[:, 1] <= camera.height - 1 - margin_px)).all())


def board_poses(board: Board, camera: TargetCamera, keyposes: int = 16, frames_between: int = 5,
                seed: int = 0) -> list[tuple[np.ndarray, np.ndarray]]:
    """A hand-held sweep: key poses all over the frame (centre, edges, corners), near and far, turned
    up to +-40 deg, each fully in view; the frames between them interpolated (a smooth wave)."""
    rng = np.random.default_rng(seed)
    keys = []
    fit = camera.fx * board.size_m[0] / camera.width      # distance at which the board spans the width
    while len(keys) < keyposes:
        u = rng.uniform(0.2, 0.8) * camera.width
        v = rng.uniform(0.2, 0.8) * camera.height
        dist = fit * rng.uniform(1.1, 2.2)
        angles = rng.uniform(-40, 40, 2).tolist() + [rng.uniform(-20, 20)]
        pose = pose_looking_at(board, camera, u, v, dist, *angles)
        if fully_in_view(board, camera, *pose):
            keys.append(pose)
    out = []
    for (r0, t0), (r1, t1) in zip(keys, keys[1:]):
        for k in range(frames_between):
            a = k / frames_between
            out.append(((1 - a) * r0 + a * r1, (1 - a) * t0 + a * t1))
    out.append(keys[-1])
    return out


def write_board_video(path: str | Path, board: Board, camera: TargetCamera, poses, fps: float = 10.0,
                      crf: int = 18, **render_kw) -> Path:
    """Render `poses` into a raw H.264 file (hw_sim's encoder, as the Pi records); returns its path."""
    path = Path(path)
    renderer = BoardRenderer(board, camera, **render_kw)
    with H264Writer(path, camera.width, camera.height, fps, crf=crf) as enc:
        for rvec, tvec in poses:
            enc.write(renderer.render(rvec, tvec))
    return path
