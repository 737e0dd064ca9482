"""Gyrodometry (issue 18) against closed-form truth: a gyro bias, slip events, IMU faults.

The truth is a constant-twist circle (``oracle.arc``), the wheels' joint angles and the
gyro's rates are written from it (plus a scripted slip and a bias), and the pipeline
is fed as the node feeds it. Nothing expected comes from the estimator's step.
Borenstein and Feng, "Gyrodometry: A New Method for Combining Data from Gyros and
Odometry in Mobile Robots" (ICRA 1996).
"""

from __future__ import annotations

import itertools
import math
import random
from collections.abc import Iterator
from dataclasses import dataclass

import pytest

from diffdrive_odom.core.estimation.config import OdometrySettings
from diffdrive_odom.core.estimation.pipeline import IMU_BACK, IMU_SILENT, ReadingPipeline
from diffdrive_odom.core.geometry.integration import Pose2D
from diffdrive_odom.settings.odometry import odometry_settings

from oracle import arc

R, B = 0.05, 0.3
NAMES = ("left_wheel_joint", "right_wheel_joint")
T0 = 1_000_000_000_000  # 1000 s: any positive stamp


@dataclass(frozen=True)
class Drive:
    """A constant twist ``(v, w)`` for ``seconds``; the right wheel spins ``slip`` rad/s
    extra (no ground motion) between ``slip_from`` and ``slip_to`` seconds."""

    v: float = 0.4
    w: float = 0.3
    seconds: float = 10.0
    slip: float = 0.0
    slip_from: float = 3.0
    slip_to: float = 4.0
    bias: float = 0.0
    noise: float = 0.0  # white noise stddev of each gyro sample [rad/s]
    wheel_hz: int = 50
    imu_hz: int = 200


def _slip_angle(d: Drive, t: float) -> float:
    """The right joint's extra angle [rad] by time ``t`` (integral of the slip rate)."""
    return d.slip * max(0.0, min(t, d.slip_to) - d.slip_from)


def events(d: Drive, seed: int = 1) -> Iterator[tuple[str, int, float, float]]:
    """(kind, stamp_ns, a, b) in stamp order: joint ('j', left, right) or imu ('i', wz, 0)."""
    rng = random.Random(seed)
    out: list[tuple[str, int, float, float]] = []
    left_rate, right_rate = (d.v - 0.5 * d.w * B) / R, (d.v + 0.5 * d.w * B) / R
    for k in range(round(d.seconds * d.wheel_hz) + 1):
        t = k / d.wheel_hz
        out.append(("j", T0 + round(t * 1e9), left_rate * t,
                    right_rate * t + _slip_angle(d, t)))
    for k in range(round(d.seconds * d.imu_hz) + 1):
        t = k / d.imu_hz
        out.append(("i", T0 + round(t * 1e9), d.w + d.bias + rng.gauss(0.0, d.noise)
                    if d.noise else d.w + d.bias, 0.0))
    # An IMU sample at a wheel reading's stamp arrives first, as a waiting node sees it.
    out.sort(key=lambda e: (e[1], e[0] == "j"))
    return iter(out)


def settings(**values: object) -> OdometrySettings:
    return odometry_settings({"wheel_radius": R, "wheel_separation": B, **values})


def run(d: Drive, seed: int = 1, **values: object) -> tuple[ReadingPipeline, list[str]]:
    pipe = ReadingPipeline(settings(**values))
    notes = []
    for kind, stamp, a, b in events(d, seed):
        if kind == "i":
            assert pipe.feed_imu(stamp, 0.0, 0.0, a) == ""
        else:
            out = pipe.feed(stamp, NAMES, (a, b))
            if out.note:
                notes.append(out.note)
    return pipe, notes


def truth(d: Drive) -> tuple[float, float, float]:
    return arc(d.v * d.seconds, d.w * d.seconds)


def error(pipe: ReadingPipeline, d: Drive) -> tuple[float, float]:
    x, y, th = truth(d)
    p = pipe.estimator.pose
    return math.hypot(p.x - x, p.y - y), abs(math.remainder(p.theta - th, 2 * math.pi))


def test_use_imu_false_is_the_wheels_and_ignores_imu_samples() -> None:
    d = Drive(slip=20.0)
    pipe, _ = run(d)
    assert pipe.gyro is None and pipe.stats.gyro is None
    # The wheels' own belief: the slip's extra right arc turns the robot by R*extra/B.
    extra = R * _slip_angle(d, d.seconds)
    th = truth(d)[2]
    assert abs(math.remainder(pipe.estimator.pose.theta - (th + extra / B), 2 * math.pi)) < 1e-9


