"""The two small estimators inside the fusion. Pure: no I/O, no logging, no clock.

SlipDetector compares the wheel (with its learned scale) and vision over a sliding window of
seconds: a wheel running ahead of vision beyond the noise of both is slip. ScaleLearner is a scalar
Kalman filter of the wheel scale, fed with stretches where both measured and agreed.
"""

from __future__ import annotations

import math
from collections import deque


class SlipDetector:
    """Window residual r = k·(W − W0) − (V − V0) against a threshold built from the noise budget.

    state: +1 the wheel runs ahead (slip), −1 it lags (skid, lifted wheel), 0 they agree. A state
    starts above the threshold and ends below `release` times it (hysteresis), so noise around the
    threshold cannot make the flag chatter.
    """

    def __init__(self, window_s: float, n_sigma: float, ratio: float, release: float,
                 quantum_m: float, noise: float):
        self.window_s, self.n_sigma, self.ratio, self.release = window_s, n_sigma, ratio, release
        self.quantum_m, self.noise = quantum_m, noise
        self._s: deque[tuple[float, float, float]] = deque()
        self.state = 0
        self.ahead = 0.0        # last window residual, signed along the wheel's travel
        self.threshold = 0.0

    def clear(self):
        self._s.clear()
        self.state = 0
        self.ahead = 0.0

    def restart(self):
        """Keep only the newest sample: the window starts afresh (after a slip ended)."""
        while len(self._s) > 1:
            self._s.popleft()
        self.state = 0
        self.ahead = 0.0

    def shift(self, dv: float):
        """Vision's count moved its past by dv (a gap settled): the window's samples move with it."""
        self._s = deque((t, v + dv, w) for t, v, w in self._s)

    @property
    def oldest(self):
        return self._s[0] if self._s else None

    @property
    def newest(self):
        return self._s[-1] if self._s else None

    def update(self, t: float, v: float, w: float, k: float, var_k: float, var_v: float) -> int:
        """Add the frame (time, vision distance, nominal wheel distance); return the new state."""
        s = self._s
        s.append((t, v, w))
        cut = t - self.window_s
        while s[0][0] < cut:
            s.popleft()
        t0, v0, w0 = s[0]
        dw = w - w0
        kdw = k * dw
        r = kdw - (v - v0)
        ahead = r if dw > 0 else (-r if dw < 0 else -abs(r))
        kq = k * self.quantum_m
        var = (2.0 * var_v + kq * kq / 6.0 + var_k * dw * dw
               + (self.noise * kdw) ** 2 / max(len(s) - 1, 1))
        thr = max(self.n_sigma * math.sqrt(var), self.ratio * abs(kdw), 3.0 * kq)
        self.ahead, self.threshold = ahead, thr
        if self.state == 0:
            if abs(ahead) > thr:
                self.state = 1 if ahead > 0 else -1
        elif abs(ahead) < self.release * thr:
            self.state = 0
        elif abs(ahead) > thr and (ahead > 0) != (self.state > 0):
            self.state = -self.state
        return self.state

    def _ahead_since(self, i: int, k: float) -> float:
        t1, v1, w1 = self._s[-1]
        _, vi, wi = self._s[i]
        dw = w1 - wi
        r = k * dw - (v1 - vi)
        return r if dw > 0 else (-r if dw < 0 else -abs(r))

    def onset_t(self, k: float) -> float:
        """When the disagreement began: the last sample from which the whole residual is seen."""
        s = self._s
        full = abs(self._ahead_since(0, k))
        for i in range(len(s) - 1, -1, -1):
            if abs(self._ahead_since(i, k)) >= full - 0.5 * self.threshold:
                return s[i][0]
        return s[0][0]

    def agree_since_t(self, k: float) -> float:
        """When they agreed again: the first sample after which the residual stays in the noise."""
        s = self._s
        for i in range(len(s)):
            if abs(self._ahead_since(i, k)) <= 0.5 * self.threshold:
                return s[i][0]
        return s[-1][0]


class ScaleLearner:
    """k = true metres per nominal wheel metre; P its variance.

    Measurements are stretches of at least `chunk_m` of wheel travel: y = vision distance,
    h = nominal wheel distance, y = k·h + noise. P grows with distance travelled (wear, load,
    debris change the effective radius). A stretch whose innovation is beyond `gate` sigma is
    refused; `relearn_after` refusals in a row mean the wheel really changed, and P is reopened.
    """

    def __init__(self, scale: float, sigma: float, *, quantum_m: float, noise: float,
                 drift: float = 0.002, chunk_m: float = 0.25, gate: float = 4.0,
                 relearn_after: int = 3, min_chunk_m: float = 0.02):
        self.k = scale
        self.P = sigma * sigma
        self.prior_var = sigma * sigma
        self.quantum_m, self.noise, self.drift = quantum_m, noise, drift
        self.chunk_m, self.gate, self.relearn_after, self.min_chunk_m = chunk_m, gate, relearn_after, min_chunk_m
        self.refused = 0
        self.accepted = 0
        self.last_pair = None        # (y, h) of the last stretch offered, for diagnosis
        self._anchor = None          # (vision, wheel) at the stretch's start
        self._frames = 0

    @property
    def sigma(self) -> float:
        return math.sqrt(self.P)

    def travel(self, metres: float):
        self.P += self.drift * self.drift * abs(metres)

    def relearn(self):
        self.P = max(self.P, self.prior_var)
        self.refused = 0

    def extend(self, v: float, w: float, var_v: float):
        """A clean sample (both measured, agreed): measure once the stretch is long enough."""
        if self._anchor is None:
            self._anchor, self._frames = (v, w), 0
            return
        self._frames += 1
        if abs(w - self._anchor[1]) >= self.chunk_m:
            self._measure(v, w, var_v)
            self._anchor, self._frames = (v, w), 0

    def close(self, v: float, w: float, var_v: float):
        """The clean stretch ends here (vision lost, slip): use it if long enough, then forget it."""
        if self._anchor is not None and abs(w - self._anchor[1]) >= self.min_chunk_m:
            self._frames += 1
            self._measure(v, w, var_v)
        self._anchor = None

    def drop(self):
        self._anchor = None

    def shift(self, dv: float):
        """Vision's count moved its past by dv (a gap settled): the stretch's start moves with it."""
        if self._anchor is not None:
            self._anchor = (self._anchor[0] + dv, self._anchor[1])

    def _measure(self, v, w, var_v) -> bool:
        y, h = v - self._anchor[0], w - self._anchor[1]
        self.last_pair = (y, h)
        kq = self.k * self.quantum_m
        R = 2.0 * var_v + kq * kq / 6.0 + (self.noise * self.k * h) ** 2 / max(self._frames, 1)
        e = y - self.k * h
        S = h * h * self.P + R
        if e * e > self.gate * self.gate * S:
            self.refused += 1
            if self.refused < self.relearn_after:
                return False
            self.relearn()
            S = h * h * self.P + R
        K = self.P * h / S
        self.k = min(5.0, max(0.2, self.k + K * e))
        self.P *= max(1.0 - K * h, 1e-6)
        self.refused = 0
        self.accepted += 1
        return True
