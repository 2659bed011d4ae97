"""The odometer's tuning: every threshold it uses, with the reason for its value. Pure data."""

from __future__ import annotations

from dataclasses import dataclass, field

from .dense import DenseParams
from .flow import FlowParams


@dataclass(frozen=True)
class OdometryParams:
    flow: FlowParams = field(default_factory=FlowParams)
    min_tracks: int = 8               # fewer agreeing tracks than this: tracking lost
    min_inlier_share: float = 0.5     # fewer agreeing than this share of tracked: lost
    mad_k: float = 3.5                # inlier gate in robust standard deviations
    inlier_floor_px: float = 0.35     # ...but never tighter than this (in pixels at the ROI centre)
    renew_share: float = 0.5          # new keyframe when fewer than this share of its features remain
    renew_floor: float = 2.0          # ...or fewer than this many times min_tracks
    entry_band: float = 0.6           # moving: new features only in this share of the ROI (entry side)
    entry_side_px: float = 2.0        # ...once the wall moves this many rows per frame
    max_baseline_px: float = 120.0    # new keyframe when features moved this far (perspective change)
    max_lost_frames: int = 15         # keep hoping for the old keyframe this long, then start afresh
    max_lost_s: float = 0.5           # ...or this long since the last tracked frame (frames that never came count)
    retry_share: float = 0.6          # fewer of the visible features tracked: retry with the global shift
    min_response: float = 0.03        # weakest phase-correlation peak trusted as a first guess
    speed_window_s: float = 0.25      # least-squares speed over this much recent history
    spread_jump: float = 3.0          # tracks disagreeing this many times more than lately: corrupt frame
    spread_floor_px: float = 0.1      # ...unless they still agree within this
    max_spread_refusals: int = 2      # then believe the new level (the scene changed, not the frame)
    moving_px: float = 3.0            # a step below this many pixels is a standstill for those statistics
    min_span_share: float = 0.2       # rolling shutter: a feature exposed over less of the interval is dropped
    full_quality_tracks: float = 3.0  # quality 1 needs this many times min_tracks agreeing
    min_texture_share: float = 0.25   # less fine texture than this share of the recent frames': not measured
    min_texture_dn: float = 0.3       # ...nor with less than this at all (a black frame)
    faint_texture_dn: float = 0.8     # ...and with less, a stand must be seen coming (a wet wall's noise the
                                      # encoder smoothed, 0.4-0.7, stays put; a dry wall at CRF 40 1.1 and up)
    texture_memory: float = 0.05      # how fast that reference follows the wall (per measured frame)
    max_accel_m_s2: float = 1.5       # a consensus whose speed changed faster than this is refused...
    speed_tol_m_s: float = 0.03       # ...beyond this much noise...
    speed_jitter_k: float = 3.0       # ...and this many times the jitter of the speeds believed lately...
    max_refusal_s: float = 1.0        # ...until it has said the same this long (a collision is real)
    across_s: float = 0.15            # a step over more than this (frames lost or dropped) is a mean speed
    still_px: float = 0.5             # within this (px at the ROI centre) of where a stand began: standing...
    still_slack: float = 0.1          # ...unless the frame is this much less like the stand's picture than the last
    reacquire_share: float = 0.5      # after a restart: this share of the visible features must agree...
    reacquire_spread_px: float = 1.0  # ...within this spread (px at the ROI centre)
    dense: DenseParams = field(default_factory=DenseParams)   # where features cannot be had
