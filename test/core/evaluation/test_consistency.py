"""Final-pose NEES of recorded runs and the maximum-likelihood noise fit.

A run here is built from wheel increments with a reference written from ``oracle.py``'s
arcs; expected covariances come from the closed forms of the model (a spin on the spot),
and the fit is checked on errors drawn from a known covariance.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.stats import chi2

from diffdrive_odom.core.bulk.batch import WheelSteps
from diffdrive_odom.core.evaluation import consistency
from diffdrive_odom.core.evaluation.consistency import Noise, RunTerms
from diffdrive_odom.core.evaluation.metrics import Trajectory
from diffdrive_odom.core.evaluation.recorded_run import Run
from diffdrive_odom.core.geometry.kinematics import Geometry

import oracle

R, B = 0.05, 0.3
GEOMETRY = Geometry(R, B)
STEP_NS = 50_000_000


def _run(steps: list[tuple[float, float]], heading_off: float = 0.0) -> Run:
    """Joint increments per step; the reference is the oracle's path, its end turned by
    ``heading_off`` (an error the odometry does not see)."""
    n = len(steps)
    d_left = np.array([s[0] for s in steps])
    d_right = np.array([s[1] for s in steps])
    stamps = np.arange(1, n + 1, dtype=np.int64) * STEP_NS + 10 * STEP_NS
    wheel = WheelSteps(stamps, np.full(n, STEP_NS * 1e-9), d_left, d_right,
                       np.zeros(n, dtype=np.int64), 1)
    poses = [oracle.ORIGIN]
    for dl, dr in steps:
        poses.append(oracle.arc(R * (dl + dr) / 2, R * (dr - dl) / B, poses[-1]))
    x, y, th = (np.array([p[i] for p in poses]) for i in range(3))
    th[-1] += heading_off
    ref = Trajectory.from_arrays(np.concatenate(([10 * STEP_NS], stamps)), x, y, th)
    return Run("synthetic", wheel, ref)


def test_a_spin_on_the_spot_gives_the_closed_form_unit_terms() -> None:
    """A spin by ``a``: per unit ``k`` the heading variance is ``(|s_l| + |s_r|) / b^2 =
    |a| / b``, per unit ``k_rot`` it is ``|a|``; the error is the reference's offset."""
    rad, n = 0.3, 40
    run = _run([(-rad, rad)] * n, heading_off=0.01)
    t = consistency.run_terms(run, GEOMETRY)
    a = 2 * R * rad * n / B
    assert t.turned == pytest.approx(a, rel=1e-12)
    assert t.wheel[2, 2] == pytest.approx(a / B, rel=1e-12)
    assert t.rotation[2, 2] == pytest.approx(a, rel=1e-12)
    assert t.rotation[0, 0] == 0.0 and t.rotation[1, 1] == 0.0
    assert t.error == pytest.approx([0.0, 0.0, -0.01], abs=1e-12)
    noise = Noise(0.0, 1e-4, 0.0, 0.0)
    want = 0.01**2 / (1e-4 * a)
    position_only = np.diag([1e-6, 1e-6, 0.0])  # the rotation term reaches no position
    assert consistency.nees(t, noise, position_only) == pytest.approx(want, rel=1e-9)


def _terms_with_errors(k_rot: float, runs: int, seed: int) -> list[RunTerms]:
    """Squares with spins at the corners; errors drawn from the model's covariance with
    ``k_rot`` (and k 1e-6, the reference error), so the fit's truth is known."""
    side, turn = 20, 15
    fwd, spin = 1.0 / side / R, (math.pi / 2) * (B / 2) / turn / R
    base = consistency.run_terms(_run(([(fwd, fwd)] * side + [(-spin, spin)] * turn) * 4),
                                 GEOMETRY)
    rng = np.random.default_rng(seed)
    truth = Noise(1e-6, k_rot, 0.0, 0.0)
    cov = consistency.covariance(base, truth)
    out = []
    for i in range(runs):
        e = rng.multivariate_normal(np.zeros(3), cov)
        out.append(RunTerms(f"run{i}", e, base.wheel, base.rotation, base.sensitivity,
                            base.turned, base.distance))
    return out


def test_the_fit_finds_the_rotation_noise_the_errors_were_drawn_with() -> None:
    terms = _terms_with_errors(1e-4, 300, 1)
    fit = consistency.fit_noise(terms, Noise(1e-6, 0.0, 0.0, 0.0))
    assert fit.noise.k_rotation == pytest.approx(1e-4, rel=0.25)
    assert fit.lr_rotation > consistency.LR_5_PERCENT
    assert fit.noise.k == 1e-6  # held fixed


def test_the_fit_says_zero_when_the_data_want_no_rotation_noise() -> None:
    """Errors smaller than the other terms already allow: the likelihood is highest at 0."""
    terms = [RunTerms(t.name, 0.3 * t.error, t.wheel, t.rotation, t.sensitivity, t.turned,
                      t.distance) for t in _terms_with_errors(0.0, 60, 2)]
    fit = consistency.fit_noise(terms, Noise(1e-6, 0.0, 0.0, 0.0))
    assert fit.noise.k_rotation == 0.0 and fit.lr_rotation == 0.0


@pytest.mark.parametrize("runs", [21, 26, 47])
def test_chi2_band_of_the_mean(runs: int) -> None:
    """Wilson-Hilferty against scipy's chi-square quantiles of the sum (3 dof a run)."""
    lo, hi = consistency.chi2_band(runs)
    assert lo == pytest.approx(chi2.ppf(0.025, 3 * runs) / runs, rel=0.01)
    assert hi == pytest.approx(chi2.ppf(0.975, 3 * runs) / runs, rel=0.01)
    assert pytest.approx(chi2.ppf(0.95, 3), abs=1e-3) == consistency.CHI2_3_95
    assert pytest.approx(chi2.ppf(0.999, 3), abs=1e-3) == consistency.CHI2_3_999


def test_the_joint_likelihood_shares_the_geometry_error_within_a_group() -> None:
    """One run a group: the per-run likelihood. Two runs of one path: errors that agree
    (a shared geometry error) are likelier than errors that disagree by the same size."""
    terms = _terms_with_errors(1e-4, 2, 3)
    noise = Noise(1e-6, 1e-4, 0.003, 0.01)
    alone = consistency.joint_log_likelihood([[t] for t in terms], noise)
    assert alone == pytest.approx(consistency.log_likelihood(terms, noise), rel=1e-12)
    a = terms[0]
    e = a.sensitivity @ np.array([0.0, 0.0, 0.02])  # the error of a 2 % wrong separation
    same = [RunTerms("a", e, a.wheel, a.rotation, a.sensitivity, a.turned, a.distance),
            RunTerms("b", e, a.wheel, a.rotation, a.sensitivity, a.turned, a.distance)]
    opposite = [same[0], RunTerms("b", -e, a.wheel, a.rotation, a.sensitivity, a.turned,
                                  a.distance)]
    assert (consistency.joint_log_likelihood([same], noise)
            > consistency.joint_log_likelihood([opposite], noise))


def test_the_upper_bound_is_where_the_likelihood_ratio_reaches_its_threshold() -> None:
    """A quadratic log-likelihood ``-(x - m)^2 / (2 s^2)``: the bound is ``m + s sqrt(2.706)``
    (to the search's step of 10^(1/16))."""
    m, s = 1e-4, 5e-5
    bound = consistency.upper_bound(lambda x: -((x - m) ** 2) / (2 * s * s), m)
    want = m + s * math.sqrt(consistency.LR_5_PERCENT)
    assert want / 10 ** (1 / 16) <= bound <= want
