"""The gyro's sample buffer: yaw rates by stamp, integrated over any interval.

Why apart from the gyrodometry decision (:mod:`~diffdrive_odom.core.estimation.gyro.gyrodometry`):
the buffer's rules (which sample is kept, where a hole makes the IMU silent, how a
rate is integrated between samples) are the same whatever is decided with them, and
the decision is easier to read without them. Time is the header stamp in ns; the
rate is linear between samples and held beyond the ends.
"""

from __future__ import annotations

from bisect import bisect_left, bisect_right, insort
from itertools import pairwise

# Samples kept at most (wheels silent while the IMU goes on): 10 s at 1 kHz.
MAX_SAMPLES = 10_000
# Times the smallest step between two rates must recur to be taken as the resolution.
QUANTUM_SEEN = 20


class GyroSamples:
    """Yaw rates [rad/s] by stamp [ns], in stamp order whatever order they came in."""

    def __init__(self) -> None:
        self.ts: list[int] = []
        self.ws: list[float] = []
        # rad/s: the smallest step between two different consecutive rates (a raw gyro's
        # resolution: its values come in whole steps), and how often it was seen.
        self._smallest = 0.0
        self._seen = 0

    @property
    def last(self) -> int | None:
        """The newest stamp (None: no sample)."""
        return self.ts[-1] if self.ts else None

    def clear(self) -> None:
        """Forget every sample (the IMU's clock went back)."""
        self.ts.clear()
        self.ws.clear()

    def insert(self, stamp_ns: int, w: float) -> bool:
        """Keep one sample; False for a duplicate stamp."""
        ts = self.ts
        if self.ws and w != self.ws[-1]:
            self._resolution(abs(w - self.ws[-1]))
        if not ts or stamp_ns > ts[-1]:
            ts.append(stamp_ns)
            self.ws.append(w)
        else:
            i = bisect_left(ts, stamp_ns)
            if ts[i] == stamp_ns:
                return False
            insort(ts, stamp_ns)
            self.ws.insert(i, w)
        if len(ts) > MAX_SAMPLES:
            del ts[0], self.ws[0]
        return True

    def _resolution(self, step: float) -> None:
        if not self._smallest or step < 0.99 * self._smallest:
            self._smallest, self._seen = step, 1
        elif step <= 1.01 * self._smallest:
            self._seen += 1

    @property
    def quantum(self) -> float:
        """The gyro's resolution [rad/s]: its smallest step once seen QUANTUM_SEEN times, else 0.

        A gyro whose values are continuous keeps finding smaller steps and has none.
        """
        return self._smallest if self._seen >= QUANTUM_SEEN else 0.0

    def rounding_variance(self, dt: float) -> float:
        """Variance [rad^2] the resolution adds to an angle integrated over ``dt`` s.

        Each sample's rounding (uniform over a step of :attr:`quantum`) is held over its
        period, independent between samples: ``q^2 / 12 * period * dt``.
        """
        ts, q = self.ts, self.quantum
        period = (ts[-1] - ts[0]) * 1e-9 / (len(ts) - 1) if len(ts) > 1 else 0.0
        return q * q / 12.0 * period * dt

    def prune(self, keep_from: int) -> None:
        """Drop samples no later interval needs (keep the last one at or before ``keep_from``)."""
        i = bisect_right(self.ts, keep_from) - 1
        if i > 0:
            del self.ts[:i], self.ws[:i]

    def rate(self, t: int) -> float:
        """The rate at ``t``: linear between samples, held beyond the ends."""
        ts, ws = self.ts, self.ws
        i = bisect_right(ts, t)
        if i == 0:
            return ws[0]
        if i == len(ts):
            return ws[-1]
        t0, t1 = ts[i - 1], ts[i]
        f = (t - t0) / (t1 - t0)
        return ws[i - 1] + f * (ws[i] - ws[i - 1])

    def integrate(self, a: int, b: int) -> float:
        """``integral of w dt`` [rad] over ``[a, b]`` (stamps in ns), trapezoids on the samples."""
        ts, ws = self.ts, self.ws
        if b <= a or not ts:
            return 0.0
        lo = bisect_right(ts, a)
        hi = bisect_left(ts, b)
        total = 0.0
        t_prev, w_prev = a, self.rate(a)
        for i in range(lo, hi):
            t, w = ts[i], ws[i]
            total += 0.5 * (w + w_prev) * (t - t_prev)
            t_prev, w_prev = t, w
        total += 0.5 * (w_prev + self.rate(b)) * (b - t_prev)
        return total * 1e-9

    def covers(self, a: int, b: int, limit_ns: float) -> bool:
        """True when samples reach within ``limit_ns`` of both ends and no hole is longer."""
        ts = self.ts
        pts = ts[bisect_left(ts, a - limit_ns):bisect_right(ts, b + limit_ns)]
        if not pts or pts[0] > a + limit_ns or pts[-1] < b - limit_ns:
            return False
        return all(q - p <= limit_ns for p, q in pairwise(pts) if q > a and p < b)
