"""The measurement model, built in one place: settings plus the camera a source delivers -> Odometer.

A recording's camera comes from [camera] (FOV or calibration, at the recording's size); the live
camera's from the sensor window plan; the simulator's from its fake camera. Whatever the source,
the same checks run here before the first frame: the lens model must be invertible over the ROI,
and every ROI ray must meet the wall at a usable angle.
"""

from __future__ import annotations

import math

from .calibration import load_calibration
from .errors import BadConfig
from .flow import FlowParams
from .gaps import BridgeParams
from .geometry import Camera, check_distortion, check_view, make_projection
from .odometry import Odometer, OdometryParams
from .pose import PoseEstimator, PoseParams
from .poseport import NullPose
from .ride import MAX_TILT_DEG as RIDE_MAX_TILT_DEG
from .settings import CameraSettings, OdometrySettings, Settings


def recording_camera(c: CameraSettings) -> Camera:
    """The camera of a recording, as [camera] describes it (width x height frames)."""
    kw = dict(hflip=c.hflip, vflip=c.vflip, readout_s=c.readout_s or 0.0)
    if c.calibration:
        cam = load_calibration(c.calibration, **kw)
        if (cam.width, cam.height) != (c.width, c.height):
            if abs(cam.width * c.height - cam.height * c.width) > 0.01 * cam.width * c.height:
                raise BadConfig(
                    f"[camera] calibration is for {cam.width}x{cam.height} frames, another shape than "
                    f"[camera] width/height {c.width}x{c.height}; calibrate at the video's size")
            cam = cam.with_size(c.width, c.height)
        return cam
    return Camera.from_fov(c.width, c.height, c.vfov_deg, c.hfov_deg, distortion=c.distortion or (), **kw)


