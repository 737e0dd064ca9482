"""How far the wheels' turn over an interval may be from the gyro's when nothing slipped.

Why apart from the decision (:mod:`~.gyro.gyrodometry`): the slip test,
the fusion's weights and the online filter's windows
(:mod:`~diffdrive_odom.core.estimation.online.online_geometry`) need the same account of what a
real robot's wheels get wrong without slipping, and it is measured while driving. Beyond
the wheels' travel noise (:mod:`~diffdrive_odom.core.uncertainty.noise`), three terms:

- **geometry**: the wheels' turn is ``u dphi_R - v dphi_L`` with the ratios ``u = r_R/b``,
  ``v = r_L/b``, known to the noise model's relative sigmas (a geometry a few percent off
  until calibrated is mostly covered by the timing term below, which grows with the turn
  rate; the online estimate is not fed back: see :meth:`RatioModel.of`).
- **quantization**: each reading's joint angle is a whole number of ticks; the turn
  between two readings is off by ``2 q (u^2 + v^2)``, ``q`` a joint's variance per reading.
- **timing**: a driver stamps a reading when it publishes it, not when its counters were
  read. A Kobuki's driver republishes the last counters at 40 Hz while they change every
  50-70 ms; the counters it sends are up to a period old. So the wheels' turn over an
  interval is the turn of a slightly shifted one: off by the turn rate times the
  difference of the two ends' stamp errors. Their sigma is measured from the data
  (:class:`StampJitter`): the robust spread of (wheels' turn - gyro's turn) / turn rate
  over intervals turning faster than :data:`MIN_RATE`, which a constant geometry error
  (a constant offset of that ratio's centre) does not widen.

Readings a driver holds (positions equal to the last while the wheels move) are no
measurement at all: the decision merges them into the next interval
(:data:`HOLD_S`). Pure Python.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass
from statistics import median

from diffdrive_odom.core.geometry.kinematics import Geometry
from diffdrive_odom.core.uncertainty.noise import NoiseModel

__all__ = ["HOLD_S", "MIN_RATE", "RatioModel", "StampJitter", "turn_variance"]

# s: readings with no motion this soon after the wheels last moved are held by the driver
# (no new counters), not a standstill: merged into the next interval that moves.
HOLD_S = 0.25
# rad/s: intervals turning faster than this measure the stamps' jitter.
MIN_RATE = 0.1
# s: the stamps' jitter assumed (1 sigma per stamp) until :data:`JITTER_AFTER` intervals
# measured it: a few ms is what a driver on USB or a serial bus gives.
DEFAULT_JITTER_S = 0.005
JITTER_WINDOW, JITTER_AFTER = 400, 25
JITTER_EVERY = 25  # new shifts between two recomputations (two medians of the window)


@dataclass(frozen=True, slots=True)
class RatioModel:
    """The ratios ``(u, v) = (r_R/b, r_L/b)`` the wheels' turn is taken with.

    With their covariance ``(cuu, cuv, cvv)``, from the noise model's relative sigmas.
    """

    u: float
    v: float
    cuu: float
    cuv: float
    cvv: float

    @classmethod
    def of(cls, geometry: Geometry, noise: NoiseModel) -> RatioModel:
        """A geometry's ratios, known to the noise model's relative sigmas.

        Not the online estimate's: fed back into the slip test, a bag whose wheels slip
        much (the TurtleBot3 sim) let slips into the estimate while its prior was wide,
        and it diverged (1608 windows refused as outliers).
        """
        sep = geometry.separation
        u, v = geometry.right_radius / sep, geometry.left_radius / sep
        rr, sr = noise.radius_stddev_ratio ** 2, noise.separation_stddev_ratio ** 2
        return cls(u, v, u * u * (rr + sr), u * v * sr, v * v * (rr + sr))

    def turn(self, phi_r: float, phi_l: float) -> float:
        """The wheels' turn [rad] for joint increments ``phi_r``, ``phi_l`` [rad]."""
        return self.u * phi_r - self.v * phi_l

    def variance(self, phi_r: float, phi_l: float) -> float:
        """Its variance from the ratios' uncertainty: ``h C h'``, ``h = (phi_r, -phi_l)``."""
        return (self.cuu * phi_r * phi_r - 2.0 * self.cuv * phi_r * phi_l
                + self.cvv * phi_l * phi_l)


class StampJitter:
    """The wheel stamps' timing error [s, 1 sigma per stamp], measured while turning."""

    def __init__(self) -> None:
        self._shifts: deque[float] = deque(maxlen=JITTER_WINDOW)
        self._sigma: float | None = None
        self._fresh = 0  # shifts offered since the sigma was computed

    def offer(self, disagreement: float, rate: float) -> None:
        """One interval: wheels' turn minus the gyro's [rad], the gyro's turn rate [rad/s]."""
        if abs(rate) >= MIN_RATE and math.isfinite(disagreement):
            self._shifts.append(disagreement / rate)
            self._fresh += 1
            if self._fresh >= JITTER_EVERY or len(self._shifts) <= JITTER_AFTER:
                self._sigma = None

    @property
    def measured(self) -> bool:
        """Enough turning intervals to have measured it."""
        return len(self._shifts) >= JITTER_AFTER

    @property
    def sigma(self) -> float:
        """1-sigma of one stamp's error: MAD of the shifts over sqrt(2) (two ends each)."""
        if not self.measured:
            return DEFAULT_JITTER_S
        if self._sigma is None:
            self._fresh = 0
            shifts = list(self._shifts)
            mid = median(shifts)
            self._sigma = 1.4826 * median(abs(s - mid) for s in shifts) / math.sqrt(2.0)
        return self._sigma


def turn_variance(ratios: RatioModel, phi_r: float, phi_l: float,
                  travel: tuple[float, float], quantization: float, jitter: float,
                  rates: tuple[float, float]) -> float:
    """Variance [rad^2] of an interval's wheel turn (see the module).

    ``travel``: the right and left joint increments' travel-noise variances [rad^2];
    ``quantization``: a joint's variance per reading [rad^2]; ``jitter``: a stamp's
    1-sigma [s]; ``rates``: the turn rate at its start and at its end [rad/s].
    """
    u2, v2 = ratios.u * ratios.u, ratios.v * ratios.v
    q = 2.0 * quantization * (u2 + v2) + u2 * travel[0] + v2 * travel[1]
    timing = jitter * jitter * (rates[0] * rates[0] + rates[1] * rates[1])
    return ratios.variance(phi_r, phi_l) + q + timing
