"""The geometry's uncertainty when the gyro's estimate of the ratios is in use.

Pure Python. ``online_calibration: apply``
(:mod:`~diffdrive_odom.core.estimation.online.online_geometry`) integrates with radii and a
separation made from the estimated ratios ``u = r_R / b``, ``v = r_L / b`` with the
configured mean radius ``m`` held: ``r_R = 2 m u / s``, ``r_L = 2 m v / s``, ``b = 2 m /
s``, ``s = u + v``. The published covariance then takes that geometry's uncertainty in
place of the configured ``diag(sr^2, sr^2, sb^2)``: in the relative errors ``(ln r_L,
ln r_R, ln b)`` of :mod:`~.propagation`'s geometry term,

    S = A C A^T + sm^2 1 1^T,   A = d(ln r_L, ln r_R, ln b) / d(u, v)
      = [[-1/s, 1/v - 1/s], [1/u - 1/s, -1/s], [-1/s, -1/s]]

with ``C`` the ratios' 2x2 covariance and ``sm`` the relative 1-sigma of the held mean
radius: the scale, which rotation cannot observe, keeps the configured geometry's
uncertainty (two radii known to ``sr`` each: ``sm = sr / sqrt(2)``). Scaling all three
together (the direction ``1 1 1``) leaves every heading change as it was, so the
heading's geometry term comes from ``C`` alone.
"""

from __future__ import annotations

import math

from diffdrive_odom.core.geometry.kinematics import Geometry
from diffdrive_odom.core.geometry.mat3 import Matrix, symmetric

__all__ = ["mean_radius_stddev_ratio", "multipliers", "ratio_geometry", "ratio_geometry_covariance"]


def mean_radius_stddev_ratio(radius_stddev_ratio: float) -> float:
    """Relative 1-sigma of the mean of two radii, each known to ``radius_stddev_ratio``."""
    return radius_stddev_ratio / math.sqrt(2.0)


def ratio_geometry(ratios: tuple[float, float], mean_radius: float
                   ) -> tuple[float, float, float]:
    """``(r_L, r_R, b)`` made of ``(u, v) = (r_R / b, r_L / b)``, ``mean_radius`` held.

    The module's formula; ratios summing to zero or less (no estimate) give the mean
    radius for both wheels and no separation (0).
    """
    u, v = ratios
    s = u + v
    if not s > 0.0:
        return mean_radius, mean_radius, 0.0
    return 2.0 * mean_radius * v / s, 2.0 * mean_radius * u / s, 2.0 * mean_radius / s


def ratio_geometry_covariance(ratios: tuple[float, float],
                              covariance: tuple[float, float, float, float],
                              scale_stddev_ratio: float) -> Matrix:
    """``S`` over ``(ln r_L, ln r_R, ln b)`` for a geometry made of ``ratios`` (see the module).

    ``ratios``: ``(u, v) = (r_R / b, r_L / b)``; ``covariance``: theirs, row-major 2x2;
    ``scale_stddev_ratio``: ``sm``, the held mean radius's relative 1-sigma.
    """
    u, v = ratios
    cuu, cuv, _, cvv = covariance
    inv_s = 1.0 / (u + v)
    rows = ((-inv_s, 1.0 / v - inv_s), (1.0 / u - inv_s, -inv_s), (-inv_s, -inv_s))

    def entry(i: int, k: int) -> float:
        (a0, a1), (b0, b1) = rows[i], rows[k]
        return a0 * b0 * cuu + (a0 * b1 + a1 * b0) * cuv + a1 * b1 * cvv + scale2

    scale2 = scale_stddev_ratio * scale_stddev_ratio
    return symmetric(entry(0, 0), entry(0, 1), entry(0, 2), entry(1, 1), entry(1, 2),
                     entry(2, 2))


def multipliers(g: Geometry, ratios: tuple[float, float],
                cov: tuple[float, float, float, float]
                ) -> tuple[tuple[float, float, float], tuple[float, float, float]]:
    """The multipliers of ddc's YAML from the ratios (mean radius held), with 1-sigma.

    With ``s = u + v`` and the mean radius ``m``: ``r_R = 2 m u / s``, ``r_L = 2 m v /
    s``, ``b = 2 m / s``; the sigmas through their Jacobian in ``(u, v)``.
    """
    u, v = ratios
    s = u + v
    m = 0.5 * (g.left_radius + g.right_radius)
    rl, rr, sep = ratio_geometry(ratios, m)
    values = (rl / g.wheel_radius, rr / g.wheel_radius, sep / g.wheel_separation)
    kr, kb = 2.0 * m / g.wheel_radius, 2.0 * m / g.wheel_separation
    s2 = s * s
    jac = ((-kr * v / s2, kr * u / s2), (kr * v / s2, -kr * u / s2), (-kb / s2, -kb / s2))
    a, b, c, d = cov
    sig = tuple(math.sqrt(max(j0 * j0 * a + j0 * j1 * (b + c) + j1 * j1 * d, 0.0))
                for j0, j1 in jac)
    return values, (sig[0], sig[1], sig[2])