def test_slip_of_one_wheel_is_named_and_the_gyro_keeps_the_pose_on_the_circle() -> None:
    d = Drive(slip=20.0, bias=0.01)  # 1 m of extra right-wheel arc over 1 s
    wheels, _ = run(Drive(slip=20.0, bias=0.01), use_imu=False)
    pipe, notes = run(d, use_imu=True, gyro_bias=0.01)
    pos, head = error(pipe, d)
    w_pos, w_head = error(wheels, d)
    assert w_head > 2.5 and w_pos > 1.0  # the wheels turned 3.3 rad too far (wrapped: 2.95)
    # Exact data, the bias known: only rounding is left.
    assert pos < 1e-9 and head < 1e-9
    g = pipe.stats.gyro
    assert g is not None and g.silent is False and notes == []
    assert g.slips.events == 1
    assert g.slips.steps == round((d.slip_to - d.slip_from) * d.wheel_hz)
    assert g.slips.last_stamp_ns == T0 + round(d.slip_to * 1e9)
    # Each slipping step's wheels saw R * slip / B rad/s of turning that was not there.
    assert g.slips.last_size == pytest.approx(R * d.slip * 1.0 / B, rel=1e-9)


def test_without_the_other_wheel_rule_the_spinning_wheel_adds_half_its_arc() -> None:
    d = Drive(slip=20.0)
    pipe, _ = run(d, use_imu=True, slip_distance_from_other_wheel=False)
    pos, head = error(pipe, d)
    assert head < 1e-9
    # The distance was the wheels' mean: half the extra arc too far, along the circle at
    # the slip (3.5 s into it, a chord of the path's direction there).
    extra = 0.5 * R * _slip_angle(d, d.seconds)
    assert pos == pytest.approx(extra, rel=0.02)


def test_an_unknown_bias_turns_the_heading_by_bias_times_time_where_wheels_agree_less() -> None:
    # Wheels with a coarse model (k large): the gyro dominates the fused heading, so an
    # unestimated bias of 0.01 rad/s shows up, bounded by 0.01 * 10 s.
    d = Drive(bias=0.01)
    pipe, _ = run(d, use_imu=True, wheel_noise_k_left=1e-2, wheel_noise_k_right=1e-2)
    _, head = error(pipe, d)
    assert 0.05 < head <= 0.1 + 1e-9


def test_zero_velocity_updates_estimate_the_bias() -> None:
    d = Drive(v=0.0, w=0.0, seconds=20.0, bias=0.02, noise=0.01, imu_hz=200)
    # The bias prior honest (0.05 rad/s): a 0.02 bias is no slip of a standing robot.
    pipe, _ = run(d, use_imu=True, gyro_noise_density=0.01 / math.sqrt(200.0),
                  gyro_bias_stddev=0.05)
    g = pipe.stats.gyro
    assert g is not None and g.zero_velocity_updates == round(d.seconds * d.wheel_hz)
    # Mean of 4000 samples of sigma 0.01: sigma 1.6e-4; the filter says about as much.
    assert g.bias_stddev == pytest.approx(0.01 / math.sqrt(d.seconds * d.imu_hz), rel=0.2)
    assert abs(g.bias - 0.02) < 4 * g.bias_stddev
    # Standing still, the heading stays put (the wheels are certain of no turn).
    assert pipe.estimator.pose.theta == 0.0


def test_heading_variance_grows_with_the_gyro_noise_and_bias_uncertainty() -> None:
    # Straight line, wheels made far noisier than the gyro: the heading variance is the
    # gyro's, noise_density^2 T (white) + (sigma_b T)^2 (the bias, one draw).
    d = Drive(w=0.0)
    nd, sb = 1e-3, 2e-3
    pipe, _ = run(d, use_imu=True, wheel_noise_k_left=1.0, wheel_noise_k_right=1.0,
                  gyro_noise_density=nd, gyro_bias_stddev=sb, gyro_bias_random_walk=0.0,
                  wheel_separation_stddev_ratio=0.0, wheel_radius_stddev_ratio=0.0)
    cov, _ = pipe.covariances()
    expected = nd * nd * d.seconds + (sb * d.seconds) ** 2
    assert cov[35] == pytest.approx(expected, rel=0.01)
    wheels, _ = run(d, wheel_noise_k_left=1.0, wheel_noise_k_right=1.0)
    assert wheels.covariances()[0][35] > 100 * expected


