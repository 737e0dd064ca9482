"""How much later the IMU's stamps are than the wheels', measured from the two turns.

Why: two recorders' or drivers' clocks are only roughly aligned. On phil_train (a navX
board stamped on its own clock, mapped onto the wheels' by the first samples) the same
turn reaches the gyro's stamps 70-180 ms after the wheels' (against the Vicon: the
gyro's 32-40 ms late on every run, the wheels' 30-150 ms early). The slip test compares
the two turns over the same stamps, so a lag is a disagreement wherever the turn rate
changes (it then takes it as stamp jitter and flags less); ``imu_time_offset`` takes it
out of the IMU's stamps.

Measured as the shift of the gyro's stamps that best fits its turn over
:data:`WINDOW_S` windows to the wheels' (least squares with a scale and an offset
fitted per shift: a geometry a few percent off and the gyro's bias must not move it),
over the last :data:`SPAN_S` of stamps, searched within :data:`MAX_LAG_S` in
:data:`STEP_S` steps, once those windows turned :data:`MIN_TURN` rad: a straight drive
says nothing of timing. Its 1-sigma from the fit's curvature at the minimum. The wheels'
turn is taken at the steps the gyrodometry judged (held readings merged), the gyro's
from its samples. Refitted every :data:`EVERY_S` of wheel stamps (numpy, about a
millisecond).
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

__all__ = ["LINE_START", "ImuLag", "LagEstimate"]

WINDOW_S = 0.25
SPAN_S = 60.0
MAX_LAG_S = 0.3
STEP_S = 0.005
MIN_TURN = 1.0  # rad turned (either way, over the windows) before a lag is measured
EVERY_S = 5.0
LINE_START = "IMU stamps "  # how every line about the lag starts (replay finds the node's)
# A lag over this many stamp-jitter sigmas is named: the slip test then takes part of
# every change of turn rate as jitter.
MATTERS_SIGMAS = 2.0


@dataclass(frozen=True, slots=True)
class LagEstimate:
    """``lag`` [s]: the IMU's stamps later than the wheels' (negative: earlier); its 1-sigma.

    Measured on the stamps as used: ``offset`` (``imu_time_offset``) already taken out,
    so the value that takes the whole lag out is :attr:`setting`.
    """

    lag: float
    sigma: float
    turned: float  # rad over the span it was measured on
    offset: float = 0.0  # s: the imu_time_offset in force while it was measured

    @property
    def setting(self) -> float:
        """The ``imu_time_offset`` that takes the lag out: the one in force plus the rest."""
        return self.offset + self.lag

    def matters(self, jitter: float) -> bool:
        """Large enough to matter for the slip test (over MATTERS_SIGMAS of the jitter)."""
        return abs(self.lag) > MATTERS_SIGMAS * max(jitter, self.sigma)

    def measured(self) -> str:
        """What was measured, with the offset in force: the summary's figure."""
        taken = f", imu_time_offset {self.offset:.3f} taken out" if self.offset else ""
        return (f"{LINE_START}{1e3 * self.lag:+.0f} ms +- {1e3 * self.sigma:.0f} ms after the "
                f"wheels' (over {self.turned:.1f} rad of turns{taken})")

    def line(self, jitter: float) -> str:
        """One line for a log or /diagnostics: the figure, and why no value is advised.

        Where it matters, the setting is named but not advised: without a reference
        nothing tells whether it helps (:meth:`checked_line`: with one). On the simulated
        TurtleBot3 bag the turns give +70 ms and 0.070 makes its end error worse; on
        phil_train's runs 0 and 2 the Vicon confirms the clocks' lag, yet the end error
        too is worse with it (doc/concepts/gyro.md).
        """
        text = self.measured()
        if self.matters(jitter):
            text += (f": {self._why(jitter)}; imu_time_offset: {self.setting:.3f} would take "
                     "it out, not advised unchecked: a lag fitted from the turns need not be "
                     "the clocks' (wheels that slip as a turn starts lag the body too), and "
                     "then the offset makes the odometry worse; replay --eval of a bag with "
                     "ground truth checks it")
        return text

    def checked_line(self, jitter: float, before_m: float, after_m: float) -> str:
        """The line once a reference judged :attr:`setting`; advised only if not worse.

        ``before_m``, ``after_m``: this run's end error without it and with it.
        """
        text = f"{self.measured()}: {self._why(jitter)}; "
        ends = f"this bag's end error {before_m:.4f} -> {after_m:.4f} m"
        if after_m <= before_m:
            return text + f"imu_time_offset: {self.setting:.3f} takes it out ({ends} with it)"
        return text + f"imu_time_offset {self.setting:.3f} is not advised: {ends} with it"

    def _why(self, jitter: float) -> str:
        return (f"more than the wheel stamps' jitter ({1e3 * jitter:.1f} ms), so the slip "
                "test is the less sensitive")


