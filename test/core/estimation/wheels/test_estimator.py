"""OdometryEstimator end to end without DDS: closed forms and the safety rules.

Expected poses are circle geometry (constant curvature) computed here; the safety
rules are checked by comparing with an estimator that never saw the bad reading.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import replace

import pytest

from diffdrive_odom.core.errors import ConfigError
from diffdrive_odom.core.estimation.wheels.config import EstimatorConfig
from diffdrive_odom.core.estimation.wheels.encoders import EncoderConfig, Reason
from diffdrive_odom.core.estimation.wheels.estimator import OdometryEstimator
from diffdrive_odom.core.estimation.wheels.timeline import Status
from diffdrive_odom.core.geometry.integration import Pose2D
from diffdrive_odom.core.geometry.kinematics import Geometry
from diffdrive_odom.core.geometry.se2 import wrap_angle

import oracle

LEFT, RIGHT = "left_wheel_joint", "right_wheel_joint"
NAMES = [LEFT, RIGHT]
ONE = EncoderConfig((LEFT,), (RIGHT,))
GEOMETRY = Geometry(wheel_radius=0.1, wheel_separation=0.4)
DEFAULTS = EstimatorConfig()
T0 = 1_700_000_000_000_000_000  # a realistic epoch stamp in ns


def ns(seconds: float) -> int:
    return T0 + round(seconds * 1e9)


def make(geometry: Geometry = GEOMETRY, config: EstimatorConfig = DEFAULTS,
         encoders: EncoderConfig = ONE) -> OdometryEstimator:
    return OdometryEstimator(geometry, encoders, config)


def arc_pose(arc: float, heading: float) -> Pose2D:
    """Where an arc of length ``arc`` turning by ``heading`` ends, from the origin."""
    return Pose2D(*oracle.arc(arc, heading))


def assert_pose(got: Pose2D, expected: Pose2D, tol: float = 1e-12) -> None:
    assert abs(got.x - expected.x) <= tol, (got, expected)
    assert abs(got.y - expected.y) <= tol, (got, expected)
    assert abs(wrap_angle(got.theta - expected.theta)) <= tol, (got, expected)


def irregular_times(total: float) -> list[float]:
    """Stamps from 0 to about ``total`` with uneven gaps, as a real driver sends them."""
    gaps = (0.005, 0.02, 0.013, 0.031, 0.0101)
    times = [0.0]
    while times[-1] < total:
        times.append(times[-1] + gaps[len(times) % len(gaps)])
    return times


def feed_positions(est: OdometryEstimator,
                   readings: Sequence[tuple[float, float, float]]) -> None:
    for t, left, right in readings:
        verdict = est.update(ns(t), NAMES, [left, right])
        assert verdict.status in (Status.REFERENCE, Status.UPDATED), verdict


# --------------------------------------------------------------- joint lookup


def test_shuffled_order_and_extra_joints_give_the_same_pose() -> None:
    plain, shuffled = make(), make()
    for k in range(50):
        left, right = 0.02 * k, 0.035 * k
        assert plain.update(ns(0.01 * k), NAMES, [left, right]).has_new_pose
        verdict = shuffled.update(ns(0.01 * k), ["caster", RIGHT, "arm", LEFT],
                                  [123.0, right, math.nan, left])
        assert verdict.has_new_pose
        assert shuffled.pose == plain.pose


def test_missing_wheel_joint_drops_the_reading() -> None:
    est = make()
    feed_positions(est, [(0.0, 0.0, 0.0), (0.01, 0.1, 0.2)])
    before = est.pose
    verdict = est.update(ns(0.02), [LEFT, "caster"], [0.3, 0.0])
    assert verdict.status == Status.DROPPED and verdict.reason
    assert est.pose == before and est.stamp_ns == ns(0.01)


def test_several_wheels_per_side_are_averaged() -> None:
    four = make(encoders=EncoderConfig(("fl", "rl"), ("fr", "rr")))
    names = ["rr", "fl", "fr", "rl"]
    four.update(ns(0.0), names, [5.0, 1.0, -3.0, 2.0])
    # Left wheels turn 0.3 and 0.5 (mean 0.4), right 1.1 and 0.9 (mean 1.0).
    four.update(ns(0.05), names, [5.9, 1.3, -1.9, 2.5])
    arc = 0.1 * (0.4 + 1.0) / 2
    heading = 0.1 * (1.0 - 0.4) / 0.4
    assert_pose(four.pose, arc_pose(arc, heading))


# ---------------------------------------------------------- geometry and signs


def test_different_wheel_radii_follow_seed_003() -> None:
    # ELEC6530 homework eq. 1: v = (r_R w_R + r_L w_L) / 2, w = (r_R w_R - r_L w_L) / d.
    geometry = Geometry(0.1, 0.4, left_wheel_radius_multiplier=0.9,
                        right_wheel_radius_multiplier=1.2, wheel_separation_multiplier=1.1)
    r_left, r_right, d = 0.09, 0.12, 0.44
    est = make(geometry)
    feed_positions(est, [(t, 2.0 * t, 2.0 * t) for t in irregular_times(1.5)])
    duration = irregular_times(1.5)[-1]
    v = (r_right * 2.0 + r_left * 2.0) / 2
    w = (r_right * 2.0 - r_left * 2.0) / d
    assert_pose(est.pose, arc_pose(v * duration, w * duration))


def test_right_joint_measured_the_other_way_as_in_seed_000() -> None:
    est = make(Geometry(0.1, 0.4, right_wheel_sign=-1))
    feed_positions(est, [(0.01 * k, 0.05 * k, -0.05 * k) for k in range(101)])
    assert_pose(est.pose, Pose2D(0.1 * 5.0, 0.0, 0.0))


def test_geometry_change_applies_from_the_next_step() -> None:
    est = make()
    feed_positions(est, [(0.0, 0.0, 0.0), (0.1, 1.0, 1.0)])
    est.set_geometry(Geometry(0.2, 0.4))
    feed_positions(est, [(0.2, 2.0, 2.0)])
    assert_pose(est.pose, Pose2D(0.1 * 1.0 + 0.2 * 1.0, 0.0, 0.0))


# ----------------------------------------------------------- velocity-only input


def test_constant_wheel_speeds_from_velocity_only() -> None:
    est = make()
    times = irregular_times(2.0)
    for t in times:
        assert est.update(ns(t), NAMES, [], [3.0, 5.0]).has_new_pose
    v, w = 0.1 * (3.0 + 5.0) / 2, 0.1 * (5.0 - 3.0) / 0.4
    assert_pose(est.pose, arc_pose(v * times[-1], w * times[-1]))
    assert est.linear == pytest.approx(v, rel=1e-9)
    assert est.angular == pytest.approx(w, rel=1e-9)


@pytest.mark.parametrize(
    ("left_gain", "right_gain", "a", "k"),
    [
        (1.0, 3.0, 2.0, 1.5),  # accelerating on a circle of radius 0.3 m
        (1.0, 1.0, 0.5, 2.0),  # accelerating straight
        (2.0, -1.0, 2.0, -2.0),  # decelerating through zero into reverse
    ],
)
def test_linearly_changing_wheel_speeds_from_velocity_only(
    left_gain: float, right_gain: float, a: float, k: float
) -> None:
    # w_side(t) = gain * (a + k t): the ratio of the wheels, hence the curvature, is
    # constant, and the trapezoidal rule is exact for a linear speed, so the CIR steps
    # land on the circle: arc s(t) and heading phi(t) both grow as a t + k t^2 / 2.
    r, b = 0.05, 0.3
    est = make(Geometry(r, b))
    times = irregular_times(2.0)
    for t in times:
        speed = a + k * t
        assert est.update(ns(t), NAMES, [], [left_gain * speed, right_gain * speed]).has_new_pose
    t_end = times[-1]
    angle = a * t_end + k * t_end**2 / 2
    assert_pose(est.pose, arc_pose(r * (left_gain + right_gain) / 2 * angle,
                                   r * (right_gain - left_gain) / b * angle))
    # The twist is the step's mean: the speed at the middle of the last interval.
    mid_speed = a + k * (times[-2] + t_end) / 2
    assert est.linear == pytest.approx(r * (left_gain + right_gain) / 2 * mid_speed, abs=1e-9)
    assert est.angular == pytest.approx(r * (right_gain - left_gain) / b * mid_speed, abs=1e-9)


def test_switching_between_position_and_velocity_takes_a_new_reference() -> None:
    est = make()
    feed_positions(est, [(0.0, 0.0, 0.0), (0.1, 1.0, 1.0)])
    before = est.pose
    verdict = est.update(ns(0.2), NAMES, [], [50.0, 50.0])
    assert verdict.status == Status.REFERENCE
    assert est.pose == before
    assert est.update(ns(0.3), NAMES, [], [50.0, 50.0]).status == Status.UPDATED
    assert_pose(est.pose, Pose2D(0.1 * 1.0 + 0.1 * 50.0 * 0.1, 0.0, 0.0))


# ------------------------------------------------------ the first reading rule


def test_non_zero_first_reading_is_only_a_reference() -> None:
    est = make(Geometry(1.0, 1.0))
    verdict = est.update(ns(0.0), NAMES, [1234.5, -987.25])
    assert verdict.status == Status.REFERENCE and verdict.has_new_pose
    assert est.pose == Pose2D()
    assert est.linear == 0.0 and est.angular == 0.0
    # Then left 1 rad, right 2 rad in 0.1 s: radius 1.5 m through 1 rad.
    assert est.update(ns(0.1), NAMES, [1235.5, -985.25]).status == Status.UPDATED
    assert_pose(est.pose, arc_pose(1.5, 1.0))


# ------------------------------------------------------------ dropped readings


BAD_READINGS: list[tuple[str, float, list[str], list[float], list[float]]] = [
    ("nan position", 0.03, NAMES, [math.nan, 0.25], []),
    ("inf position", 0.03, NAMES, [0.15, math.inf], []),
    ("-inf position", 0.03, NAMES, [-math.inf, 0.25], []),
    ("nan velocity", 0.03, NAMES, [], [math.nan, 1.0]),
    ("short position", 0.03, NAMES, [0.15], []),
    ("short velocity", 0.03, NAMES, [], [1.0]),
    ("no data", 0.03, NAMES, [], []),
    ("missing wheel", 0.03, [LEFT], [0.15], []),
    ("repeated stamp", 0.02, NAMES, [0.15, 0.25], []),
    # Older readings carry the positions of their stamps (5 and 15 rad/s, as the good ones).
    ("slightly older stamp", 0.019, NAMES, [0.095, 0.285], []),
    ("older, under the jump threshold", 0.02 - 0.999, NAMES, [-4.895, -14.685], []),
]


@pytest.mark.parametrize(("what", "t", "names", "position", "velocity"), BAD_READINGS,
                         ids=[b[0] for b in BAD_READINGS])
def test_unusable_reading_is_dropped_without_touching_state(
    what: str, t: float, names: list[str], position: list[float], velocity: list[float]
) -> None:
    good = [(0.0, 0.0, 0.0), (0.02, 0.1, 0.3)]
    after = (0.04, 0.2, 0.6)  # 5 and 15 rad/s throughout
    est, clean = make(), make()
    feed_positions(est, good)
    feed_positions(clean, good)
    state = (est.pose, est.stamp_ns, est.linear, est.angular, est.last_step)
    verdict = est.update(ns(t), names, position, velocity)
    assert verdict.status == Status.DROPPED and verdict.reason, what
    assert not verdict.has_new_pose
    assert (est.pose, est.stamp_ns, est.linear, est.angular, est.last_step) == state
    # The next good reading integrates from the last good one, as if nothing happened.
    feed_positions(est, [after])
    feed_positions(clean, [after])
    assert est.pose == clean.pose
    # An older reading is a true sample of the motion: the twist may come from it.
    assert est.linear == pytest.approx(clean.linear, rel=1e-12)
    assert est.angular == pytest.approx(clean.angular, rel=1e-12)


@pytest.mark.parametrize(("threshold", "back", "restarts"),
                         [(1.0, 1.5, True), (1.0, 0.5, False), (0.1, 0.2, True),
                          (0.1, 0.05, False), (0.0, 0.001, True)])
def test_stamp_far_back_restarts_at_the_origin(
    threshold: float, back: float, restarts: bool
) -> None:
    est = make(config=EstimatorConfig(time_jump_threshold=threshold))
    feed_positions(est, [(10.0, 0.0, 0.0), (10.1, 1.0, 2.0)])
    moved = est.pose
    assert moved != Pose2D()
    verdict = est.update(ns(10.1 - back), NAMES, [7.0, 7.0])
    if not restarts:
        assert verdict.status == Status.DROPPED
        assert est.pose == moved
        return
    assert verdict.status == Status.TIME_RESET and verdict.has_new_pose and verdict.reason
    assert est.pose == Pose2D()
    assert (est.linear, est.angular, est.last_step) == (0.0, 0.0, None)
    assert est.stamp_ns == ns(10.1 - back)
    # The bag's first reading is the new reference: only motion from it counts.
    assert est.update(ns(10.1 - back + 0.05), NAMES, [7.5, 7.5]).status == Status.UPDATED
    assert_pose(est.pose, Pose2D(0.1 * 0.5, 0.0, 0.0))


@pytest.mark.parametrize(("left", "right"), [(5.0, 0.3), (0.3, -4.0), (-100.0, -100.0)])
def test_implausible_step_is_skipped_and_reanchors(left: float, right: float) -> None:
    # max 10 rad/s over 0.1 s allows 1 rad per step.
    est = make(config=EstimatorConfig(max_wheel_speed=10.0))
    feed_positions(est, [(0.0, 0.0, 0.0), (0.1, 0.9, 0.9)])
    assert_pose(est.pose, Pose2D(0.09, 0.0, 0.0))
    before = est.pose
    verdict = est.update(ns(0.2), NAMES, [0.9 + left, 0.9 + right])
    assert verdict.status == Status.REANCHORED and verdict.reason
    assert not verdict.has_new_pose
    assert est.pose == before and est.stamp_ns == ns(0.2)
    # The glitch value is the new reference: the next step counts from it.
    assert est.update(ns(0.3), NAMES, [1.4 + left, 1.4 + right]).status == Status.UPDATED
    assert_pose(est.pose, Pose2D(0.09 + 0.05, 0.0, 0.0))


# ------------------------------------------------------------- reset / restart


def test_reset_returns_to_zero_with_no_jump_on_the_next_step() -> None:
    est = make()
    feed_positions(est, [(0.0, 3.0, 4.0), (0.1, 4.0, 6.0), (0.2, 5.0, 8.0)])
    assert est.pose != Pose2D()
    est.reset()
    assert est.pose == Pose2D()
    assert (est.linear, est.angular, est.last_step) == (0.0, 0.0, None)
    assert est.stamp_ns == ns(0.2)  # the last reading stays the reference
    assert est.update(ns(0.3), NAMES, [5.5, 8.5]).status == Status.UPDATED
    assert_pose(est.pose, Pose2D(0.05, 0.0, 0.0))


def test_restart_forgets_the_reference() -> None:
    est = make()
    feed_positions(est, [(0.0, 3.0, 4.0), (0.1, 4.0, 6.0)])
    est.restart()
    assert est.stamp_ns is None and est.pose == Pose2D()
    assert est.update(ns(0.2), NAMES, [90.0, -90.0]).status == Status.REFERENCE
    assert est.pose == Pose2D()


# ----------------------------------------------------------------------- twist


def test_twist_is_the_step_over_its_interval() -> None:
    est = make()
    feed_positions(est, [(0.0, 0.0, 0.0), (0.05, 0.2, 0.6)])
    ds, dtheta = 0.1 * (0.2 + 0.6) / 2, 0.1 * (0.6 - 0.2) / 0.4
    assert est.last_step is not None
    assert est.last_step.dt == pytest.approx(0.05, abs=1e-15)
    assert est.last_step.ds == pytest.approx(ds, abs=1e-15)
    assert est.last_step.dtheta == pytest.approx(dtheta, abs=1e-15)
    assert est.linear == pytest.approx(ds / 0.05, rel=1e-12)
    assert est.angular == pytest.approx(dtheta / 0.05, rel=1e-12)


def test_rolling_window_smooths_the_twist_only() -> None:
    window = 3
    plain = make()
    smooth = make(config=replace(DEFAULTS, velocity_rolling_window_size=window))
    readings = [(0.0, 0.0, 0.0)]
    step_linear: list[float] = []  # each step's own twist, from the geometry
    step_angular: list[float] = []
    for dt, dl, dr in [(0.02, 0.1, 0.1), (0.01, 0.3, -0.1), (0.03, 0.0, 0.5),
                       (0.02, 0.2, 0.2), (0.05, -0.4, 0.1), (0.02, 0.1, 0.3)]:
        t, left, right = readings[-1]
        readings.append((t + dt, left + dl, right + dr))
        step_linear.append(0.1 * (dl + dr) / 2 / dt)
        step_angular.append(0.1 * (dr - dl) / 0.4 / dt)
    for k, reading in enumerate(readings):
        feed_positions(plain, [reading])
        feed_positions(smooth, [reading])
        assert smooth.pose == plain.pose  # never applied to the pose
        if k == 0:
            continue
        assert plain.linear == pytest.approx(step_linear[k - 1], rel=1e-9)
        recent = slice(max(0, k - window), k)
        assert smooth.linear == pytest.approx(
            sum(step_linear[recent]) / len(step_linear[recent]), rel=1e-9)
        assert smooth.angular == pytest.approx(
            sum(step_angular[recent]) / len(step_angular[recent]), rel=1e-9)
    # After a reset the window starts empty again.
    smooth.reset()
    plain.reset()
    t, left, right = readings[-1]
    feed_positions(plain, [(t + 0.02, left + 0.2, right + 0.1)])
    feed_positions(smooth, [(t + 0.02, left + 0.2, right + 0.1)])
    assert (smooth.linear, smooth.angular) == (plain.linear, plain.angular)


# ------------------------------------------------------------------ reading gaps


def test_driver_restart_after_a_pause_is_a_new_reference() -> None:
    """Counters 0 -> 20 rad, 4 s of silence, counters from 0: 5 rad/s backwards would pass
    the speed check, so only the gap rule keeps the pose."""
    est = make()
    feed_positions(est, [(0.1 * k, 2.0 * k, 2.0 * k) for k in range(11)])  # 20 rad, 1 s
    assert_pose(est.pose, Pose2D(0.1 * 20.0, 0.0, 0.0))
    verdict = est.update(ns(5.0), NAMES, [0.0, 0.0])
    # Far ahead: a pause or a lone outlier? Held until the next reading tells.
    assert verdict.status == Status.HELD and verdict.code == Reason.HELD
    assert not verdict.has_new_pose and verdict.dropped_code is None
    assert_pose(est.pose, Pose2D(2.0, 0.0, 0.0))
    verdict = est.update(ns(5.1), NAMES, [1.0, 1.0])  # continues from it: a real pause
    assert verdict.status == Status.UPDATED and verdict.code == Reason.GAP
    assert "4.000 s" in verdict.reason and "max_reading_gap" in verdict.reason
    assert verdict.warning == "re-anchored"
    # The pose as the pause left it plus the 1 rad after; twist from that step only.
    assert_pose(est.pose, Pose2D(0.1 * 21.0, 0.0, 0.0))
    assert est.linear == pytest.approx(0.1 * 1.0 / 0.1, rel=1e-12)
    feed_positions(est, [(5.0 + 0.1 * k, 1.0 * k, 1.0 * k) for k in range(2, 6)])
    assert_pose(est.pose, Pose2D(0.1 * 25.0, 0.0, 0.0))


def test_a_5_hz_driver_integrates_with_the_default_gap() -> None:
    est = make()
    feed_positions(est, [(0.2 * k, 0.1 * k, 0.1 * k) for k in range(26)])
    assert_pose(est.pose, Pose2D(0.1 * 2.5, 0.0, 0.0), 1e-12)


@pytest.mark.parametrize(("gap", "pause", "integrated"),
                         [(1.0, 0.999, True), (1.0, 1.001, False), (math.inf, 60.0, True),
                          (0.05, 0.06, False)])
def test_max_reading_gap_bounds_the_integrated_interval(
    gap: float, pause: float, integrated: bool
) -> None:
    est = make(config=EstimatorConfig(max_reading_gap=gap))
    feed_positions(est, [(0.0, 0.0, 0.0)])
    verdict = est.update(ns(pause), NAMES, [0.5, 0.5])
    assert (verdict.status == Status.UPDATED) is integrated, verdict
    assert (verdict.status == Status.HELD) is not integrated, verdict
    assert_pose(est.pose, Pose2D(0.05 if integrated else 0.0, 0.0, 0.0))


@pytest.mark.parametrize("value", [0.0, -1.0, math.nan, -math.inf])
def test_max_reading_gap_must_be_positive(value: float) -> None:
    with pytest.raises(ConfigError) as err:
        EstimatorConfig(max_reading_gap=value)
    assert err.value.field == "max_reading_gap"


CODES = {
    "nan position": Reason.NON_FINITE, "inf position": Reason.NON_FINITE,
    "-inf position": Reason.NON_FINITE, "nan velocity": Reason.NON_FINITE,
    "short position": Reason.BAD_ARRAY, "short velocity": Reason.BAD_ARRAY,
    "no data": Reason.NO_DATA, "missing wheel": Reason.MISSING_JOINT,
    "repeated stamp": Reason.STALE_STAMP, "slightly older stamp": Reason.STALE_STAMP,
    "older, under the jump threshold": Reason.STALE_STAMP,
}


def test_every_dropped_reading_has_a_stable_code() -> None:
    assert set(CODES) == {b[0] for b in BAD_READINGS}
    for what, t, names, position, velocity in BAD_READINGS:
        est = make()
        feed_positions(est, [(0.0, 0.0, 0.0), (0.02, 0.1, 0.3)])
        assert est.update(ns(t), names, position, velocity).code == CODES[what], what


def test_missing_joint_reason_names_what_was_expected_and_what_came() -> None:
    verdict = make().update(ns(0.0), ["wheel_l", "wheel_r"], [0.0, 0.0])
    assert verdict.code == Reason.MISSING_JOINT
    for name in (LEFT, RIGHT, "wheel_l", "wheel_r"):
        assert repr(name) in verdict.reason, verdict.reason


# ------------------------------------------------- never crash, never lie (issue 9)

TWO_L, TWO_R = ("fl", "rl"), ("fr", "rr")
TWO = EncoderConfig(TWO_L, TWO_R)
FOUR = [*TWO_L, *TWO_R]
HUGE = 1.7e308


def finite_state(est: OdometryEstimator) -> bool:
    step = est.last_step
    values = [est.pose.x, est.pose.y, est.pose.theta, est.linear, est.angular]
    if step is not None:
        values += [step.dt, step.ds, step.dtheta]
    return all(math.isfinite(v) for v in values)


@pytest.mark.parametrize("bad", [[(HUGE,) * 4], [(-HUGE, -HUGE, HUGE, HUGE)],
                                 [(-HUGE, HUGE, 0.0, 0.0), (HUGE, -HUGE, 0.0, 0.0)]],
                         ids=["all huge", "opposite sides", "-inf + inf within a side"])
def test_huge_positions_on_two_wheels_per_side_are_skipped(
    bad: list[tuple[float, ...]]
) -> None:
    """Overflow in the side mean (and -inf + inf) used to kill the node."""
    est = make(encoders=TWO)
    assert est.update(ns(0.0), FOUR, [0.0] * 4).status == Status.REFERENCE
    t = 0.0
    for values in bad:
        t += 0.02
        verdict = est.update(ns(t), FOUR, list(values))
        assert verdict.status == Status.REANCHORED and verdict.code == Reason.TOO_FAST
        assert est.pose == Pose2D() and finite_state(est)
    # Back to sane counts: one skipped step (from the glitch), then tracked exactly.
    assert est.update(ns(t + 0.02), FOUR, [1.0] * 4).status == Status.REANCHORED
    assert est.update(ns(t + 0.04), FOUR, [1.5] * 4).status == Status.UPDATED
    assert_pose(est.pose, Pose2D(0.1 * 0.5, 0.0, 0.0))


def test_wheels_of_a_side_that_disagree_wildly_are_not_averaged_into_a_step() -> None:
    est = make(encoders=TWO)
    est.update(ns(0.0), FOUR, [0.0] * 4)
    verdict = est.update(ns(0.02), FOUR, [-1e6, 1e6, 0.0, 0.0])  # side mean 0: plausible
    assert verdict.status == Status.REANCHORED and "max_wheel_speed" in verdict.reason


COUNTER = EncoderConfig((LEFT,), (RIGHT,), ticks_per_revolution=4096.0, counter_bits=16)
TICK = 2 * math.pi / 4096


@pytest.mark.parametrize("count", [-HUGE, HUGE, 1e300, 65536.0, -32769.0])
def test_count_outside_the_counter_range_is_dropped(count: float) -> None:
    """-1.7e308 then 1.7e308 killed the node (floor(inf)); 1e300 unwrapped to a zero step."""
    est = make(encoders=COUNTER)
    feed_positions(est, [(0.0, 65000.0, 100.0), (0.02, 65100.0, 200.0)])
    before = est.pose
    verdict = est.update(ns(0.04), NAMES, [count, 300.0])
    assert verdict.status == Status.DROPPED and verdict.code == Reason.OUT_OF_RANGE
    assert "encoder_counter_bits" in verdict.reason
    assert est.pose == before
    # The real motion after it is not lost: 65100 + 600 wraps to 164.
    assert est.update(ns(0.06), NAMES, [164.0, 800.0]).status == Status.UPDATED
    assert_pose(est.pose, Pose2D(0.1 * 700 * TICK, 0.0, 0.0))


def test_counter_range_limits_are_signed_or_unsigned() -> None:
    est = make(encoders=COUNTER)
    for k, count in enumerate([-32768.0, 65535.0, 0.0]):
        assert est.update(ns(0.02 * k), NAMES, [count, 0.0]).code != Reason.OUT_OF_RANGE


@pytest.mark.parametrize("jump", [HUGE, 1e200, 1e20, -1e20])
def test_absurd_step_with_no_speed_check_never_makes_the_pose_non_finite(jump: float) -> None:
    """``max_wheel_speed: .inf``: sinc(inf) killed the node, or the pose became NaN."""
    est = make(config=EstimatorConfig(max_wheel_speed=math.inf))
    feed_positions(est, [(0.0, 0.0, 0.0), (0.02, 0.1, 0.1)])
    before = est.pose
    verdict = est.update(ns(0.04), NAMES, [0.1 + jump, 0.1])
    assert verdict.status == Status.REANCHORED and verdict.code == Reason.TOO_FAST
    assert "m in one step" in verdict.reason and verdict.warning == "re-anchored"
    assert est.pose == before and finite_state(est)
    # Published and tracked again after the glitch.
    est.update(ns(0.06), NAMES, [0.2, 0.2])  # from the glitch value: skipped too
    assert est.update(ns(0.08), NAMES, [0.3, 0.4]).has_new_pose
    assert finite_state(est)


def test_a_large_but_physical_step_passes_with_no_speed_check() -> None:
    est = make(config=EstimatorConfig(max_wheel_speed=math.inf))
    feed_positions(est, [(0.0, 0.0, 0.0), (0.5, 9000.0, 9000.0)])  # 900 m in one step
    assert_pose(est.pose, Pose2D(900.0, 0.0, 0.0), 1e-9)


def test_a_step_whose_integration_overflows_is_never_committed() -> None:
    # A (valid, absurd) 1e-307 m axle: 100 m of wheel difference turns by inf rad.
    est = make(Geometry(0.1, 1e-307), config=EstimatorConfig(max_wheel_speed=math.inf))
    feed_positions(est, [(0.0, 0.0, 0.0), (0.02, 1e-300, 0.0)])
    before = est.pose
    verdict = est.update(ns(0.04), NAMES, [1e3, 0.0])
    assert verdict.status == Status.REANCHORED and "not a finite number" in verdict.reason
    assert est.pose == before and finite_state(est)


def test_a_lone_reading_far_in_the_future_is_an_outlier() -> None:
    """+100 s made the next normal reading look like a bag loop (restart at the origin)."""
    est = make()
    feed_positions(est, [(0.02 * k, 0.1 * k, 0.1 * k) for k in range(11)])
    verdict = est.update(ns(0.2 + 100.0), NAMES, [1.1, 1.1])
    assert verdict.status == Status.HELD and not verdict.has_new_pose
    assert not verdict.warning
    verdict = est.update(ns(0.22), NAMES, [1.1, 1.1])
    assert verdict.status == Status.UPDATED and verdict.code == Reason.FUTURE_STAMP
    assert verdict.dropped_code == Reason.FUTURE_STAMP and verdict.warning == "dropped"
    assert "100.000 s" in verdict.reason
    assert_pose(est.pose, Pose2D(0.1 * 1.1, 0.0, 0.0))
    assert est.linear == pytest.approx(0.1 * 5.0, rel=1e-9)  # 0.1 rad per 20 ms
    feed_positions(est, [(0.02 * k, 0.1 * k, 0.1 * k) for k in range(12, 21)])
    assert_pose(est.pose, Pose2D(0.1 * 2.0, 0.0, 0.0))


def test_a_bogus_hour_ahead_never_licenses_kilometres() -> None:
    """+1 h with +1e5 rad passed the speed check (the allowed travel grew with dt)."""
    est = make()
    feed_positions(est, [(0.0, 0.0, 0.0), (0.02, 0.1, 0.1)])
    assert est.update(ns(0.02 + 3600.0), NAMES, [1e5, 1e5]).status == Status.HELD
    assert est.update(ns(0.04), NAMES, [0.2, 0.2]).code == Reason.FUTURE_STAMP
    assert_pose(est.pose, Pose2D(0.1 * 0.2, 0.0, 0.0))


def test_two_far_readings_in_a_row_the_second_one_decides() -> None:
    est = make()
    feed_positions(est, [(0.0, 0.0, 0.0)])
    assert est.update(ns(100.0), NAMES, [5.0, 5.0]).status == Status.HELD
    verdict = est.update(ns(4.0), NAMES, [0.0, 0.0])  # a real 4 s pause, still far ahead
    assert verdict.status == Status.HELD and verdict.dropped_code == Reason.FUTURE_STAMP
    verdict = est.update(ns(4.02), NAMES, [0.1, 0.1])  # continues from the 4 s one
    assert verdict.code == Reason.GAP and "4.000 s" in verdict.reason
    assert_pose(est.pose, Pose2D(0.01, 0.0, 0.0))


def test_a_bag_loop_after_a_held_reading_still_restarts() -> None:
    est = make()
    feed_positions(est, [(10.0, 0.0, 0.0), (10.02, 0.1, 0.1)])
    assert est.update(ns(200.0), NAMES, [5.0, 5.0]).status == Status.HELD
    assert est.update(ns(0.0), NAMES, [0.0, 0.0]).status == Status.TIME_RESET
    assert est.update(ns(0.02), NAMES, [0.1, 0.1]).status == Status.UPDATED
    assert_pose(est.pose, Pose2D(0.01, 0.0, 0.0))


@pytest.mark.parametrize(("left_speed", "right_speed"), [(5.0, 5.0), (4.0, 6.0), (150.0, 190.0)])
def test_stamps_stepping_back_lose_no_motion_and_spike_no_twist(
    left_speed: float, right_speed: float
) -> None:
    """The issue's numbers: 50 Hz, at 1 s the driver's clock steps back 0.3 s, 0.5 s more.

    Constant wheel speeds: the path is one circle, so pose and twist have a closed form
    at every true time. On main the first step after the stale readings covered 0.32 s
    of motion in 0.02 s of stamps: a 16x twist spike, or (fast wheels) a skipped step.
    """
    est = make()
    period, back = 0.02, 0.3
    arc_rate = 0.1 * (left_speed + right_speed) / 2  # m/s
    turn_rate = 0.1 * (right_speed - left_speed) / 0.4  # rad/s
    stale = 0
    for k in range(76):  # true times 0 .. 1.5 s
        t = period * k
        stamp = t if t <= 1.0 + 1e-9 else t - back
        verdict = est.update(ns(stamp), NAMES, [left_speed * t, right_speed * t])
        assert verdict.status in (Status.REFERENCE, Status.UPDATED, Status.DROPPED), verdict
        stale += verdict.status == Status.DROPPED
        if verdict.status == Status.UPDATED:
            assert_pose(est.pose, arc_pose(arc_rate * t, turn_rate * t), 1e-9)
            assert est.linear == pytest.approx(arc_rate, rel=1e-9)
            assert est.angular == pytest.approx(turn_rate, rel=1e-9, abs=1e-12)
    assert stale == 15  # the readings stamped 0.72 .. 1.00 s
    assert_pose(est.pose, arc_pose(arc_rate * 1.5, turn_rate * 1.5), 1e-9)
