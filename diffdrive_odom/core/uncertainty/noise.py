"""What is random in wheel odometry, per step: the noise model and its defaults.

Pure Python. Two random terms, each with a variance in proportion to what the step did,
so that ten small steps add the same variance as one big one (the model does not depend
on the reading rate) and a robot at rest gains none:

- wheel travel (Chong and Kleeman, "Accurate odometry and error modelling for a mobile
  robot", ICRA 1997): each wheel's ground arc ``d`` is off by zero-mean noise of variance
  ``k |d|``, ``k`` [m] per side; it grows with distance;
- rotation: the heading change ``dtheta`` of a step is off by zero-mean noise of
  variance ``k_rot |dtheta|`` [rad^2], ``k_rot`` [rad] the variance per radian turned,
  independent of the wheels'. It is the slip of turning, on the spot or in an arc
  (tyres scrubbing sideways, the contact patches not points), a random error of the
  turn itself that the wheel-travel term cannot give where little distance is rolled:
  a spin of angle ``a`` on the spot rolls ``b |a| / 2`` per wheel, so the wheel term's
  heading variance ``(k_l + k_r) |a| / (2 b)`` is tiny for a small ``k``. Kelly
  ("Linearized Error Propagation in Odometry") propagates random error of the rotation
  input apart from the translation's. A straight line (``dtheta`` 0) gains nothing.

The random terms are one draw per step; systematic error (wrong radii, separation) is
one draw per robot and is the geometry term of :mod:`~.propagation`. Both forms of the
propagation (the per-step :class:`~.propagation.PoseUncertainty` and the fast lane's
:mod:`~.fastcov`) take each step's variances from the functions here, which accept
floats and numpy arrays alike.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import cast, overload

import numpy as np
import numpy.typing as npt

from diffdrive_odom.core.errors import ConfigError
from diffdrive_odom.core.geometry.kinematics import Geometry

# Defaults for an uncalibrated robot: wheel-travel noise k [m] (a side's arc off by 1 mm,
# 1 sigma, after 1 m rolled), each radius known to 0.25 % and the separation to 1 %
# (1 sigma). Chosen on the June 2020 OptiOdom sessions (Sousa et al.) with the nominal
# geometry and judged on the December/January ones (bench/bench_calibration.py;
# doc/concepts/covariance.md): final-pose mean NEES inside the 95 % band on both.
DEFAULT_K = 1.0e-6
DEFAULT_RADIUS_STDDEV_RATIO = 0.0025
DEFAULT_SEPARATION_STDDEV_RATIO = 0.01
# Rotation noise k_rot [rad]: heading variance per radian turned. Chosen on the June 2020
# OptiOdom sessions by maximum likelihood of the final poses (bench/bench_nees.py): 0, per
# run and with the geometry error shared within an experiment; the June runs reject more
# than about 4e-6. Judged on the December 2020 / January 2021 ones: mean NEES 2.93 in its
# band, 1 of 26 runs above chi-square's 95 % quantile, none above 99.9 %.
DEFAULT_ROTATION_K = 0.0
# What a calibration's values drift between recording sessions (tyres, floor), relative,
# 1 sigma: calibrate adds it to its bootstrap sigma (core.evaluation.crossval.with_drift). Chosen on
# the June 2020 OptiOdom experiments, checked on the Dec 2020 / Jan 2021 ones
# (doc/concepts/calibration.md).
SESSION_DRIFT_RATIO = 0.0019

FloatArray = npt.NDArray[np.float64]


class UncertaintyConfigError(ConfigError):
    """A noise setting that cannot work (names the parameter)."""


@dataclass(frozen=True)
class NoiseModel:
    """Wheel-travel and rotation noise, geometry uncertainty: what the covariance covers.

    ``k`` per side [m]: variance ``k * |arc|`` of each step's ground arc. The ratios: the
    relative 1-sigma uncertainty of each effective radius and of the separation.
    ``k_rotation`` [rad]: variance ``k_rotation * |dtheta|`` of each step's heading change.
    """

    k_left: float = DEFAULT_K
    k_right: float = DEFAULT_K
    radius_stddev_ratio: float = DEFAULT_RADIUS_STDDEV_RATIO
    separation_stddev_ratio: float = DEFAULT_SEPARATION_STDDEV_RATIO
    k_rotation: float = DEFAULT_ROTATION_K

    def __post_init__(self) -> None:
        for field, value in (("wheel_noise_k_left", self.k_left),
                             ("wheel_noise_k_right", self.k_right),
                             ("wheel_radius_stddev_ratio", self.radius_stddev_ratio),
                             ("wheel_separation_stddev_ratio", self.separation_stddev_ratio),
                             ("rotation_noise_k", self.k_rotation)):
            if (isinstance(value, bool) or not isinstance(value, (int, float))
                    or not math.isfinite(value) or value < 0.0):
                raise UncertaintyConfigError(field, f"must be finite and >= 0, got {value!r}")


@overload
def joint_variances(model: NoiseModel, geometry: Geometry, d_left: float, d_right: float
                    ) -> tuple[float, float]: ...
@overload
def joint_variances(model: NoiseModel, geometry: Geometry, d_left: FloatArray,
                    d_right: FloatArray) -> tuple[FloatArray, FloatArray]: ...
def joint_variances(model: NoiseModel, geometry: Geometry, d_left: float | FloatArray,
                    d_right: float | FloatArray
                    ) -> tuple[float | FloatArray, float | FloatArray]:
    """Variance [rad^2] of each joint increment: ``k |r d| / r^2 = k |d| / r``.

    Floats or arrays of them (the fast lane's steps at once).
    """
    # abs() of a float or an array alike (the cast is for mypy, which types abs() of the
    # union as object; the arithmetic is numpy's where the argument is an array).
    return (model.k_left * cast("float", abs(d_left)) / geometry.left_radius,
            model.k_right * cast("float", abs(d_right)) / geometry.right_radius)


@overload
def rotation_variance(model: NoiseModel, dtheta: float) -> float: ...
@overload
def rotation_variance(model: NoiseModel, dtheta: FloatArray) -> FloatArray: ...
def rotation_variance(model: NoiseModel, dtheta: float | FloatArray) -> float | FloatArray:
    """Variance [rad^2] the step's turn adds to its heading change: ``k_rot |dtheta|``.

    Floats or arrays of them (the fast lane's steps at once).
    """
    return model.k_rotation * cast("float", abs(dtheta))


def quantization_variance(ticks_per_revolution: float, wheels_per_side: int) -> float:
    """Variance [rad^2] of one reading's joint angle from counting whole ticks (0 = radians)."""
    if ticks_per_revolution <= 0.0:
        return 0.0
    tick = 2.0 * math.pi / ticks_per_revolution
    return tick * tick / 12.0 / wheels_per_side


def unknown_path(theta: float, ds: float, dtheta: float) -> tuple[tuple[float, ...], ...]:
    """The position covariance [m^2] (3x3, odom frame) a gap's unknown path adds to its arc.

    Over a gap only the wheels' totals are known: the distance ``ds`` along the path and
    the heading change ``dtheta``, not how the turn was spread along it. In the frame at
    the gap's start (heading ``theta``), a path that turns one way spends its length at
    headings ``phi`` between 0 and ``dtheta``, and ends at ``ds`` times the mean of
    ``(cos phi, sin phi)`` over them: from ``ds (1, 0)`` (drove, then turned on the spot)
    to ``ds (cos dtheta, sin dtheta)`` (turned, then drove). The one arc the gap is
    integrated as spends it evenly (its chord). The added covariance is ``ds^2`` times the
    covariance of ``(cos phi, sin phi)`` for ``phi`` uniform on ``[0, dtheta]``, the spread
    of those headings: zero for a straight gap (nothing unknown) or a turn on the spot (no
    distance), ``ds^2 dtheta^2 / 12`` across the path for a small turn; rotated into the
    odom frame. The heading adds nothing: its change is exact from the counts.
    """
    a = dtheta
    if abs(a) < 0.01:  # the series (next terms a^4 smaller): the closed form cancels
        a2 = a * a
        var_c, var_s = a2 * a2 * (1.0 / 45.0 - a2 / 315.0), a2 * (1.0 / 12.0 - a2 / 40.0)
        cov = a * a2 * (-1.0 / 24.0 + 7.0 * a2 / 720.0)
    else:
        mean_c, mean_s = math.sin(a) / a, (1.0 - math.cos(a)) / a
        half = math.sin(2.0 * a) / (4.0 * a)
        var_c = 0.5 + half - mean_c * mean_c
        var_s = 0.5 - half - mean_s * mean_s
        cov = math.sin(a) ** 2 / (2.0 * a) - mean_c * mean_s
    c, s = math.cos(theta), math.sin(theta)
    scale = ds * ds
    xx = scale * (c * c * var_c - 2.0 * c * s * cov + s * s * var_s)
    yy = scale * (s * s * var_c + 2.0 * c * s * cov + c * c * var_s)
    xy = scale * (c * s * (var_c - var_s) + (c * c - s * s) * cov)
    return ((xx, xy, 0.0), (xy, yy, 0.0), (0.0, 0.0, 0.0))
