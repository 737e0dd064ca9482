"""The geometry term when the online estimate is applied (issue 25 item 3), closed forms.

``S`` over ``(ln r_L, ln r_R, ln b)`` for radii and separation made from the ratios
``u = r_R / b``, ``v = r_L / b`` with the mean radius held: the heading direction
``ln r_R - ln r_L = ln u - ln v`` carries the ratios' covariance alone, the common
scale the held mean radius's sigma alone. A straight line of length ``L`` with exact
wheels then has ``var y = (L^2 / (2 b))^2 var(ln u - ln v)`` and ``var x = (L / 2)^2
var(ln r_L + ln r_R)`` (written from the rolling model, not from the package's step).
"""

from __future__ import annotations

import math

import pytest

from diffdrive_odom.core.estimation.online.ratios import (
    mean_radius_stddev_ratio,
    ratio_geometry,
    ratio_geometry_covariance,
)
from diffdrive_odom.core.geometry.integration import Pose2D
from diffdrive_odom.core.geometry.kinematics import Geometry
from diffdrive_odom.core.uncertainty.noise import NoiseModel
from diffdrive_odom.core.uncertainty.propagation import PoseUncertainty

U, V = 0.0505 / 0.303, 0.0498 / 0.303
COV = (4e-8, 1.5e-8, 1.5e-8, 3e-8)
SM = 0.0025 / math.sqrt(2.0)


def quad(s: tuple[tuple[float, ...], ...], e: tuple[float, float, float]) -> float:
    return sum(e[i] * s[i][k] * e[k] for i in range(3) for k in range(3))


def test_heading_direction_takes_the_ratios_and_scale_the_configured_sigma() -> None:
    s = ratio_geometry_covariance((U, V), COV, SM)
    cuu, cuv, _, cvv = COV
    var_diff = cuu / U**2 - 2 * cuv / (U * V) + cvv / V**2  # var(ln u - ln v)
    assert quad(s, (-1.0, 1.0, 0.0)) == pytest.approx(var_diff, rel=1e-12)
    # ln b = ln 2m - ln(u + v)
    assert s[2][2] == pytest.approx((cuu + 2 * cuv + cvv) / (U + V) ** 2 + SM**2, rel=1e-12)
    # Without uncertainty on the ratios: the scale direction only, each entry sm^2.
    only_scale = ratio_geometry_covariance((U, V), (0.0, 0.0, 0.0, 0.0), SM)
    assert all(value == pytest.approx(SM**2, rel=1e-12) for row in only_scale for value in row)
    assert mean_radius_stddev_ratio(0.0025) == pytest.approx(SM, rel=1e-15)


def test_a_straight_line_with_the_estimate_in_use() -> None:
    g = Geometry(0.05, 0.3)
    s = ratio_geometry_covariance((U, V), COV, SM)
    unc = PoseUncertainty(NoiseModel(0.0, 0.0, 0.0025, 0.01, 0.0))
    unc.geometry_covariance = s
    pose, n, step = Pose2D(), 200, 0.01  # 2 m in 1 cm steps, straight ahead
    for _ in range(n):
        unc.propagate(pose, g, ds=step, dtheta=0.0, d_left=step / 0.05, d_right=step / 0.05,
                      dt=0.02)
        pose = Pose2D(pose.x + step, 0.0, 0.0)
    cov = unc.pose_covariance(pose, g)
    length, b = n * step, g.separation
    cuu, cuv, _, cvv = COV
    var_diff = cuu / U**2 - 2 * cuv / (U * V) + cvv / V**2
    assert cov[1][1] == pytest.approx((length**2 / (2 * b)) ** 2 * var_diff, rel=1e-9)
    # ln r_L + ln r_R = 2 ln 2m + ln u + ln v - 2 ln(u + v), the scale's sm in each radius
    du, dv = 1 / U - 2 / (U + V), 1 / V - 2 / (U + V)
    var_sum = du * du * cuu + 2 * du * dv * cuv + dv * dv * cvv + 4 * SM**2
    assert cov[0][0] == pytest.approx(length**2 / 4 * var_sum, rel=1e-9)
    assert cov[2][2] == pytest.approx((length / b) ** 2 * var_diff, rel=1e-9)


def test_the_switch_folds_the_stretch_before() -> None:
    """At the switch the published covariance stays what it was; the new S counts after."""
    g = Geometry(0.05, 0.3)
    unc = PoseUncertainty(NoiseModel(0.0, 0.0, 0.0025, 0.01, 0.0))
    pose = Pose2D()
    for _ in range(100):
        unc.propagate(pose, g, ds=0.01, dtheta=0.002, d_left=0.19, d_right=0.21, dt=0.02)
        pose = Pose2D(pose.x + 0.01, pose.y + 0.001, pose.theta + 0.002)
    before = unc.pose_covariance(pose, g)
    unc.switch_geometry(ratio_geometry_covariance((U, V), COV, SM))
    assert unc.pose_covariance(pose, g) == before
    assert unc.sensitivity == ((0.0,) * 3,) * 3


def test_the_geometry_made_of_the_ratios_holds_the_mean_radius() -> None:
    """A geometry's own ratios give it back when its mean radius is held; no estimate
    (ratios summing to zero) gives both wheels the mean radius."""
    r_l, r_r, b = 0.049, 0.0515, 0.31
    got = ratio_geometry((r_r / b, r_l / b), 0.5 * (r_l + r_r))
    assert got == pytest.approx((r_l, r_r, b), rel=1e-15)
    assert ratio_geometry((0.0, 0.0), 0.05) == (0.05, 0.05, 0.0)
