"""Online calibration from the gyro (issue 25 item 1-2), on realistic streams.

The streams (``gyrostreams``): the IMU on its own clock, every message in receive-time
order; the robot's true geometry differs from the configured one and its joint
angles follow the true one (integrated there, not by the package). The truth of the
estimate is the true geometry, in closed form: with the configured mean radius held,
``left = 2 r_L / (r_L + r_R)``, ``right = 2 r_R / (r_L + r_R)``, ``separation = 2 R b /
((r_L + r_R) B)``.
"""

from __future__ import annotations

import math
from dataclasses import replace
from functools import cache
from itertools import pairwise
from typing import Any

import pytest
from gyrostreams import (
    ISSUE_ROUTE,
    NAMES,
    TIMINGS,
    B,
    R,
    Route,
    Truth,
    stream,
    truth,
)

from diffdrive_odom.core.estimation.online.online_estimate import CHI2_2DOF_3SIGMA, OnlineEstimate
from diffdrive_odom.core.estimation.online.ratios import multipliers
from diffdrive_odom.core.estimation.pipeline import ReadingPipeline
from diffdrive_odom.core.geometry.kinematics import Geometry
from diffdrive_odom.settings.errors import ParameterError
from diffdrive_odom.settings.odometry import odometry_settings, online_warning

from oracle import mahalanobis2

BIAS = math.radians(0.3)
ND = 3e-4
TRUE = (R, R * 1.005, B * 1.01)  # the issue's: 0.5 % on one radius, 1 % on the track
# Twice the issue's route without its slips: 150 s, 53 m, 15 rad left, 10 rad right.
MIXED = Route(ISSUE_ROUTE.segments * 2)
SLIPPY = Route(ISSUE_ROUTE.segments * 2, ISSUE_ROUTE.slips)
# Turning one way only, and straight only.
LEFT_ONLY = Route(((8.0, 0.4, 0.0), (10.0, 0.3, 0.4), (8.0, 0.4, 0.0), (10.0, 0.3, 0.5)))
STRAIGHT = Route(((20.0, 0.5, 0.0), (20.0, -0.4, 0.0), (20.0, 0.5, 0.0)))
TIMING = {t.name: t for t in TIMINGS}
# The wheels' travel noise is 0 on these streams (exact joint angles): said so.
EXACT_WHEELS = {"wheel_noise_k_left": 0.0, "wheel_noise_k_right": 0.0}


@cache
def _truth(route: Route, geometry: tuple[float, float, float]) -> Truth:
    return truth(route, *geometry)


def run(route: Route, timing: str, geometry: tuple[float, float, float] = TRUE,
        seed: int = 1, ticks: float = 0.0, **values: object
        ) -> tuple[OnlineEstimate, list[str], ReadingPipeline]:
    """Feed the stream as a node does; the final estimate and the warnings said."""
    pipe = ReadingPipeline(odometry_settings(
        {"wheel_radius": R, "wheel_separation": B, "use_imu": True,
         "ticks_per_revolution": ticks, **EXACT_WHEELS, **values}))
    scale = ticks / (2.0 * math.pi) if ticks else 1.0
    warnings = []
    for kind, rx, stamp, a, b in stream(route, TIMING[timing], BIAS, ND, seed,
                                        _truth(route, geometry)):
        if kind == "i":
            pipe.feed_imu(stamp, 0.0, 0.0, a, receive_ns=rx)
            continue
        if ticks:
            a, b = float(round(a * scale)), float(round(b * scale))
        out = pipe.feed(stamp, NAMES, (a, b), receive_ns=rx)
        if out.warning.startswith("online calibration"):
            warnings.append(out.warning)
    est = pipe.stats.online
    assert est is not None
    return est, warnings, pipe


def true_multipliers(geometry: tuple[float, float, float]) -> tuple[float, float, float]:
    rl, rr, b = geometry
    return 2 * rl / (rl + rr), 2 * rr / (rl + rr), 2 * R * b / ((rl + rr) * B)


