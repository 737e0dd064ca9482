"""The rotation term: each step's turn ``dtheta`` has noise of its own, variance ``k_rot |dtheta|``.

Closed forms from that definition (derived in the docstrings) and consistency by Monte
Carlo against a truth that integrates noisy turns with ``test/oracle.py``'s textbook
arcs. The fast lane's array form against the per-step recursion: test_fastlane.py.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from diffdrive_odom.core.estimation.wheels.encoders import EncoderConfig
from diffdrive_odom.core.estimation.wheels.estimator import OdometryEstimator
from diffdrive_odom.core.geometry.kinematics import Geometry
from diffdrive_odom.core.uncertainty.noise import NoiseModel, UncertaintyConfigError
from diffdrive_odom.settings.errors import ParameterError
from diffdrive_odom.settings.odometry import odometry_settings

import oracle

R, B = 0.05, 0.3
GEOMETRY = Geometry(R, B)
NAMES = ["l", "r"]
ENCODERS = EncoderConfig(("l",), ("r",))
STEP_NS = 50_000_000  # 20 Hz


def _estimator(k: float, k_rot: float) -> OdometryEstimator:
    return OdometryEstimator(GEOMETRY, ENCODERS, noise=NoiseModel(k, k, 0.0, 0.0, k_rot))


def _p3(est: OdometryEstimator) -> np.ndarray:
    assert est.uncertainty is not None
    return np.array(est.uncertainty.pose_covariance(est.pose, est.geometry))


def _drive(est: OdometryEstimator, steps: list[tuple[float, float]]) -> None:
    """Joint increments per step, from a zero reading."""
    left = right = 0.0
    est.update(1, NAMES, [left, right])
    for i, (dl, dr) in enumerate(steps, start=1):
        left, right = left + dl, right + dr
        est.update(1 + i * STEP_NS, NAMES, [left, right])


@pytest.mark.parametrize("k", [0.0, 3e-5])
def test_a_spin_on_the_spot_adds_k_rot_times_the_angle_to_the_heading(k: float) -> None:
    """A spin by ``a`` on the spot (wheel arcs ``-+ b a / 2``): the turn's own term gives
    ``var(theta) = k_rot |a|``; the wheels' term ``k (|s_l| + |s_r|) / b^2 = k |a| / b``
    adds to it. The centre does not move, so the turn's term reaches neither x nor y (the
    wheels' does: their along-path errors move the centre)."""
    k_rot, rad, n = 2e-4, 0.4, 30
    est, base = _estimator(k, k_rot), _estimator(k, 0.0)
    steps = [(-rad, rad)] * 10 + [(rad, -rad)] * (n - 10)  # left, then back right
    _drive(est, steps)
    _drive(base, steps)
    a = R * rad * 2 / B * n  # |angle| turned, both ways summed
    p, p0 = _p3(est), _p3(base)
    assert p[2, 2] == pytest.approx(k_rot * a + k * a / B, rel=1e-12)
    assert np.array_equal(p[:2, :], p0[:2, :])


def test_a_straight_line_is_unchanged_by_the_rotation_term() -> None:
    """No turn, no term: the same floats with ``k_rot`` 0 and 1."""
    with_term, without = _estimator(4e-5, 1.0), _estimator(4e-5, 0.0)
    steps = [(0.6, 0.6)] * 50
    _drive(with_term, steps)
    _drive(without, steps)
    assert np.array_equal(_p3(with_term), _p3(without))


def test_a_full_circle_closed_form() -> None:
    """A circle of radius ``rho`` from the origin, turned ``2 pi`` in N small steps,
    ``k_rot`` alone. A heading error ``e`` at angle ``phi`` (position
    ``p = rho (sin phi, 1 - cos phi)``) swings the end ``q`` (the origin again) by
    ``e (-(q_y - p_y), q_x - p_x)``; summing ``k_rot dphi`` over the circle:
    ``var(x) = k_rot rho^2 int (1 - cos)^2 = 3 pi k_rot rho^2``,
    ``var(y) = k_rot rho^2 int sin^2 = pi k_rot rho^2``,
    ``cov(x, theta) = k_rot rho int (1 - cos) = 2 pi k_rot rho``, ``cov(y, theta) = 0``,
    ``cov(x, y) = 0``, ``var(theta) = 2 pi k_rot``. N steps approximate the integrals
    (the mid-step chord: to O(1/N^2))."""
    k_rot, n = 1e-3, 2000
    rho = 1.0
    dphi = 2 * math.pi / n
    # wheel arcs of a step: (rho -+ b/2) dphi; joint increments: arc / R
    dl, dr = (rho - B / 2) * dphi / R, (rho + B / 2) * dphi / R
    est = _estimator(0.0, k_rot)
    _drive(est, [(dl, dr)] * n)
    end = oracle.integrate([(rho * dphi, dphi)] * n)
    assert math.hypot(end[0], end[1]) < 1e-9  # the oracle's circle closes
    p = _p3(est)
    assert p[2, 2] == pytest.approx(2 * math.pi * k_rot, rel=1e-12)
    assert p[0, 0] == pytest.approx(3 * math.pi * k_rot * rho**2, rel=1e-5)
    assert p[1, 1] == pytest.approx(math.pi * k_rot * rho**2, rel=1e-5)
    assert p[0, 2] == pytest.approx(2 * math.pi * k_rot * rho, rel=1e-5)
    assert abs(p[1, 2]) < 1e-5 * k_rot and abs(p[0, 1]) < 1e-5 * k_rot