def thesis_roi(width: int, height: int) -> tuple[int, int, int, int]:
    """The thesis's window: a square under the centre row, centred across, as tall as half the frame."""
    size = min(height // 2, width)
    return ((width - size) // 2, height // 2, size, size)


def resolve_roi(o: OdometrySettings, camera: Camera, default) -> tuple[int, int, int, int]:
    """[odometry] roi if set (checked against the frame), else the source's default."""
    if o.roi is None:
        return tuple(default)
    x, y, rw, rh = o.roi
    w, h = camera.width, camera.height
    if x < 0 or y < 0 or rw < 32 or rh < 32 or x + rw > w or y + rh > h:
        raise BadConfig(f"[odometry] roi = {list(o.roi)} must lie inside the {w}x{h} frame and be at "
                        "least 32x32 pixels")
    return tuple(o.roi)


def odometry_params(o: OdometrySettings) -> OdometryParams:
    fp = FlowParams(max_features=o.max_features, win_px=o.win_px, levels=o.levels,
                    max_roundtrip_px=o.max_roundtrip_px)
    return OdometryParams(flow=fp, min_tracks=o.min_tracks, max_baseline_px=o.max_baseline_px,
                          speed_window_s=o.speed_window_s)


def check_geometry(settings: Settings, camera: Camera, roi) -> float:
    """Refuse a view the odometry cannot measure; return the worst incidence (deg) on the ROI border."""
    o = settings.odometry
    mount = settings.mount.mount()
    check_distortion(camera, roi)
    # the exact model decides whether the view is usable, whatever method then measures
    worst = check_view(camera, make_projection("cylinder", mount), roi, o.max_incidence_deg)
    if o.method == "plane":
        check_view(camera, make_projection("plane", mount), roi, o.max_incidence_deg)
    return worst


def pose_params(settings: Settings) -> PoseParams | None:
    """What the pose estimator assumes of the car, or None when nothing is estimated."""
    o, auto = settings.odometry, settings.mount.tilt_auto
    # unset: pitch, height and sway with a configured tilt; with tilt "auto" alone none: on a shaking car
    # the tilt's own error dominates, and both together measured worse (docs/accuracy.md, "Pose")
    on = o.estimate_pose if o.estimate_pose is not None else not auto and o.method != "pixel"
    # unset: the ride height where its readings hold, a tilt up to MAX_TILT_DEG (steeper, they drift
    # alike and the chain sums them); with tilt auto the pose is read for it and not applied, and the
    # level only at a tilt found up to there
    ride = o.ride_height if o.ride_height is not None else (
        o.estimate_pose is not False if auto else on and abs(settings.mount.tilt_deg) <= RIDE_MAX_TILT_DEG)
    if o.ride_height and (o.estimate_pose is False or o.method == "pixel"):
        raise BadConfig("[odometry] ride_height = true sums the pose estimator's height changes: it needs "
                        "[odometry] estimate_pose unset or true (or set ride_height = false)")
    if not (auto or on):
        return None
    if o.method == "pixel":
        what = '[mount] tilt_deg = "auto"' if settings.mount.tilt_auto else "[odometry] estimate_pose = true"
        raise BadConfig(f'{what} needs [odometry] method = "cylinder" or "plane": the pixel method has no '
                        "tilt or height to estimate")
    read = on or ride
    return PoseParams(auto_tilt=auto, pitch_sigma_deg=o.pitch_jitter_deg if read else 0.0,
                      bounce_sigma_mm=o.bounce_mm if read else 0.0, sway_sigma_mm=o.sway_mm if read else 0.0,
                      ride_height=ride, correct_pose=on,
                      ride_max_tilt_deg=RIDE_MAX_TILT_DEG if auto and o.ride_height is None else math.inf)


def build_odometer(settings: Settings, camera: Camera, default_roi) -> Odometer:
    """The only place outside the tests that makes an Odometer."""
    roi = resolve_roi(settings.odometry, camera, default_roi)
    check_geometry(settings, camera, roi)
    projection = make_projection(settings.odometry.method, settings.mount.mount())
    params = pose_params(settings)
    pose = NullPose(settings.mount.tilt_deg) if params is None else PoseEstimator(camera, projection, roi, params)
    return Odometer(camera, projection, roi, odometry_params(settings.odometry), pose=pose)


def bridge_params(settings: Settings, odometer: Odometer) -> BridgeParams:
    """The bridge's noise model for this mount: a pitch of the camera by pitch_jitter_deg moves
    the image by fy * pitch pixels, which the odometer reads as that many pixels of wall."""
    pitch = math.radians(settings.odometry.pitch_jitter_deg)
    return BridgeParams(pose_sigma_m=odometer.m_per_px * odometer.camera.fy * pitch)


def describe(settings: Settings, camera: Camera, default_roi) -> dict:
    """The derived geometry an operator checks before a run (crawlerd --check-config)."""
    roi = resolve_roi(settings.odometry, camera, default_roi)
    worst = check_geometry(settings, camera, roi)
    pose_params(settings)                 # what a run would refuse, --check-config refuses too
    mount = settings.mount.mount()
    projection = make_projection(settings.odometry.method, mount)
    x, y, w, h = roi
    corners = camera.normalise([[x, y], [x + w - 1, y], [x, y + h - 1], [x + w - 1, y + h - 1]])
    wall = projection.to_wall(corners)
    vfov = 2 * math.atan((camera.height / 2) / camera.fy)
    return {
        "method": settings.odometry.method,
        "camera_height_m": round(mount.height_m, 6),
        "tilt_deg": settings.mount.tilt_deg if settings.mount.tilt_auto else mount.tilt_deg,   # "auto": from 0
        "frame": [camera.width, camera.height],
        "intrinsics": {k: round(getattr(camera, k), 3) for k in ("fx", "fy", "cx", "cy")},
        # thesis Eq. 3.1 at the crown, tilt ignored
        "m_per_px_eq31": round(2 * mount.height_m * math.tan(vfov / 2) / camera.height, 9),
        "m_per_px_centre": round(mount.height_m / camera.fy, 9),
        "roi": list(roi),
        "roi_on_wall_m": {"axial": [round(float(wall[:, 1].min()), 5), round(float(wall[:, 1].max()), 5)],
                          "arc": [round(float(wall[:, 0].min()), 5), round(float(wall[:, 0].max()), 5)]},
        "worst_incidence_deg": round(worst, 2),
        "readout_ms": round(camera.readout_s * 1000, 4),
    }
