"""Propagated covariance: closed forms, properties, and consistency by Monte Carlo.

The wheel-travel noise model is Chong and Kleeman's ("Accurate odometry and error
modelling for a mobile robot", ICRA 1997): each wheel's ground arc over a step is off
by zero-mean noise of variance ``k |arc|``. Expected values come from that definition
(closed forms derived in the docstrings) or from simulating it: the Monte Carlo truth
integrates noisy wheel arcs, and a geometry drawn per run, with ``test/oracle.py``'s
textbook arcs, never with the code under test.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from diffdrive_odom.core.estimation.pipeline import ReadingPipeline
from diffdrive_odom.core.estimation.wheels.encoders import EncoderConfig
from diffdrive_odom.core.estimation.wheels.estimator import OdometryEstimator
from diffdrive_odom.core.geometry.kinematics import Geometry, wheel_rates
from diffdrive_odom.core.uncertainty.noise import DEFAULT_K, NoiseModel
from diffdrive_odom.core.uncertainty.propagation import (
    COVARIANCE_FLOOR,
    ROLLING_CONSTRAINT_VARIANCE,
    UNOBSERVED_VARIANCE,
    covariance_matrix,
    pose_message_covariance,
    twist_message_covariance,
)
from diffdrive_odom.settings.errors import ParameterError
from diffdrive_odom.settings.odometry import odometry_settings

import oracle

R, B = 0.05, 0.3
GEOMETRY = Geometry(R, B)
NAMES = ["l", "r"]
ENCODERS = EncoderConfig(("l",), ("r",))
STEP_NS = 50_000_000  # 20 Hz


def _estimator(k_left: float, k_right: float, encoders: EncoderConfig = ENCODERS,
               geometry: Geometry = GEOMETRY, radius_ratio: float = 0.0,
               separation_ratio: float = 0.0) -> OdometryEstimator:
    """The wheel-noise part alone unless the geometry ratios are given."""
    return OdometryEstimator(geometry, encoders, noise=NoiseModel(
        k_left, k_right, radius_ratio, separation_ratio))


def _p3(est: OdometryEstimator) -> np.ndarray:
    assert est.uncertainty is not None
    return np.array(est.uncertainty.pose_covariance(est.pose, est.geometry))


# --- closed forms ---------------------------------------------------------------------


def test_straight_line_closed_form() -> None:
    """N equal steps of length h along x (s = N h), both wheels with noise k.

    Linearised about the straight path, a step's errors are ``w_s = (e_l + e_r) / 2``
    along the path and ``w_t = (e_r - e_l) / b`` in heading, with
    ``var(e) = k h``: ``var(w_s) = k h / 2``, ``var(w_t) = 2 k h / b^2``, independent.
    x only sees the along-path errors: ``var(x) = N k h / 2 = k s / 2``. Heading is
    their sum: ``var(theta) = 2 k s / b^2``. The chord of step i points at the mid-step
    heading, so ``dy_i = h (theta_{i-1} + w_t,i / 2)`` and the coefficient of
    ``w_t,j`` in y is ``h (N - j + 1/2)``; summing its square over j:
    ``var(y) = h^2 var(w_t) (N^3 / 3 - N / 12) = (2 k / b^2)(s^3 / 3 - s h^2 / 12)``,
    ``cov(y, theta) = h var(w_t) N^2 / 2 = k s^2 / b^2``, ``cov(x, .) = 0``.
    """
    k, rad, n = 4e-5, 0.6, 80
    est = _estimator(k, k)
    est.update(1, NAMES, [0.0, 0.0])
    h = R * rad
    last_var_x = -1.0
    for i in range(1, n + 1):
        est.update(1 + i * STEP_NS, NAMES, [i * rad, i * rad])
        p = _p3(est)
        s = i * h
        assert p[0, 0] == pytest.approx(k * s / 2, rel=1e-12)
        assert p[0, 0] > last_var_x  # grows with distance
        last_var_x = p[0, 0]
    s = n * h
    assert p[2, 2] == pytest.approx(2 * k * s / B**2, rel=1e-12)
    assert p[1, 1] == pytest.approx(2 * k / B**2 * (s**3 / 3 - s * h**2 / 12), rel=1e-9)
    assert p[1, 2] == pytest.approx(k * s**2 / B**2, rel=1e-9)
    assert abs(p[0, 1]) < 1e-15 and abs(p[0, 2]) < 1e-15
    # Different noise per side: var(x) = (k_l + k_r) s / 4, var(theta) = (k_l + k_r) s / b^2.
    est = _estimator(1e-5, 7e-5)
    est.update(1, NAMES, [0.0, 0.0])
    est.update(1 + STEP_NS, NAMES, [rad, rad])
    p = _p3(est)
    assert p[0, 0] == pytest.approx(8e-5 * h / 4, rel=1e-12)
    assert p[2, 2] == pytest.approx(8e-5 * h / B**2, rel=1e-12)


def test_geometry_term_on_a_straight_line_grows_with_distance_squared() -> None:
    """Straight along x, s = N h, no wheel noise, radii uncertain by ``sr`` each (relative).

    A relative radius error ``e_l`` scales the left arcs: the path's length by
    ``s e_l / 2`` and the heading by ``-s e_l / b`` at the end, growing along the way, so
    ``y`` collects ``-(h^2 / b) sum_j (N - j + 1/2) = -s^2 / (2 b)`` per unit ``e_l``
    (the chord at the mid-step heading, as in the closed form above). Both wheels
    independent: ``var(x) = sr^2 s^2 / 2``, ``var(theta) = 2 sr^2 s^2 / b^2``,
    ``var(y) = sr^2 s^4 / (2 b^2)``, ``cov(y, theta) = sr^2 s^3 / b^2``. The separation
    scales the heading change, which is zero here: no term from ``sb``.
    """
    sr, n, rad = 0.01, 60, 0.6
    est = _estimator(0.0, 0.0, radius_ratio=sr, separation_ratio=0.05)
    est.update(1, NAMES, [0.0, 0.0])
    h = R * rad
    for i in range(1, n + 1):
        est.update(1 + i * STEP_NS, NAMES, [i * rad, i * rad])
        s = i * h
        assert _p3(est)[0, 0] == pytest.approx(sr**2 * s**2 / 2, rel=1e-12)
    p = _p3(est)
    assert p[2, 2] == pytest.approx(2 * sr**2 * s**2 / B**2, rel=1e-12)
    assert p[1, 1] == pytest.approx(sr**2 * s**4 / (2 * B**2), rel=1e-9)
    assert p[1, 2] == pytest.approx(sr**2 * s**3 / B**2, rel=1e-9)
    assert abs(p[0, 1]) < 1e-15 and abs(p[0, 2]) < 1e-15
    est.reset()  # reset clears the sensitivity too
    assert est.uncertainty is not None and not np.any(_p3(est))


def test_geometry_term_of_a_spin_on_the_spot() -> None:
    """A spin by ``phi`` (wheels ``-+ b phi / 2``): the heading error is the radius error's
    ``phi / 2`` per wheel and the separation error's ``-phi``. One wrong radius also moves
    the centre (by at most half that wheel's travel times its error)."""
    sr, sb, rad = 0.004, 0.02, 3.0
    est = _estimator(0.0, 0.0, radius_ratio=sr, separation_ratio=sb)
    est.update(1, NAMES, [0.0, 0.0])
    for i in range(1, 11):
        est.update(1 + i * STEP_NS, NAMES, [-i * rad, i * rad])
    phi = 2 * R * 10 * rad / B
    p = _p3(est)
    assert p[2, 2] == pytest.approx(2 * sr**2 * (phi / 2) ** 2 + sb**2 * phi**2, rel=1e-12)
    travel = R * 10 * rad
    assert p[0, 0] + p[1, 1] <= 2 * (sr * travel / 2) ** 2 * (1 + 1e-12)


def test_twist_covariance_from_the_same_model_and_dt() -> None:
    """v = (s_l + s_r) / 2 dt, w = (s_r - s_l) / b dt with var(s) = k |s|, per step."""
    kl, kr, dl, dr = 2e-5, 5e-5, 0.3, -0.5  # joint increments [rad]
    dt = STEP_NS * 1e-9
    est = _estimator(kl, kr)
    est.update(1, NAMES, [0.0, 0.0])
    est.update(1 + STEP_NS, NAMES, [dl, dr])
    assert est.uncertainty is not None
    t = np.array(est.uncertainty.twist_covariance())
    vl, vr = kl * abs(R * dl), kr * abs(R * dr)
    assert t[0, 0] == pytest.approx((vl + vr) / 4 / dt**2, rel=1e-12)
    assert t[1, 1] == pytest.approx((vl + vr) / B**2 / dt**2, rel=1e-12)
    assert t[0, 1] == pytest.approx((vr - vl) / (2 * B) / dt**2, rel=1e-12)


def test_quantization_is_a_floor_not_a_per_step_variance() -> None:
    """Standing still, the pose covariance is the two readings' quantization, at any rate.

    One tick is ``2 pi / tpr`` rad; a reading is off by a uniform error of variance
    ``tick^2 / 12`` per wheel; the pose depends on the reference and the current
    reading only (the increments telescope): ``var(theta) = 2 * 2 (r tick)^2 / 12 / b^2``.
    """
    tpr = 1000.0
    encoders = EncoderConfig(("l",), ("r",), ticks_per_revolution=tpr)
    expected = 4 * (R * 2 * math.pi / tpr) ** 2 / 12 / B**2
    for rate_steps in (10, 1000):  # 10 and 1000 readings of the same standstill
        est = _estimator(1e-4, 1e-4, encoders)
        for i in range(rate_steps + 1):
            est.update(1 + i * 1_000_000, NAMES, [5.0, 7.0])
        assert _p3(est)[2, 2] == pytest.approx(expected, rel=1e-12)


def test_message_layout_is_planar() -> None:
    p = ((1.0, 0.1, 0.2), (0.1, 2.0, 0.3), (0.2, 0.3, 3.0))
    m = np.array(pose_message_covariance(p)).reshape(6, 6)
    np.testing.assert_array_equal(m[np.ix_([0, 1, 5], [0, 1, 5])],
                                  np.array(p) + COVARIANCE_FLOOR * np.eye(3))
    assert [m[i, i] for i in (2, 3, 4)] == [UNOBSERVED_VARIANCE] * 3
    assert (m == m.T).all() and np.count_nonzero(m) == 9 + 3
    t = np.array(twist_message_covariance(((4.0, 0.5), (0.5, 6.0)))).reshape(6, 6)
    assert (t[0, 0], t[0, 5], t[5, 0], t[5, 5]) == (
        4.0 + COVARIANCE_FLOOR, 0.5, 0.5, 6.0 + COVARIANCE_FLOOR)
    assert t[1, 1] == ROLLING_CONSTRAINT_VARIANCE
    assert [t[i, i] for i in (2, 3, 4)] == [UNOBSERVED_VARIANCE] * 3
    assert (t == t.T).all() and np.count_nonzero(t) == 4 + 1 + 3


# --- properties -----------------------------------------------------------------------


steps_strategy = st.lists(
    st.tuples(st.floats(-3.0, 3.0), st.floats(-3.0, 3.0), st.integers(1, 200)),
    min_size=1, max_size=60)


@settings(derandomize=True, max_examples=150, deadline=None)
@given(steps=steps_strategy, k_left=st.floats(0.0, 1e-2), k_right=st.floats(0.0, 1e-2),
       tpr=st.sampled_from([0.0, 64.0, 2796.8]))
def test_covariance_stays_a_covariance_and_reset_restores_the_start(
    steps: list[tuple[float, float, int]], k_left: float, k_right: float, tpr: float
) -> None:
    encoders = EncoderConfig(("l",), ("r",), ticks_per_revolution=tpr)
    est = _estimator(k_left, k_right, encoders)
    assert est.uncertainty is not None
    start = est.uncertainty.covariance
    t, left, right = 1, 0.0, 0.0
    est.update(t, NAMES, [left, right])
    for d_left, d_right, ms in steps:
        t += ms * 1_000_000
        left, right = left + d_left, right + d_right
        est.update(t, NAMES, [left, right])
        for m in (_p3(est), np.array(est.uncertainty.twist_covariance())):
            assert np.isfinite(m).all()
            assert (m == m.T).all()
            scale = max(1.0, float(np.abs(m).max()))
            assert np.linalg.eigvalsh(m).min() >= -1e-12 * scale
    est.reset()
    assert est.uncertainty.covariance == start
    assert est.uncertainty.twist_covariance() == ((0.0, 0.0), (0.0, 0.0))


# --- consistency: NEES over a Monte Carlo of the simulated base -------------------------


def _chi2_quantile(p: float, dof: int) -> float:
    """Wilson-Hilferty: (X / nu)^(1/3) is close to normal, mean 1 - 2/(9 nu), var 2/(9 nu).

    Within 1e-4 relative of the exact quantile for the hundreds of degrees of freedom
    used here (scipy is not a dependency of the package).
    """
    z = {0.025: -1.959963984540054, 0.975: 1.959963984540054}[p]
    c = 2.0 / (9.0 * dof)
    return dof * (1.0 - c + z * math.sqrt(c)) ** 3


def _route() -> list[tuple[float, float, float]]:
    """(seconds, m/s, rad/s): straight, left arc, spin, right arc, straight."""
    return [(2.0, 0.4, 0.0), (2.0, 0.3, 0.8), (1.0, 0.0, -1.5), (2.0, 0.3, -0.6),
            (1.5, 0.4, 0.0)]


def _final_nees(k_true: float, k_model: float, runs: int, sr: float = 0.0, sb: float = 0.0,
                sr_model: float = 0.0, sb_model: float = 0.0) -> np.ndarray:
    """Final-pose NEES of the estimator (nominal geometry) against the oracle's truth.

    Per run the robot's true radii and separation are drawn once (relative 1-sigma
    ``sr``, ``sb``: the geometry error is one draw per robot), and each step's true
    wheel arcs are the true radius times the joint increment plus slip of variance
    ``k_true |arc|``. The truth integrates those arcs with :func:`oracle.wheel_arc`
    (the textbook arc, not the package's step); the estimator sees only the joints.
    """
    nees = np.empty(runs)
    for run in range(runs):
        rng = np.random.default_rng(run)
        e_l, e_r, e_b = rng.standard_normal(3) * (sr, sr, sb)
        r_l, r_r, b = R * (1 + e_l), R * (1 + e_r), B * (1 + e_b)
        est = _estimator(k_model, k_model, radius_ratio=sr_model, separation_ratio=sb_model)
        t, left, right, truth = STEP_NS, 0.0, 0.0, oracle.ORIGIN
        est.update(t, NAMES, [left, right])
        for seconds, v, w in _route():
            rate_l, rate_r = wheel_rates(GEOMETRY, v, w)  # commanded with the nominal one
            d_l, d_r = rate_l * STEP_NS * 1e-9, rate_r * STEP_NS * 1e-9
            for _ in range(round(seconds * 1e9 / STEP_NS)):
                s_l, s_r = r_l * d_l, r_r * d_r
                s_l += math.sqrt(k_true * abs(s_l)) * rng.standard_normal()
                s_r += math.sqrt(k_true * abs(s_r)) * rng.standard_normal()
                truth = oracle.wheel_arc(s_l, s_r, b, truth)
                t, left, right = t + STEP_NS, left + d_l, right + d_r
                est.update(t, NAMES, [left, right])
        pose = est.pose
        e = np.array([pose.x - truth[0], pose.y - truth[1],
                      math.remainder(pose.theta - truth[2], 2 * math.pi)])
        nees[run] = e @ np.linalg.solve(_p3(est), e)
    return nees


RUNS = 250
K_TRUE = 1e-4  # m: 1 cm per metre rolled (1 sigma), heading sigma ~0.16 rad at the end


def test_nees_of_the_final_pose_is_inside_the_95_percent_bounds() -> None:
    """Consistent: N * mean NEES ~ chi2(3N), inside its two-sided 95 % interval."""
    nees = _final_nees(K_TRUE, K_TRUE, RUNS)
    low, high = _chi2_quantile(0.025, 3 * RUNS), _chi2_quantile(0.975, 3 * RUNS)
    print(f"NEES over {RUNS} runs: mean {nees.mean():.3f} (3 expected), bounds "
          f"[{low / RUNS:.3f}, {high / RUNS:.3f}]")
    assert low <= nees.sum() <= high, nees.mean()


def test_nees_with_an_uncertain_geometry_is_inside_the_95_percent_bounds() -> None:
    """Radii off by 1 % and the separation by 3 % (1 sigma, one draw per run) dominate
    the wheel noise: the geometry term makes the covariance consistent, and without it
    the same runs are far overconfident."""
    runs, sr, sb = 200, 0.01, 0.03
    nees = _final_nees(1e-6, 1e-6, runs, sr, sb, sr, sb)
    low, high = _chi2_quantile(0.025, 3 * runs), _chi2_quantile(0.975, 3 * runs)
    assert low <= nees.sum() <= high, nees.mean()
    without = _final_nees(1e-6, 1e-6, 60, sr, sb)
    assert without.mean() > 10 * 3, without.mean()


def test_nees_fails_when_the_model_k_is_ten_times_too_small() -> None:
    """The same test can fail: with k / 10 the covariance is overconfident."""
    runs = 60
    nees = _final_nees(K_TRUE, K_TRUE / 10, runs)
    assert nees.sum() > _chi2_quantile(0.975, 3 * runs), nees.mean()


# --- parameters and the pipeline --------------------------------------------------------


BASE = {"wheel_radius": R, "wheel_separation": B, "wheel_radius_stddev_ratio": 0.0,
        "wheel_separation_stddev_ratio": 0.0}


@pytest.mark.parametrize(("name", "value"), [
    ("covariance_model", "dynamic"),
    ("wheel_noise_k_left", -1e-5),
    ("wheel_noise_k_right", float("nan")),
    ("wheel_noise_k_left", float("inf")),
    ("wheel_radius_stddev_ratio", -0.01),
    ("wheel_separation_stddev_ratio", float("nan")),
])
def test_bad_noise_parameters_name_themselves(name: str, value: object) -> None:
    with pytest.raises(ParameterError) as err:
        odometry_settings({**BASE, name: value})
    assert err.value.name == name


JOINTS = ["left_wheel_joint", "right_wheel_joint"]


def test_static_model_publishes_the_diagonals_propagated_the_model(tmp_path: Path) -> None:
    pose_diag, twist_diag = [1.0, 2.0, 3.0, 4.0, 5.0, 6.0], [0.1, 0.2, 0.3, 0.4, 0.5, 0.6]
    static = ReadingPipeline(odometry_settings({
        **BASE, "covariance_model": "static", "pose_covariance_diagonal": pose_diag,
        "twist_covariance_diagonal": twist_diag}))
    assert static.settings.noise is None and static.estimator.uncertainty is None
    static.feed(1, JOINTS, [0.0, 0.0])
    static.feed(1 + STEP_NS, JOINTS, [1.0, 1.0])
    assert static.covariances() == (covariance_matrix(pose_diag), covariance_matrix(twist_diag))

    pipe = ReadingPipeline(odometry_settings({**BASE, "wheel_noise_k_left": 3e-5,
                                              "wheel_noise_k_right": 3e-5}))
    pipe.feed(1, JOINTS, [0.0, 0.0])
    pipe.feed(1 + STEP_NS, JOINTS, [1.0, 1.0])
    pose, _ = pipe.covariances()
    assert pose[0] - COVARIANCE_FLOOR == pytest.approx(3e-5 * R / 2, rel=1e-12)
    # A runtime change of the encoder settings keeps the covariance, as it keeps the pose.
    pipe.reconfigure(odometry_settings({**BASE, "wheel_noise_k_left": 3e-5,
                                        "wheel_noise_k_right": 3e-5, "max_wheel_speed": 50.0}))
    assert pipe.covariances()[0] == pose
    pipe.reset()
    assert pipe.covariances()[0][0] == COVARIANCE_FLOOR  # nothing but the floor


def test_runtime_changes_of_the_model_carry_the_covariance_on() -> None:
    """A new k applies from the next step; static -> propagated starts from zero there."""
    pipe = ReadingPipeline(odometry_settings({**BASE, "wheel_noise_k_left": 1e-5,
                                              "wheel_noise_k_right": 1e-5}))
    pipe.feed(1, JOINTS, [0.0, 0.0])
    pipe.feed(1 + STEP_NS, JOINTS, [1.0, 1.0])
    pipe.reconfigure(odometry_settings({**BASE, "wheel_noise_k_left": 5e-5,
                                        "wheel_noise_k_right": 5e-5}))
    pipe.feed(1 + 2 * STEP_NS, JOINTS, [2.0, 2.0])
    assert pipe.covariances()[0][0] - COVARIANCE_FLOOR == pytest.approx(
        (1e-5 + 5e-5) * R / 2, rel=1e-12)
    pipe.reconfigure(odometry_settings({**BASE, "covariance_model": "static"}))
    assert pipe.estimator.uncertainty is None
    assert pipe.covariances()[0][0] == 0.001  # pose_covariance_diagonal default
    pipe.reconfigure(odometry_settings(BASE))
    pipe.feed(1 + 3 * STEP_NS, JOINTS, [3.0, 3.0])
    assert pipe.covariances()[0][0] - COVARIANCE_FLOOR == pytest.approx(DEFAULT_K * R / 2,
                                                                    rel=1e-12)


# --- real runs ----------------------------------------------------------------------------


@pytest.mark.parametrize("run", ["square_231220200029_run-01", "square_231220200029_run-04"])
def test_final_pose_nees_of_the_optiodom_squares_with_the_defaults(run: str) -> None:
    """The node's defaults (nominal geometry) on two real squares: the final pose's NEES
    against motion capture, whose own error (1 mm, 0.5 deg; doc/concepts/covariance.md) is
    added, lies below chi-square(3)'s 99 % quantile and is not vanishingly small (a
    covariance inflated until nothing can fail is no better than an overconfident one).
    """
    from diffdrive_odom.core.evaluation.metrics import interpolate
    from diffdrive_odom.core.geometry.se2 import between
    from diffdrive_odom.tools.bags import bagreadings, poses

    from rosutil import DATA

    bag = DATA / "optiodom" / run
    pipe = ReadingPipeline(odometry_settings({"wheel_radius": 0.042, "wheel_separation": 0.2}))
    readings = list(bagreadings.read_joint_states(bag))
    for r in readings:
        pipe.feed(r.stamp_ns, r.names, r.position, r.velocity)
    est = pipe.estimator
    assert est.stamp_ns is not None
    ends = interpolate(poses.read_trajectory(bag, "/ground_truth/pose"),
                       np.array([readings[0].stamp_ns, est.stamp_ns]))
    truth = between(ends[:1], ends[1:])[0]
    e = np.array([est.pose.x - truth[0], est.pose.y - truth[1],
                  math.remainder(est.pose.theta - truth[2], 2 * math.pi)])
    cov = np.array(pipe.covariances()[0]).reshape(6, 6)[np.ix_([0, 1, 5], [0, 1, 5])]
    cov += np.diag([1e-3**2, 1e-3**2, math.radians(0.5) ** 2])
    nees = float(e @ np.linalg.solve(cov, e))
    assert 0.1 < nees < 11.34, nees  # chi2(3): its 0.8 % and 99 % quantiles