def test_a_1khz_imu_gives_the_same_circle() -> None:
    d = Drive(slip=20.0, imu_hz=1000, wheel_hz=100)
    pipe, _ = run(d, use_imu=True)
    pos, head = error(pipe, d)
    assert pos < 1e-9 and head < 1e-9


def test_silent_imu_falls_back_to_wheels_without_a_jump_and_comes_back() -> None:
    d = Drive()
    pipe = ReadingPipeline(settings(use_imu=True, imu_timeout=0.1))
    notes: list[str] = []
    poses: list[Pose2D] = []
    for kind, stamp, a, b in events(d):
        t = (stamp - T0) * 1e-9
        if kind == "i":
            if not 4.0 < t < 6.0:  # silent for 2 s
                pipe.feed_imu(stamp, 0.0, 0.0, a)
            continue
        out = pipe.feed(stamp, NAMES, (a, b))
        if out.note:
            notes.append(out.note)
        poses.append(pipe.estimator.pose)
        if t == 5.0:
            g = pipe.stats.gyro
            assert g is not None and g.silent
    assert notes == [IMU_SILENT, IMU_BACK]
    step = d.v / d.wheel_hz
    for p, q in itertools.pairwise(poses):
        assert math.hypot(q.x - p.x, q.y - p.y) <= step * (1 + 1e-9)  # no jump
    pos, head = error(pipe, d)
    assert pos < 1e-9 and head < 1e-9  # exact wheels, exact gyro: either is the truth


@pytest.mark.parametrize(("stamp", "w", "code"), [
    (T0 + 500_000_000, math.nan, "non_finite"),
    (T0 + 500_000_000, math.inf, "non_finite"),
    (T0 + 500_000_000, 40.0, "saturated"),
    (0, 0.3, "zero_stamp"),
    (T0 + 100_000_000, 0.3, "stale_stamp"),  # before the last integrated step
    (T0 + 5_000_000_000, 0.3, "future_stamp"),  # 4.5 s past the wheels (gap 1 s)
])
def test_bad_imu_samples_are_refused_counted_and_change_nothing(stamp: int, w: float,
                                                                  code: str) -> None:
    d = Drive(seconds=1.0)
    clean, _ = run(d, use_imu=True)
    pipe = ReadingPipeline(settings(use_imu=True))
    for kind, s, a, b in events(d):
        if kind == "i":
            pipe.feed_imu(s, 0.0, 0.0, a)
        else:
            pipe.feed(s, NAMES, (a, b))
        if s == T0 + 500_000_000 and kind == "j":
            assert pipe.feed_imu(stamp, 0.0, 0.0, w) == code
    g = pipe.stats.gyro
    assert g is not None and dict(g.dropped) == {code: 1}
    assert pipe.estimator.pose == clean.estimator.pose
    assert all(math.isfinite(v) for v in pipe.covariances()[0])


def test_an_upside_down_imu_is_one_value_away() -> None:
    d = Drive(slip=20.0)
    pipe = ReadingPipeline(settings(use_imu=True,
                                    imu_orientation=[math.pi, 0.0, 0.0]))
    for kind, s, a, b in events(d):
        if kind == "i":
            pipe.feed_imu(s, 0.0, 0.0, -a)  # its z axis points down
        else:
            pipe.feed(s, NAMES, (a, b))
    pos, head = error(pipe, d)
    assert pos < 1e-9 and head < 1e-9


def test_imu_samples_arriving_after_the_wheel_reading_are_caught_up() -> None:
    # Each wheel reading arrives before the IMU samples up to its stamp (the worst
    # order): the extrapolated part is replaced by the samples at the next step.
    d = Drive(w=0.3)
    pipe = ReadingPipeline(settings(use_imu=True))
    evs = sorted(events(d), key=lambda e: (e[1], e[0] == "i"))
    for kind, s, a, b in evs:
        if kind == "i":
            pipe.feed_imu(s, 0.0, 0.0, a)
        else:
            pipe.feed(s, NAMES, (a, b))
    pos, head = error(pipe, d)
    assert pos < 1e-9 and head < 1e-9