def test_the_twist_gains_the_turn_rate_variance() -> None:
    """``w = dtheta / dt``: the term adds ``k_rot |dtheta| / dt^2`` to var(w), nothing to v."""
    k_rot, dl, dr = 3e-4, 0.3, -0.5
    dt = STEP_NS * 1e-9
    est, base = _estimator(2e-5, k_rot), _estimator(2e-5, 0.0)
    _drive(est, [(dl, dr)])
    _drive(base, [(dl, dr)])
    assert est.uncertainty is not None and base.uncertainty is not None
    t, t0 = np.array(est.uncertainty.twist_covariance()), np.array(
        base.uncertainty.twist_covariance())
    dtheta = R * (dr - dl) / B
    assert t[1, 1] - t0[1, 1] == pytest.approx(k_rot * abs(dtheta) / dt**2, rel=1e-12)
    assert t[0, 0] == t0[0, 0] and t[0, 1] == t0[0, 1]


def _chi2_band(dof: int) -> tuple[float, float]:
    """Two-sided 95 % band of a chi-square sum (Wilson-Hilferty)."""
    c = 2.0 / (9.0 * dof)
    lo, hi = (dof * (1 - c + z * math.sqrt(c)) ** 3 for z in (-1.96, 1.96))
    return lo, hi


def _square_nees(k_rot_true: float, k_rot_model: float, runs: int) -> np.ndarray:
    """Squares of 1 m with spins on the spot at the corners; the truth turns each step by
    the wheels' angle plus noise of variance ``k_rot_true |dtheta|`` (no other noise)."""
    rng = np.random.default_rng(11)
    side_steps, turn_steps = 20, 15
    fwd = 1.0 / side_steps / R  # joint increment per straight step
    turn = (math.pi / 2) * (B / 2) / turn_steps / R  # per spin step (left back, right on)
    legs = ([(fwd, fwd)] * side_steps + [(-turn, turn)] * turn_steps) * 4
    out = np.empty(runs)
    for run in range(runs):
        est = _estimator(0.0, k_rot_model)
        _drive(est, legs)
        steps = []
        for dl, dr in legs:
            ds, dth = R * (dl + dr) / 2, R * (dr - dl) / B
            steps.append((ds, dth + rng.normal(0.0, math.sqrt(k_rot_true * abs(dth)))))
        truth = oracle.integrate(steps)
        e = np.array([est.pose.x - truth[0], est.pose.y - truth[1],
                      math.remainder(est.pose.theta - truth[2], 2 * math.pi)])
        out[run] = e @ np.linalg.solve(_p3(est) + 1e-18 * np.eye(3), e)
    return out


def test_nees_with_slipping_turns_is_consistent_only_with_the_term() -> None:
    """Turns that slip: with the true ``k_rot`` the final NEES sum lies in chi-square's
    95 % band; without the term the covariance has no heading variance at all and the
    NEES is far above it."""
    runs = 150
    nees = _square_nees(1e-3, 1e-3, runs)
    lo, hi = _chi2_band(3 * runs)
    assert lo <= nees.sum() <= hi, nees.mean()
    low = _square_nees(1e-3, 1e-4, 40)
    assert low.sum() > _chi2_band(3 * 40)[1], low.mean()


def test_a_bad_rotation_noise_names_its_parameter() -> None:
    with pytest.raises(UncertaintyConfigError, match="rotation_noise_k"):
        NoiseModel(k_rotation=-1e-5)
    with pytest.raises(ParameterError, match="rotation_noise_k"):
        odometry_settings({"wheel_radius": R, "wheel_separation": B,
                           "rotation_noise_k": float("nan")})
    s = odometry_settings({"wheel_radius": R, "wheel_separation": B, "rotation_noise_k": 2e-5})
    assert s.noise is not None and s.noise.k_rotation == 2e-5
