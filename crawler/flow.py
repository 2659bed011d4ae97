"""Feature detection and checked Lucas–Kanade tracking on grey ROIs. Pure: no I/O, no state.

All tuning sits in one frozen FlowParams. (OpenCV's Python binding cannot take a prebuilt pyramid in
calcOpticalFlowPyrLK — a list is not accepted as InputArray there — so each LK call builds its own.)
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np


@dataclass(frozen=True)
class FlowParams:
    max_features: int = 30          # Shi–Tomasi corners per keyframe (docs/performance.md)
    quality_level: float = 0.01     # corner strength relative to the strongest one
    min_distance_px: int = 8        # spread features over the ROI
    block_size: int = 7
    win_px: int = 9                 # LK window (odd)
    levels: int = 1                 # pyramid levels above full resolution (the guess is good)
    iterations: int = 10
    epsilon_px: float = 0.01
    max_roundtrip_px: float = 0.5   # forward–backward check
    check_backward: bool = True     # the backward LK call of that check (half the tracking cost)
    coarse_level: int = 2           # pyramid level of the phase-correlation first guess

    @property
    def lk_kwargs(self) -> dict:
        return dict(winSize=(self.win_px, self.win_px), maxLevel=self.levels,
                    criteria=(cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT,
                              self.iterations, self.epsilon_px),
                    flags=cv2.OPTFLOW_USE_INITIAL_FLOW)


def coarse_image(img: np.ndarray, params: FlowParams) -> np.ndarray:
    """The low-resolution copy used for the global phase-correlation guess, as float32."""
    f = 2 ** params.coarse_level
    h, w = img.shape
    small = cv2.resize(img, (-(-w // f), -(-h // f)), interpolation=cv2.INTER_AREA)
    return small.astype(np.float32)


def detect(img: np.ndarray, params: FlowParams, border_px: int = 0) -> np.ndarray:
    """Shi–Tomasi corners (N, 2) float32, kept border_px away from the ROI edge."""
    mask = None
    if border_px:
        mask = np.zeros(img.shape, np.uint8)
        mask[border_px:-border_px, border_px:-border_px] = 255
    pts = cv2.goodFeaturesToTrack(img, params.max_features, params.quality_level,
                                  params.min_distance_px, mask=mask, blockSize=params.block_size)
    if pts is None:
        return np.empty((0, 2), np.float32)
    return pts.reshape(-1, 2)


def coarse_shift(prev: np.ndarray, cur: np.ndarray, window: np.ndarray, scale: float):
    """Global image shift prev -> cur by phase correlation: ((dx, dy) in full-res px, response)."""
    (dx, dy), response = cv2.phaseCorrelate(prev, cur, window)
    return np.array([dx * scale, dy * scale]), float(response)


def track(img0: np.ndarray, img1: np.ndarray, pts0: np.ndarray, guess: np.ndarray, params: FlowParams):
    """Track pts0 from image 0 into image 1 starting at guess; check by tracking back.

    Returns (pts1, ok, roundtrip_px). A point is ok when both directions converge and the
    backward track lands within max_roundtrip_px of where it started.
    """
    if len(pts0) == 0:
        return pts0.copy(), np.zeros(0, bool), np.zeros(0, np.float32)
    p0 = np.ascontiguousarray(pts0, np.float32).reshape(-1, 1, 2)
    p1 = np.ascontiguousarray(guess, np.float32).reshape(-1, 1, 2).copy()
    lk = params.lk_kwargs
    p1, st1, _ = cv2.calcOpticalFlowPyrLK(img0, img1, p0, p1, **lk)
    if not params.check_backward:
        return p1.reshape(-1, 2), st1.ravel() == 1, np.zeros(len(p0), np.float32)
    back, st2, _ = cv2.calcOpticalFlowPyrLK(img1, img0, p1, p0.copy(), **lk)
    roundtrip = np.linalg.norm((back - p0).reshape(-1, 2), axis=1)
    ok = (st1.ravel() == 1) & (st2.ravel() == 1) & (roundtrip < params.max_roundtrip_px)
    return p1.reshape(-1, 2), ok, roundtrip