@pytest.mark.parametrize(("name", "value"), [
    ("imu_orientation", [0.0, 0.0]),
    ("imu_orientation", [0.0, 1.5, 0.0]),  # z axis nearly horizontal
    ("gyro_noise_density", 0.0),
    ("imu_timeout", -1.0),
    ("gyro_bias", math.nan),
    ("slip_threshold_sigmas", 0.0),
    ("slip_min_angle", -0.01),
    ("imu_stamp_source", "device"),
])
def test_bad_gyro_parameters_are_named(name: str, value: object) -> None:
    from diffdrive_odom.settings.errors import ParameterError

    with pytest.raises(ParameterError) as err:
        settings(use_imu=True, **{name: value})
    assert err.value.name == name


# --- consistency: final-pose NEES in the gyro mode ---------------------------------------


def _chi2_band(dof: int) -> tuple[float, float]:
    """Two-sided 95 % quantiles of chi2(dof) (Wilson-Hilferty, as test_uncertainty)."""
    c = 2.0 / (9.0 * dof)
    z = 1.959963984540054
    return dof * (1.0 - c - z * math.sqrt(c)) ** 3, dof * (1.0 - c + z * math.sqrt(c)) ** 3


ROUTE = [(2.0, 0.4, 0.0), (2.0, 0.3, 0.8), (1.0, 0.0, -1.5), (2.0, 0.3, -0.6), (1.5, 0.4, 0.0)]


def _gyro_nees(runs: int, k: float, nd: float, sb: float, model_nd: float) -> list[float]:
    """Final-pose NEES with wheel noise ``k`` [m], gyro white noise ``nd`` and a bias
    drawn per run (sigma ``sb``); the truth integrates the true ground arcs with the
    oracle's textbook arc, the gyro measures their true heading rate.

    The truth's rate jumps at every wheel step (each step's own noise); the gyro's
    samples are interpolated linearly, which smears a jump over one sample interval.
    At 500 Hz (10 samples per step) that is well below the gyro's noise; at 200 Hz it
    is not and the mean NEES reads about 3.3-3.5 (the test data's artefact, not the
    model's: 10 samples give 2.84 over 200 runs).
    """
    import numpy as np

    wheel_hz, imu_per_step = 50, 10
    dt = 1.0 / wheel_hz
    out = []
    for run in range(runs):
        rng = np.random.default_rng(run)
        bias = sb * rng.standard_normal()
        pipe = ReadingPipeline(settings(
            use_imu=True, wheel_noise_k_left=k, wheel_noise_k_right=k,
            wheel_radius_stddev_ratio=0.0, wheel_separation_stddev_ratio=0.0,
            gyro_noise_density=model_nd, gyro_bias_stddev=sb, gyro_bias_random_walk=0.0))
        truth: tuple[float, float, float] = (0.0, 0.0, 0.0)
        left = right = 0.0
        step = 0
        sigma = nd * math.sqrt(wheel_hz * imu_per_step)
        pipe.feed_imu(T0 - 5_000_000, 0.0, 0.0, bias + sigma * rng.standard_normal())
        pipe.feed(T0, NAMES, (0.0, 0.0))
        for seconds, v, w in ROUTE:
            d_l, d_r = (v - 0.5 * w * B) * dt, (v + 0.5 * w * B) * dt  # commanded arcs
            for _ in range(round(seconds * wheel_hz)):
                s_l = d_l + math.sqrt(k * abs(d_l)) * rng.standard_normal()
                s_r = d_r + math.sqrt(k * abs(d_r)) * rng.standard_normal()
                truth = arc(0.5 * (s_l + s_r), (s_r - s_l) / B, truth)
                rate = (s_r - s_l) / B / dt
                for j in range(imu_per_step):
                    ns = T0 + round((step + j / imu_per_step) * dt * 1e9)
                    pipe.feed_imu(ns, 0.0, 0.0, rate + bias + sigma * rng.standard_normal())
                step += 1
                left, right = left + d_l / R, right + d_r / R
                pipe.feed(T0 + round(step * dt * 1e9), NAMES, (left, right))
        p = pipe.estimator.pose
        cov = pipe.covariances()[0]
        m = np.array([[cov[0], cov[1], cov[5]], [cov[6], cov[7], cov[11]],
                      [cov[30], cov[31], cov[35]]])
        e = np.array([p.x - truth[0], p.y - truth[1],
                      math.remainder(p.theta - truth[2], 2 * math.pi)])
        out.append(float(e @ np.linalg.solve(m, e)))
    return out


