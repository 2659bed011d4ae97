"""The car's ride height: how much higher than the mount it rides over sediment or debris. Pure: no I/O.

The flow shows a height only as a change: a camera that rises zooms the image against its keyframe
(crawler/pose.py reads that change to ~0.1 mm per keyframe). Its level does not show in one frame
(on the cylinder the curvature the ROI sees makes 1 mm of level a 0.0004 px pattern), but it
scales every metre: 15 mm of sediment under a 226 mm camera reads 6.6 % long. The level is the sum
of the changes, one per keyframe (the chain), with two limits the physics sets:

- the chain also sums each change's reading error, a random walk of ~0.6 mm per sqrt(m): it is
  remembered over `memory_m` of travel only, and a level is applied only once the chain, smoothed
  over `window_m` against the bounce, stands `k_sigma` of its own noise (the walk and the bounce
  that is left) off the mount. Below that a smooth run gets no level, so nothing of the walk. The
  bounce left is what the window averages in time, but at least what it averages over the handovers
  in it: each reads the height at one instant, and a slow car's keyframe spans several bounces;
  that scatter is read from the changes themselves (`_sampled`);
- a level that is gone again (the chain back within half the threshold) is let go, and none is
  applied while that noise is above `max_sigma` of the height (heavy compression, shake: their
  readings are biased beyond their scatter, and the chain would run away with them).

On by default with a configured tilt up to MAX_TILT_DEG (`[odometry] ride_height` unset): a steep
tilt (at 40 deg the features grow as they come nearer: 0.1-0.2 mm per keyframe, against 0.03 mm at
24 deg and none at 0) biases every reading alike, and the chain sums them. So does a configured
tilt more than ~2 deg off, or a wall that tracks badly: the noise gate holds most of those.

docs/odometry.md, "Ride height", has the figures.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from .consensus import FadingMean

SAMPLED_RATE = 0.1      # the sampled scatter is remembered over ~10 handovers...
SAMPLED_MIN = 5         # ...and known after 5: before, no level
MAX_TILT_DEG = 30.0     # steeper, the readings drift (40 deg: a false level on two of the runs measured)


@dataclass(frozen=True)
class RideParams:
    memory_m: float = 5.0       # the chain is remembered over this much travel while no level is applied
    window_m: float = 0.03      # the chain is smoothed over this much travel: the bounce averages out
    k_sigma: float = 5.0        # a level is applied once it stands this many of its sigma off the mount
                                # (4 put false levels on photographed walls: docs/odometry.md)
    max_sigma: float = 0.01     # ...and only while that sigma is within this share of the height


class RideHeight:
    """The camera's ride height against the mount, from the height changes at keyframe handovers."""

    def __init__(self, height_m: float, params: RideParams | None = None):
        self.p = params or RideParams()
        self.height_m = height_m
        self.chain = 0.0          # the summed changes (metres of height below the crown; - : higher)
        self.chain_var = 0.0      # ...and the variance of their summed reading errors
        self.smooth = 0.0         # the chain, smoothed over window_m
        self.level_m = 0.0        # the applied level: 0 until it is significant
        self.sigma_m = 0.0        # the smoothed chain's noise when no level is there
        self.spent_sigma_m = 0.0  # what the levels applied leave in the distance: their sigma times the metres
        self.sampled = FadingMean(SAMPLED_RATE)   # the height's own scatter about its trend, as the handovers sample it
        self._last_change = None

    def handover(self, change_m: float, var_m2: float, moved_m: float, dt_s: float,
                 bounce_m: float, bounce_tau_s: float) -> float:
        """One keyframe's height change against the last one (reading and its variance), over
        moved_m of travel and dt_s; bounce_m, bounce_tau_s: the bounce the tracks show. Returns
        the level to apply from now on (metres added to the mount's height)."""
        moved = abs(moved_m)
        if not (math.isfinite(change_m) and math.isfinite(var_m2)) or moved <= 0.0:
            return self.level_m
        self.spent_sigma_m += moved * self.sigma_m / self.height_m if self.level_m else 0.0   # one level: linear
        keep = 1.0 if self.level_m else math.exp(-moved / self.p.memory_m)   # a bank found is held
        self.chain = keep * self.chain + change_m
        self.chain_var = keep * keep * self.chain_var + var_m2
        a = min(1.0, moved / self.p.window_m)
        self.smooth += a * (self.chain - self.smooth)
        window_s = dt_s * self.p.window_m / moved        # the window in time at this speed
        left = bounce_m * bounce_m * bounce_tau_s / (bounce_tau_s + window_s)   # the bounce a low-pass leaves
        left = max(left, self._sampled(change_m) * a / (2.0 - a))
        self.sigma_m = math.sqrt(self.chain_var + left)
        threshold = self.p.k_sigma * self.sigma_m
        sure = self.sigma_m <= self.p.max_sigma * self.height_m and self.sampled.n >= SAMPLED_MIN
        if sure and (abs(self.smooth) > threshold or (self.level_m and abs(self.smooth) > 0.5 * threshold)):
            self.level_m = self.smooth
        else:
            self.level_m = 0.0
        return self.level_m

    def _sampled(self, change_m: float) -> float:
        """The variance of the height about its trend at the handovers, from the changes read: a
        bounce that the keyframes sample at one instant each (a slow car: one keyframe spans
        several bounces) is not averaged by the window in time, only over the samples in it.
        Successive changes share their middle height, so c_k - c_(k-1) = h_k - 2 h_(k-1) + h_(k-2):
        its square is 6 times the variance, and a bank's steady rise drops out of it."""
        if self._last_change is not None:
            self.sampled.add((change_m - self._last_change) ** 2 / 6.0)
        self._last_change = change_m
        return self.sampled.value
