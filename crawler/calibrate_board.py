"""Calibration boards: the `--board` text, and finding a board's corners in one grey frame.

A checkerboard is found with cv2.findChessboardCornersSB on a copy scaled to at most DETECT_SIDE_PX
and refined with cv2.cornerSubPix at full resolution. SB rather than the classic
findChessboardCorners: with adaptive thresholding (needed under uneven light) the classic one takes
~0.25 s (640x480, this PC) on each frame in which it does not find the pattern, e.g. every frame when
--board gives the wrong count; SB gives up in ~40 ms. (SB's own corners fitted a rendered lens 5x worse than after
cornerSubPix; with it, both detectors recover the lens to 0.04 px.)
A ChArUco board is found through whichever aruco API the installed OpenCV has: 4.6 (Raspberry Pi OS
Bookworm) has detectMarkers + interpolateCornersCharuco, 4.7 and later have CharucoDetector; both
draw and number the board the same way, so one printed board works with either. A ChArUco board
may be partly out of the frame, which puts corners near the image edges where the distortion is.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import cv2
import numpy as np

from .errors import BadConfig

DETECT_SIDE_PX = 800            # longest side of the copy the checkerboard is searched in
MIN_CHARUCO_CORNERS = 12        # fewer leave a view's pose (and its share of the intrinsics) loose
SUBPIX_CRITERIA = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 40, 0.001)
CHESSBOARD_FLAGS = cv2.CALIB_CB_NORMALIZE_IMAGE
DEFAULT_BOARD = "checkerboard:9x6:25mm"
DEFAULT_DICTIONARY = "DICT_6X6_250"
FORMS = ("checkerboard:COLSxROWS[:SQUARE] (inner corners, e.g. checkerboard:9x6:25mm for a board of "
         "10x7 squares) or charuco:COLSxROWS:SQUARE:MARKER[:DICT] (squares, e.g. charuco:8x11:20mm:15mm:"
         f"{DEFAULT_DICTIONARY})")
_UNITS = {"mm": 1e-3, "cm": 1e-2, "m": 1.0}


@dataclass(frozen=True)
class BoardSpec:
    """checkerboard: cols x rows INNER corners (OpenCV's pattern size); charuco: cols x rows SQUARES."""

    kind: str
    cols: int
    rows: int
    square_m: float = 0.025
    marker_m: float = 0.0
    dictionary: str = DEFAULT_DICTIONARY

    @property
    def corners(self) -> tuple[int, int]:
        """Inner corners across and down."""
        return (self.cols, self.rows) if self.kind == "checkerboard" else (self.cols - 1, self.rows - 1)

    def object_points(self) -> np.ndarray:
        """(N, 3) float32 inner corners of a checkerboard on its plane, metres, row by row (OpenCV's order)."""
        nx, ny = self.corners
        pts = np.zeros((nx * ny, 3), np.float32)
        pts[:, :2] = np.mgrid[0:nx, 0:ny].T.reshape(-1, 2) * self.square_m
        return pts

    def text(self) -> str:
        size = f"{self.square_m * 1000:g}mm"
        if self.kind == "checkerboard":
            return f"checkerboard:{self.cols}x{self.rows}:{size}"
        return f"charuco:{self.cols}x{self.rows}:{size}:{self.marker_m * 1000:g}mm:{self.dictionary}"


def _length(text: str, what: str, whole: str) -> float:
    m = re.fullmatch(r"([0-9]*\.?[0-9]+)(mm|cm|m)", text.strip())
    if not m or float(m.group(1)) <= 0:
        raise BadConfig(f"--board {whole!r}: {what} {text!r} must be a length with its unit, e.g. 25mm")
    return float(m.group(1)) * _UNITS[m.group(2)]


def parse_board(text: str) -> BoardSpec:
    """'checkerboard:9x6:25mm' or 'charuco:8x11:20mm:15mm[:DICT_...]' -> BoardSpec (BadConfig if not)."""
    parts = text.strip().split(":")
    kind = parts[0].lower()
    m = re.fullmatch(r"(\d+)x(\d+)", parts[1].lower()) if len(parts) > 1 else None
    if kind not in ("checkerboard", "charuco") or m is None:
        raise BadConfig(f"--board {text!r} must be {FORMS}")
    cols, rows = int(m.group(1)), int(m.group(2))
    if kind == "checkerboard":
        if len(parts) > 3 or cols < 3 or rows < 3 or cols == rows:
            raise BadConfig(f"--board {text!r}: a checkerboard needs at least 3x3 inner corners and a different "
                            f"count across than down (else its orientation is ambiguous); {FORMS}")
        square = _length(parts[2], "the square size", text) if len(parts) == 3 else 0.025
        return BoardSpec(kind, cols, rows, square)
    if len(parts) not in (4, 5) or cols < 3 or rows < 3:
        raise BadConfig(f"--board {text!r}: a ChArUco board needs at least 3x3 squares, the square and the "
                        f"marker size; {FORMS}")
    square, marker = _length(parts[2], "the square size", text), _length(parts[3], "the marker size", text)
    if marker >= square:
        raise BadConfig(f"--board {text!r}: the marker ({parts[3]}) must be smaller than the square ({parts[2]})")
    dictionary = parts[4].upper() if len(parts) == 5 else DEFAULT_DICTIONARY
    if not dictionary.startswith("DICT_") or not hasattr(cv2.aruco, dictionary):
        raise BadConfig(f"--board {text!r}: {dictionary!r} is not an OpenCV ArUco dictionary (e.g. DICT_4X4_50, "
                        "DICT_5X5_100, DICT_6X6_250)")
    return BoardSpec(kind, cols, rows, square, marker, dictionary)


def _subpix_window(img_pts: np.ndarray, nx: int) -> int:
    """Half-size of cornerSubPix's window: a third of the corner spacing, so it stays on two squares."""
    rows = img_pts.reshape(-1, nx, 2)
    spacing = float(np.median(np.linalg.norm(np.diff(rows, axis=1), axis=2)))
    return int(max(2, min(11, spacing / 3)))


class CheckerboardFinder:
    """Inner corners of a checkerboard, all of them or none (a partly hidden board is not found)."""

    def __init__(self, spec: BoardSpec):
        self.spec = spec
        self.pattern = spec.corners
        self._obj = spec.object_points()

    def find(self, gray: np.ndarray):
        """(object points (N, 3), image points (N, 2)) in float32, or None."""
        h, w = gray.shape[:2]
        scale = min(1.0, DETECT_SIDE_PX / max(h, w))
        small = gray if scale == 1.0 else cv2.resize(gray, (round(w * scale), round(h * scale)),
                                                     interpolation=cv2.INTER_AREA)
        found, corners = cv2.findChessboardCornersSB(small, self.pattern, flags=CHESSBOARD_FLAGS)
        if not found:
            return None
        corners = (corners.reshape(-1, 2) / scale).astype(np.float32)
        win = _subpix_window(corners, self.pattern[0])
        corners = cv2.cornerSubPix(gray, corners.reshape(-1, 1, 2), (win, win), (-1, -1), SUBPIX_CRITERIA)
        return self._obj, corners.reshape(-1, 2)


class CharucoFinder:
    """The ChArUco corners whose neighbouring markers were seen; needs MIN_CHARUCO_CORNERS of them,
    not all on one line of the board."""

    def __init__(self, spec: BoardSpec):
        aruco = cv2.aruco
        self.spec = spec
        self._dictionary = aruco.getPredefinedDictionary(getattr(aruco, spec.dictionary))
        if hasattr(aruco, "CharucoDetector"):               # OpenCV >= 4.7
            board = aruco.CharucoBoard((spec.cols, spec.rows), spec.square_m, spec.marker_m, self._dictionary)
            self._detector = aruco.CharucoDetector(board)
            self._detect = self._detect_47
            corners = board.getChessboardCorners()
        else:                                               # OpenCV 4.6
            self._board = aruco.CharucoBoard_create(spec.cols, spec.rows, spec.square_m, spec.marker_m,
                                                    self._dictionary)
            self._params = aruco.DetectorParameters_create()
            self._detect = self._detect_46
            corners = self._board.chessboardCorners
        self._obj = np.asarray(corners, np.float32).reshape(-1, 3)      # the board's own numbering

    def _detect_47(self, gray):
        corners, ids, _, _ = self._detector.detectBoard(gray)
        return corners, ids

    def _detect_46(self, gray):
        """4.6's corners sit half a pixel off (+0.49, +0.49 px on hw_sim's boards, where 4.7+'s and
        the checkerboard's are unbiased; opencv_contrib issue 3301), so they are refined again with
        cornerSubPix: then 0.08 px RMS from the truth, 4.7+'s own 0.06 px."""
        aruco = cv2.aruco
        markers, marker_ids, _ = aruco.detectMarkers(gray, self._dictionary, parameters=self._params)
        if marker_ids is None or len(marker_ids) == 0:
            return None, None
        _, corners, ids = aruco.interpolateCornersCharuco(markers, marker_ids, gray, self._board)
        if ids is None or len(ids) < MIN_CHARUCO_CORNERS:
            return corners, ids
        win = self._subpix_window(corners.reshape(-1, 2), ids.ravel())
        return cv2.cornerSubPix(gray, corners.reshape(-1, 1, 2), (win, win), (-1, -1), SUBPIX_CRITERIA), ids

    def _subpix_window(self, pts: np.ndarray, ids: np.ndarray) -> int:
        """cornerSubPix's half-window: within the white gap between a square's edge and its marker."""
        nx = self.spec.cols - 1
        where = {int(i): k for k, i in enumerate(ids)}
        steps = [np.linalg.norm(pts[where[i + 1]] - pts[k]) for i, k in where.items()
                 if (i + 1) % nx and i + 1 in where]
        spacing = float(np.median(steps)) if steps else 0.0
        gap = spacing * (self.spec.square_m - self.spec.marker_m) / (2 * self.spec.square_m)
        return int(max(2, min(11, 0.8 * gap)))

    def find(self, gray: np.ndarray):
        corners, ids = self._detect(gray)
        if ids is None or len(ids) < MIN_CHARUCO_CORNERS:
            return None
        ids = ids.ravel().astype(int)
        nx = self.spec.cols - 1
        if len(set(ids % nx)) < 2 or len(set(ids // nx)) < 2:     # all on one row or column: no plane
            return None
        return self._obj[ids], np.asarray(corners, np.float32).reshape(-1, 2)


def make_finder(spec: BoardSpec):
    return CheckerboardFinder(spec) if spec.kind == "checkerboard" else CharucoFinder(spec)