def truth_distance2(est: OnlineEstimate, geometry: tuple[float, float, float]) -> float:
    """The true ratios' squared Mahalanobis distance from the estimate."""
    rl, rr, b = geometry
    return mahalanobis2(est.ratios, est.covariance, (rr / b, rl / b))


@pytest.mark.parametrize("timing", ["stamped 5 ms early", "30 ms behind", "173 Hz jittered"])
def test_converges_to_the_true_geometry_within_3_sigma(timing: str) -> None:
    est, warnings, pipe = run(MIXED, timing)
    assert est.determined
    assert truth_distance2(est, TRUE) < CHI2_2DOF_3SIGMA
    for got, sigma, want in zip(est.multipliers, est.stddevs, true_multipliers(TRUE),
                                strict=True):
        assert abs(got - want) < 3 * sigma
        assert sigma < 0.001  # 0.1 %: the issue's goal for 50 m
    gyro = pipe.stats.gyro  # no slip on the route; the gyro's test may flag a few steps
    assert gyro is not None and est.excluded.get("slip", 0) == gyro.slips.steps
    assert est.excluded["standstill"] > 0  # the standstills at both ends
    assert len(warnings) >= 1  # the configured geometry is 1 % off: said


def test_quantized_encoders_still_cover_the_truth() -> None:
    """4096 counts a turn: the quantization is in the window's noise, not per step."""
    est, _, _ = run(MIXED, "stamped 5 ms early", ticks=4096.0)
    assert est.determined
    assert truth_distance2(est, TRUE) < CHI2_2DOF_3SIGMA


def test_sigma_covers_the_truth_over_seeds() -> None:
    """Monte Carlo: the truth's Mahalanobis distance behaves as chi-square with 2 dof."""
    d2 = [truth_distance2(run(MIXED, "173 Hz jittered", seed=s)[0], TRUE) for s in range(8)]
    assert max(d2) < CHI2_2DOF_3SIGMA
    assert sum(d2) / len(d2) < 4.0  # chi2(2) has mean 2; 8 draws' mean < 4 at 97 %


@pytest.mark.parametrize("route", [LEFT_ONLY, STRAIGHT], ids=["left only", "straight"])
def test_not_determined_without_turns_both_ways(route: Route) -> None:
    est, warnings, _ = run(route, "stamped 5 ms early")
    assert not est.determined
    assert not est.outside and warnings == []
    assert "not yet determined" in est.line()


def test_slips_are_excluded_and_counted() -> None:
    est, _, pipe = run(SLIPPY, "stamped 5 ms early")
    gyro = pipe.stats.gyro
    assert gyro is not None and gyro.slips.events == 4
    assert est.excluded["slip"] == gyro.slips.steps
    assert truth_distance2(est, TRUE) < CHI2_2DOF_3SIGMA


def test_warns_when_the_robot_differs_not_when_it_matches() -> None:
    _, warnings, _ = run(MIXED, "30 ms behind")
    # Once, then at most once a minute while outside: the run is 150 s.
    assert 1 <= len(warnings) <= 3
    assert "recalibrate" in warnings[0] and "outside" in warnings[0]
    false = [len(run(MIXED, "173 Hz jittered", geometry=(R, R, B), seed=s)[1])
             for s in range(6)]
    assert sum(false) == 0


def test_dropout_counts_steps_without_gyro() -> None:
    est, _, _ = run(MIXED, "dropout")
    assert est.excluded["no_gyro"] > 0
    assert truth_distance2(est, TRUE) < CHI2_2DOF_3SIGMA