class ImuLag:
    """The wheels' cumulative turn and the gyro's rates over the last span, and the fit."""

    def __init__(self, offset: float = 0.0) -> None:
        self._offset = offset  # s: imu_time_offset, already out of the gyro's stamps
        self._wheels: deque[tuple[int, float]] = deque()  # (stamp, cumulative turn)
        self._gyro: deque[tuple[int, float]] = deque()  # (stamp, yaw rate) as they came
        self._turn = 0.0
        self._fitted_at: int | None = None
        self.estimate: LagEstimate | None = None

    @property
    def seconds(self) -> float:
        """The lag last measured [s], 0 until there is one."""
        return 0.0 if self.estimate is None else self.estimate.lag

    def clear(self, offset: float | None = None) -> None:
        """Forget both streams (a clock went back); the last estimate stays.

        ``offset``: imu_time_offset changed (the stamps kept were shifted by the old one);
        the last estimate keeps its own, so its setting stays right.
        """
        if offset is not None:
            self._offset = offset
        self._wheels.clear()
        self._gyro.clear()
        self._turn = 0.0

    def gyro(self, stamp_ns: int, rate: float) -> None:
        """One IMU sample's yaw rate [rad/s]."""
        self._gyro.append((stamp_ns, rate))
        while self._gyro and stamp_ns - self._gyro[0][0] > (SPAN_S + 2 * MAX_LAG_S) * 1e9:
            self._gyro.popleft()

    def wheels(self, t0: int, t1: int, turn: float) -> None:
        """One judged step ``t0 -> t1`` and the wheels' turn over it [rad]; refit when due."""
        w = self._wheels
        if not w or w[-1][0] != t0:
            w.append((t0, self._turn))
        self._turn += turn
        w.append((t1, self._turn))
        while w and t1 - w[0][0] > SPAN_S * 1e9:
            w.popleft()
        if self._fitted_at is None or t1 - self._fitted_at >= EVERY_S * 1e9:
            self._fitted_at = t1
            self.estimate = self._fit() or self.estimate

    def _fit(self) -> LagEstimate | None:
        if len(self._wheels) < 4 or len(self._gyro) < 4:
            return None
        tw, cw = (np.array(c, dtype=float) for c in zip(*self._wheels, strict=True))
        order = np.argsort([t for t, _ in self._gyro], kind="stable")
        g = np.array(self._gyro, dtype=float)[order]
        tg, rate = g[:, 0], g[:, 1]
        heading = np.concatenate(([0.0], np.cumsum(0.5 * (rate[1:] + rate[:-1]) * np.diff(tg))))
        edges = np.arange(tw[0], tw[-1], WINDOW_S * 1e9)
        if len(edges) < 8:
            return None
        dw = np.diff(np.interp(edges, tw, cw))
        turned = float(np.sum(np.abs(dw)))
        if turned < MIN_TURN:
            return None
        shifts = np.arange(-MAX_LAG_S, MAX_LAG_S + 0.5 * STEP_S, STEP_S)
        at = edges[None, :] + shifts[:, None] * 1e9
        inside = (at[:, 0] >= tg[0]) & (at[:, -1] <= tg[-1])
        if inside.sum() < 5:
            return None
        dg = np.diff(np.interp(at, tg, heading) * 1e-9, axis=1)
        # Per shift, the residual of dw on (dg, 1): Syy - Sxy^2 / Sxx, centred.
        x = dg - dg.mean(axis=1, keepdims=True)
        y = dw - dw.mean()
        sxx, sxy = np.einsum("ij,ij->i", x, x), x @ y
        with np.errstate(divide="ignore", invalid="ignore"):
            sse = np.where(inside & (sxx > 0.0), float(y @ y) - sxy * sxy / sxx, np.inf)
        best = int(np.argmin(sse))
        if not (0 < best < len(shifts) - 1 and np.isfinite(sse[best - 1:best + 2]).all()):
            return None  # at the search's edge or beside a gap: no minimum to trust
        curvature = (sse[best - 1] - 2.0 * sse[best] + sse[best + 1]) / STEP_S ** 2
        resid = sse[best] / max(len(dw) - 3, 1)
        sigma = math.sqrt(2.0 * resid / curvature) if curvature > 0.0 else math.inf
        return LagEstimate(float(shifts[best]), sigma, turned, self._offset)
