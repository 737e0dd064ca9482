"""The printed sigma's combination rule: bootstrap over runs + a drift between sessions.

Pure (numpy only, no bag, no fit). Expected values come from the model the rule states:
an experiment's true geometry is the robot's times (1 + delta), delta ~ N(0, s^2) per
session; its fit adds its own noise (the bootstrap's sigma). Two experiments then differ
by N(0, sigma_a^2 + sigma_b^2 + 2 s^2 v^2), so the drift ratio is sqrt(2) s.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from diffdrive_odom.core.evaluation import crossval
from diffdrive_odom.core.uncertainty.noise import SESSION_DRIFT_RATIO

V = np.array([0.042, 0.042, 0.2])


def test_with_drift_adds_the_ratio_of_each_value_on_the_diagonal_only() -> None:
    cov = np.array([[4e-10, 1e-10, 2e-9], [1e-10, 9e-10, 3e-9], [2e-9, 3e-9, 1e-7]])
    out = crossval.with_drift(V, cov, 0.002)
    expected = cov.copy()
    expected[0, 0] += (0.002 * 0.042) ** 2
    expected[1, 1] += (0.002 * 0.042) ** 2
    expected[2, 2] += (0.002 * 0.2) ** 2
    assert np.allclose(out, expected, rtol=1e-12, atol=0.0)
    assert np.array_equal(crossval.with_drift(V, cov, 0.0), cov)
    default = crossval.with_drift(V, np.zeros((3, 3)))
    assert np.allclose(np.sqrt(np.diag(default)), SESSION_DRIFT_RATIO * V, rtol=1e-12)
    assert np.sqrt(out[2, 2]) == pytest.approx(math.hypot(math.sqrt(1e-7), 0.002 * 0.2))


def test_drift_ratio_of_two_noise_free_experiments_is_their_relative_difference() -> None:
    d = 0.003
    zero = np.zeros((3, 3))
    got = crossval.drift_ratio([V, V * (1 + d)], [zero, zero])
    assert got == pytest.approx(d / (1 + d / 2), rel=1e-9)


def test_drift_ratio_averages_over_pairs_and_parameters() -> None:
    d = 0.002
    zero = np.zeros((3, 3))
    got = crossval.drift_ratio([V, V * (1 + d), V * (1 - d)], [zero, zero, zero])
    squares = [(d / (1 + d / 2)) ** 2, (d / (1 - d / 2)) ** 2, (2 * d) ** 2]
    assert got == pytest.approx(math.sqrt(sum(squares) / 3), rel=1e-9)


def test_drift_ratio_is_zero_when_the_fits_own_sigmas_explain_the_difference() -> None:
    own = np.diag((0.004 * V) ** 2)  # 0.4 % each, the fits 0.3 % apart
    assert crossval.drift_ratio([V, V * 1.003], [own, own]) == 0.0
    # Only the excess counts: 0.5 % apart, each known to 0.3 % of its own value.
    own = np.diag((0.003 * V) ** 2)
    got = crossval.drift_ratio([V, V * 1.005], [own, own * 1.005**2])
    rel = 0.005 / 1.0025
    assert got == pytest.approx(math.sqrt(rel**2 - 2 * 0.003**2), rel=1e-9)
    with pytest.raises(ValueError, match="two or more"):
        crossval.drift_ratio([V], [own])


def test_pair_z_is_the_difference_over_the_combined_sigma() -> None:
    printed_a = np.diag([4e-10, 1e-10, 9e-8])
    cov_b = np.diag([5e-10, 3e-10, 7e-8])  # sums: (3e-5)^2, (2e-5)^2, (4e-4)^2
    b = V + np.array([-3e-5, 0.0, 8e-4])
    assert np.allclose(crossval.pair_z(V, printed_a, b, cov_b), [1.0, 0.0, 2.0], rtol=1e-9)


def test_the_rule_covers_68_and_95_percent_where_the_model_holds() -> None:
    """Simulated experiments: the drift estimated by drift_ratio, then the printed sigma
    (with_drift) checked by pair_z on every pair: the model's own coverage."""
    rng = np.random.default_rng(7)
    s = 0.002  # per-session relative deviation; two sessions differ by sqrt(2) s
    n = 80
    own = [np.diag((rng.uniform(0.0005, 0.002) * V) ** 2) for _ in range(n)]
    fits = [V * (1 + s * rng.standard_normal(3)) + rng.standard_normal(3) * np.sqrt(np.diag(c))
            for c in own]
    ratio = crossval.drift_ratio(fits, own)
    assert ratio == pytest.approx(math.sqrt(2) * s, rel=0.15)
    z = np.array([crossval.pair_z(fits[i], crossval.with_drift(fits[i], own[i], ratio),
                                  fits[j], own[j])
                  for i in range(n) for j in range(i + 1, n)])
    assert 0.63 < np.mean(z < 1) < 0.74, np.mean(z < 1)
    assert 0.92 < np.mean(z < 2) < 0.98, np.mean(z < 2)
    before = np.array([crossval.pair_z(fits[i], own[i], fits[j], own[j])
                       for i in range(n) for j in range(i + 1, n)])
    assert np.mean(before < 1) < 0.5  # the bootstrap alone misses the drift