def test_steps_reach_the_online_filters_in_time_order_across_a_dropout() -> None:
    """An IMU 8 ms late falls silent for 1.5 s: the steps still pending are given up
    before the step that found it silent, so the filters (the reference's scale reads a
    step back in time as a new timeline) see every step once, in order."""
    timing = replace(TIMING["dropout"], imu_latency=8e-3)
    pipe = ReadingPipeline(odometry_settings(
        {"wheel_radius": R, "wheel_separation": B, "use_imu": True, **EXACT_WHEELS}))
    gyro = pipe.gyro
    assert gyro is not None and gyro.observer is not None
    seen: list[tuple[int, int]] = []
    observe = gyro.observer

    def record(g: Geometry, t0: int, t1: int, *rest: Any) -> None:
        seen.append((t0, t1))
        observe(g, t0, t1, *rest)

    gyro.observer = record
    for kind, rx, stamp, a, b in stream(MIXED, timing, BIAS, ND, 1, _truth(MIXED, TRUE)):
        if kind == "i":
            pipe.feed_imu(stamp, 0.0, 0.0, a, receive_ns=rx)
        else:
            pipe.feed(stamp, NAMES, (a, b), receive_ns=rx)
    assert len(seen) > 3000
    assert all(b[0] >= a[1] for a, b in pairwise(seen)), "a step out of time order"


def test_multipliers_hold_the_mean_radius() -> None:
    g = Geometry(0.05, 0.3)
    rl, rr, b = 0.049, 0.0505, 0.303
    values, sigmas = multipliers(g, (rr / b, rl / b), (0.0, 0.0, 0.0, 0.0))
    assert values == pytest.approx(true_multipliers((rl, rr, b)), rel=1e-12)
    assert sigmas == (0.0, 0.0, 0.0)
    # A numerical derivative of the closed form gives the same sigma as the Jacobian.
    var = 1e-8
    _, sig = multipliers(g, (rr / b, rl / b), (var, 0.0, 0.0, 0.0))
    h = 1e-7
    up = true_multipliers((rl, rr * (1 + h / (rr / b)), b))
    mid = true_multipliers((rl, rr, b))
    assert sig[1] == pytest.approx(abs(up[1] - mid[1]) / h * math.sqrt(var), rel=1e-4)


def test_settings_modes() -> None:
    base = {"wheel_radius": R, "wheel_separation": B}
    applying = odometry_settings({**base, "online_calibration": "apply"}).online
    assert applying is not None and applying.apply and applying.apply_sigma == 0.002
    for bad in (0.0, -1.0, math.inf, math.nan):
        with pytest.raises(ParameterError, match="online_calibration_apply_sigma"):
            odometry_settings({**base, "online_calibration": "apply",
                               "online_calibration_apply_sigma": bad})
    with pytest.raises(ParameterError, match="online_calibration"):
        odometry_settings({**base, "online_calibration": "off"})
    # Unquoted, `-p online_calibration:=off` reaches the node as false (rclpy's YAML).
    with pytest.raises(ParameterError, match=r"online_calibration.*quote the value"):
        odometry_settings({**base, "online_calibration": False})
    assert odometry_settings({**base, "online_calibration": "disabled"}).online is None
    wheels_only = ReadingPipeline(odometry_settings(base))
    # monitor (the default) without the gyro: nothing runs, and no line says so at start.
    assert wheels_only.stats.online is None and online_warning(wheels_only.settings) == ""
    gyro = ReadingPipeline(odometry_settings({**base, "use_imu": True}))
    assert gyro.stats.online is not None
    off = ReadingPipeline(odometry_settings({**base, "use_imu": True,
                                             "online_calibration": "disabled"}))
    assert off.stats.online is None
    # At runtime: monitor -> disabled -> monitor (a fresh estimate), the gyro carries on.
    gyro.reconfigure(off.settings)
    assert gyro.stats.online is None and gyro.gyro is not None and gyro.gyro.observer is None
    gyro.reconfigure(odometry_settings({**base, "use_imu": True}))
    assert gyro.stats.online is not None and gyro.gyro.observer is not None
