"""What the annotated video shows, drawn with OpenCV: pure functions of an image and the numbers.

The inspection overlay is the one operators know from sewer CCTV: a dark bar along the top with the
pipe and the date and time, one along the bottom with the footage counter in the run's unit to a
tenth and the survey direction. Under it, smaller, the odometry's own view: the region measured
(green while tracking, red when lost), each feature's track from its keyframe, the principal row.
Text scales with the frame, so a 240x240 live window reads as well as a 960x720 recording.
"""

from __future__ import annotations

import cv2
import numpy as np

FONT = cv2.FONT_HERSHEY_SIMPLEX
WHITE, BLACK, YELLOW = (255, 255, 255), (0, 0, 0), (0, 255, 255)


def _text(img, text: str, org, scale: float, colour=WHITE, thick: int = 1):
    cv2.putText(img, text, org, FONT, scale, BLACK, thick + 2, cv2.LINE_AA)
    cv2.putText(img, text, org, FONT, scale, colour, thick, cv2.LINE_AA)


def draw_tracks(img, roi, camera, points, origins, tracking: bool):
    x, y, w, h = roi
    cv2.rectangle(img, (x, y), (x + w - 1, y + h - 1), (0, 200, 0) if tracking else (0, 0, 255), 2)
    if len(points) and len(origins) == len(points):
        lines = np.stack([origins, points], axis=1).round().astype(np.int32)
        cv2.polylines(img, list(lines), False, (0, 200, 255), 1, cv2.LINE_AA)
    for p in points.round().astype(int):
        cv2.circle(img, (int(p[0]), int(p[1])), 3, YELLOW, -1)
    cy = int(camera.cy)
    cv2.circle(img, (int(camera.cx), cy), 4, (255, 128, 0), -1)
    cv2.line(img, (0, cy), (img.shape[1] - 1, cy), (255, 128, 0), 1)


def draw_odometry(img, est):
    """The numbers behind the footage: distance, speed, time, tracks and quality (small, upper left)."""
    s = img.shape[1] / 1200.0
    speed = "--" if est.speed_m_s is None else f"{est.speed_m_s:+.3f} m/s"
    lines = [f"distance {est.distance_m:+.4f} m  speed {speed}", f"t {est.t_s:.3f} s  frame {est.frame}",
             f"tracks {est.inliers}/{est.tracks}  q {est.quality:.2f}" + ("" if est.tracking else "  LOST")]
    bar = int(40 * s) + 8
    for i, text in enumerate(lines):
        _text(img, text, (int(8 * s) + 2, bar + int(26 * s) * (i + 1)), 0.6 * s, thick=1)


def draw_inspection(img, footage: str, direction: str, pipe_id: str, when: str):
    """The CCTV overlay: pipe and date on a top bar, the footage counter large on a bottom bar."""
    h, w = img.shape[:2]
    s = w / 960.0
    bar = max(int(40 * s), 14)
    img[:bar] = (img[:bar] * 0.35).astype(img.dtype)
    img[h - int(1.4 * bar):] = (img[h - int(1.4 * bar):] * 0.35).astype(img.dtype)
    _text(img, pipe_id or "crawlerd", (int(8 * s) + 2, bar - int(10 * s) - 2), 0.8 * s, thick=max(1, int(2 * s)))
    (tw, _), _ = cv2.getTextSize(when, FONT, 0.8 * s, 1)
    _text(img, when, (w - tw - int(10 * s) - 2, bar - int(10 * s) - 2), 0.8 * s, thick=max(1, int(2 * s)))
    _text(img, footage, (int(8 * s) + 2, h - int(12 * s) - 2), 1.3 * s, YELLOW, thick=max(1, int(3 * s)))
    tag = {"downstream": "DS", "upstream": "US"}.get(direction, "")
    (tw, _), _ = cv2.getTextSize(tag, FONT, 1.0 * s, 2)
    _text(img, tag, (w - tw - int(10 * s) - 2, h - int(14 * s) - 2), 1.0 * s, thick=max(1, int(2 * s)))