def test_nees_of_the_final_pose_in_the_gyro_mode_is_inside_the_95_percent_bounds() -> None:
    runs = 120
    nees = _gyro_nees(runs, 1e-5, 1e-3, 0.005, 1e-3)
    low, high = _chi2_band(3 * runs)
    print(f"gyro-mode NEES over {runs} runs: mean {sum(nees) / runs:.3f}, band "
          f"[{low / runs:.3f}, {high / runs:.3f}]")
    assert low <= sum(nees) <= high, sum(nees) / runs
    # The same runs with a model that believes the gyro ten times better: overconfident.
    worse = _gyro_nees(40, 1e-5, 1e-2, 0.005, 1e-3)
    assert sum(worse) > _chi2_band(3 * 40)[1], sum(worse) / 40


def test_runtime_parameter_changes_keep_the_gyro_and_its_bias() -> None:
    """A change of a gyro parameter, or one that rebuilds the estimator, keeps the bias
    estimate, the pose and the gyro-aided heading (no jump, the slip still caught)."""
    import dataclasses

    d = Drive(slip=20.0)
    pipe = ReadingPipeline(settings(use_imu=True))
    changed = False
    for kind, s, a, b in events(d):
        if kind == "i":
            pipe.feed_imu(s, 0.0, 0.0, a)
            continue
        pipe.feed(s, NAMES, (a, b))
        if not changed and s >= T0 + 2_000_000_000:
            gyro = pipe.gyro
            assert gyro is not None
            gyro.bias = 1e-12  # a value only the estimate itself could carry on
            old = pipe.settings
            cov = pipe.covariances()[0]
            new_gyro = dataclasses.replace(old.gyro, timeout=0.2)  # type: ignore[type-var]
            pipe.reconfigure(dataclasses.replace(
                old, gyro=new_gyro,
                estimator=dataclasses.replace(old.estimator, max_wheel_speed=300.0)))
            assert pipe.gyro is gyro and gyro.config.timeout == 0.2 and gyro.bias == 1e-12
            assert pipe.estimator.heading is gyro
            assert pipe.covariances()[0] == cov  # the bias's share of it included
            changed = True
    g = pipe.stats.gyro
    assert g is not None and g.slips.events == 1
    pos, head = error(pipe, d)
    # A rebuilt estimator takes the next reading as its reference (the wheels' units may
    # have changed): that one step's turn and travel are not integrated, nothing else.
    assert head == pytest.approx(d.w / d.wheel_hz, abs=1e-9)
    assert pos < d.v / d.wheel_hz


def test_a_bag_played_in_a_loop_restarts_the_gyro_with_the_wheels() -> None:
    """Both clocks jump back 10 s (a looped play): the wheels restart at the origin
    (time_reset) and the gyro's samples of the new run are taken, none of the old run's
    kept: the second run ends on the circle as exactly as the first."""
    d = Drive(slip=20.0)
    evs = list(events(d))
    pipe = ReadingPipeline(settings(use_imu=True))
    for _ in range(2):
        for kind, s, a, b in evs:
            if kind == "i":
                assert pipe.feed_imu(s, 0.0, 0.0, a) == ""
            else:
                pipe.feed(s, NAMES, (a, b))
        pos, head = error(pipe, d)
        assert pos < 1e-9 and head < 1e-9
    assert pipe.stats.time_resets == 1
    g = pipe.stats.gyro
    assert g is not None and g.slips.events == 2 and not g.dropped


def test_a_robot_turned_by_hand_with_wheels_still_is_a_slip_not_a_bias() -> None:
    """Wheels still, the gyro says 0.5 rad/s for 1 s (someone turns the robot): the
    heading follows the gyro, one slip event, and the bias estimate stays put."""
    d = Drive(v=0.0, w=0.0, seconds=3.0)
    pipe = ReadingPipeline(settings(use_imu=True))
    for kind, s, a, b in events(d):
        t = (s - T0) * 1e-9
        if kind == "i":
            pipe.feed_imu(s, 0.0, 0.0, 0.5 if 1.0 < t <= 2.0 else 0.0)
        else:
            pipe.feed(s, NAMES, (a, b))
    g = pipe.stats.gyro
    assert g is not None and g.slips.events == 1
    # Linear interpolation between the samples at 1.0 s (0) and 1.005 s (0.5) and
    # likewise at 2 s: 0.5 * (1 s - 5 ms) + 2 * 0.5 * 0.5 * 5 ms = 0.5 rad exactly.
    assert pipe.estimator.pose.theta == pytest.approx(0.5, abs=1e-12)
    assert abs(g.bias) < 1e-9 and g.zero_velocity_updates > 0
