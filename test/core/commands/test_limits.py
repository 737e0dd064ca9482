"""The limiter against closed-form motion profiles (constant acceleration, jerk ramps).

Expected times come from kinematics of uniformly accelerated motion, not from runs of
the code: a step to V under acceleration A takes V / A; under jerk J alone it takes
sqrt(2 V / J); under A and J it takes V / A + A / (2 J).
"""

from __future__ import annotations

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from diffdrive_odom.core.commands.limits import (
    AxisLimiter,
    AxisLimits,
    CommandLimits,
    LimitError,
    TwistLimiter,
    Watchdog,
    ddc_axis_limits,
)
from diffdrive_odom.core.geometry.kinematics import Geometry, body_increment

DT = 0.01
EPS = 1e-9


def profile(limiter: AxisLimiter, target: float, seconds: float, dt: float = DT) -> list[float]:
    """Velocities after each step of ``dt`` while commanding ``target``."""
    return [limiter.limit(target, dt) for _ in range(round(seconds / dt))]


def first_time_at(values: list[float], target: float, dt: float = DT) -> float:
    """Time (end of step) at which ``target`` is first reached (within EPS)."""
    for i, v in enumerate(values):
        if abs(v - target) <= 1e-9:
            return (i + 1) * dt
    raise AssertionError(f"{target} never reached; last {values[-1]}")


@pytest.mark.parametrize("dt", [0.01, 0.02, 0.005])
def test_acceleration_step_reaches_target_after_v_over_a_and_not_before(dt: float) -> None:
    lim = AxisLimiter(AxisLimits(max_acceleration=2.0))
    values = profile(lim, 1.0, 1.0, dt)
    assert first_time_at(values, 1.0, dt) == pytest.approx(0.5, abs=dt / 2)
    for i, v in enumerate(values):
        t = (i + 1) * dt
        assert v <= 2.0 * t + EPS  # never faster than the ramp
    assert values[-1] == 1.0


def test_deceleration_defaults_to_minus_acceleration_as_in_control_toolbox() -> None:
    lim = AxisLimiter(AxisLimits(max_acceleration=2.0))
    lim.reset(1.0)
    values = profile(lim, 0.0, 1.0)
    assert first_time_at(values, 0.0) == pytest.approx(0.5, abs=DT / 2)


def test_deceleration_limit_alone_limits_braking_only() -> None:
    lim = AxisLimiter(AxisLimits(max_deceleration=-4.0))
    lim.reset(1.0)
    values = profile(lim, 0.0, 0.5)
    assert first_time_at(values, 0.0) == pytest.approx(0.25, abs=DT / 2)
    assert all(b - a >= -4.0 * DT - EPS for a, b in zip([1.0, *values], values, strict=False))
    # Speeding up is not limited: a step to 2 m/s from 1 m/s is immediate.
    lim.reset(1.0)
    assert lim.limit(2.0, DT) == 2.0


def test_asymmetric_forward_limits() -> None:
    lim = AxisLimiter(AxisLimits(max_acceleration=1.0, max_deceleration=-4.0))
    up = profile(lim, 1.0, 2.0)
    assert first_time_at(up, 1.0) == pytest.approx(1.0, abs=DT / 2)
    down = profile(lim, 0.0, 1.0)
    assert first_time_at(down, 0.0) == pytest.approx(0.25, abs=DT / 2)


def test_reverse_limits() -> None:
    lim = AxisLimiter(AxisLimits(max_acceleration=1.0, max_acceleration_reverse=-0.5,
                                 max_deceleration_reverse=2.0))
    back = profile(lim, -1.0, 3.0)
    assert first_time_at(back, -1.0) == pytest.approx(2.0, abs=DT / 2)
    stop = profile(lim, 0.0, 1.0)
    assert first_time_at(stop, 0.0) == pytest.approx(0.5, abs=DT / 2)


def test_reverse_fallbacks_follow_control_toolbox() -> None:
    lim = AxisLimits(max_acceleration=3.0, max_deceleration=-5.0)
    assert lim.reverse_start == -3.0  # max_acceleration_reverse = -max_acceleration
    assert lim.reverse_bounds == (-3.0, 5.0)  # max_deceleration_reverse = -max_deceleration
    assert AxisLimits(max_acceleration=3.0).forward_bounds == (-3.0, 3.0)


def test_braking_through_zero_switches_to_reverse_acceleration() -> None:
    # Hard brake (-10) but gentle reverse start (-1): from +1 to -1 takes
    # 1/10 s of braking plus 1/1 s of reverse acceleration.
    lim = AxisLimiter(AxisLimits(max_acceleration=1.0, max_deceleration=-10.0,
                                 max_acceleration_reverse=-1.0))
    lim.reset(1.0)
    values = profile(lim, -1.0, 2.0)
    assert first_time_at(values, -1.0) == pytest.approx(1.1, abs=DT)
    # Once moving backwards, no step speeds up faster than the reverse limit.
    prev = 0.0
    for v in values:
        if prev < 0.0:
            assert v - prev >= -1.0 * DT - EPS
        prev = v


def test_jerk_alone_reaches_step_after_sqrt_2v_over_j() -> None:
    lim = AxisLimiter(AxisLimits(max_jerk=8.0))
    values = profile(lim, 1.0, 1.0, 0.001)
    assert first_time_at(values, 1.0, 0.001) == pytest.approx(math.sqrt(2 * 1.0 / 8.0), abs=0.002)
    accelerations = [(b - a) / 0.001 for a, b in zip([0.0, *values], values, strict=False)]
    for a0, a1 in zip([0.0, *accelerations], accelerations, strict=False):
        if a1 > a0:  # building up: bounded by the jerk
            assert a1 - a0 <= 8.0 * 0.001 + 1e-6


def test_jerk_and_acceleration_give_trapezoidal_acceleration() -> None:
    a_max, j_max, v = 2.0, 8.0, 1.0
    lim = AxisLimiter(AxisLimits(max_acceleration=a_max, max_jerk=j_max))
    dt = 0.001
    values = profile(lim, v, 1.5, dt)
    assert first_time_at(values, v, dt) == pytest.approx(v / a_max + a_max / (2 * j_max),
                                                         abs=0.003)
    assert max(b - a for a, b in zip([0.0, *values], values, strict=False)) <= a_max * dt + EPS


def test_jerk_limits_braking_build_up_and_never_overshoots() -> None:
    lim = AxisLimiter(AxisLimits(max_jerk=10.0))
    lim.reset(1.0)
    values = profile(lim, 0.0, 2.0, 0.001)
    assert first_time_at(values, 0.0, 0.001) == pytest.approx(math.sqrt(2 / 10.0), abs=0.002)
    assert min(values) >= 0.0


def test_velocity_limits_and_min_default() -> None:
    lim = AxisLimiter(AxisLimits(max_velocity=0.5))
    assert lim.limit(2.0, DT) == 0.5
    assert lim.limit(-2.0, DT) == -0.5
    no_reverse = AxisLimiter(AxisLimits(max_velocity=0.5, min_velocity=0.0))
    assert no_reverse.limit(-1.0, DT) == 0.0


def test_nan_means_no_limit() -> None:
    lim = AxisLimiter(AxisLimits())
    assert lim.limit(7.5, DT) == 7.5
    assert lim.limit(-7.5, DT) == -7.5


def test_no_time_no_change() -> None:
    lim = AxisLimiter(AxisLimits(max_acceleration=1.0))
    lim.reset(0.3)
    assert lim.limit(5.0, 0.0) == 0.3


@pytest.mark.parametrize(
    ("field", "value"),
    [
        ("max_acceleration", -1.0),
        ("max_acceleration", 0.0),
        ("max_deceleration", 2.0),
        ("max_acceleration_reverse", 1.0),
        ("max_deceleration_reverse", -1.0),
        ("max_jerk", -3.0),
        ("min_jerk", 3.0),
        ("max_velocity", -0.1),
        ("min_velocity", 0.1),
        ("max_velocity", math.inf),
    ],
)
def test_unusable_limits_are_refused_by_name(field: str, value: float) -> None:
    with pytest.raises(LimitError) as err:
        AxisLimits(**{field: value})
    assert err.value.field == field


def test_max_wheel_velocity_validation() -> None:
    with pytest.raises(LimitError, match="max_wheel_velocity"):
        CommandLimits(max_wheel_velocity=-1.0)
    CommandLimits(max_wheel_velocity=0.0)  # 0 = no limit, like .nan


finite_limit = st.one_of(st.just(math.nan), st.floats(0.1, 10.0))


@settings(max_examples=200, deadline=None)
@given(
    acc=finite_limit, dec=finite_limit, acc_rev=finite_limit, dec_rev=finite_limit,
    vmax=finite_limit,
    targets=st.lists(st.floats(-3.0, 3.0), min_size=1, max_size=60),
    dt=st.floats(0.002, 0.1),
)
def test_every_step_respects_the_bound_of_its_direction(
    acc: float, dec: float, acc_rev: float, dec_rev: float, vmax: float,
    targets: list[float], dt: float,
) -> None:
    limits = AxisLimits(max_velocity=vmax, max_acceleration=acc, max_deceleration=-dec,
                        max_acceleration_reverse=-acc_rev, max_deceleration_reverse=dec_rev)
    low_v, high_v = limits.velocity_bounds
    f_low, f_high = limits.forward_bounds
    r_low, r_high = limits.reverse_bounds
    lim = AxisLimiter(limits)
    v0 = 0.0
    for target in targets:
        v = lim.limit(target, dt)
        assert low_v - EPS <= v <= high_v + EPS
        dv = v - v0
        tol = 1e-9 * (1 + abs(v0))
        if v0 > 0.0 and v >= 0.0:
            assert f_low * dt - tol <= dv <= f_high * dt + tol
        elif v0 < 0.0 and v <= 0.0:
            assert r_low * dt - tol <= dv <= r_high * dt + tol
        elif v0 == 0.0:
            assert r_low * dt - tol <= dv <= f_high * dt + tol
        else:  # crossed zero: braking until the stop, then the other direction's start
            brake, start = (f_low, r_low) if v0 > 0.0 else (r_high, f_high)
            t_stop = -v0 / brake if math.isfinite(brake) else 0.0
            assert 0.0 <= t_stop <= dt + EPS
            assert abs(v) <= abs(start) * (dt - t_stop) + tol
        # Never moves away from the target.
        assert min(v0, target) - tol <= v <= max(v0, target) + tol
        v0 = v


def test_wheel_saturation_feeds_back_into_the_limiter() -> None:
    # Saturated at half the commanded speed, then a stop: braking starts from the real
    # (saturated) speed, so the stop takes (v/2) / decel, not v / decel.
    geometry = Geometry(wheel_radius=0.1, wheel_separation=0.4)
    limits = CommandLimits(AxisLimits(max_acceleration=100.0, max_deceleration=-1.0),
                           AxisLimits(), max_wheel_velocity=10.0)  # 10 rad/s = 1 m/s
    tl = TwistLimiter(limits, geometry)
    for _ in range(100):
        out = tl.step(2.0, 0.0, DT)
    assert out.linear == pytest.approx(1.0)
    assert out.wheel_scale == pytest.approx(0.5)
    assert max(abs(out.left), abs(out.right)) == pytest.approx(10.0)
    steps = 0
    while tl.step(0.0, 0.0, DT).linear > 0.0:
        steps += 1
    assert steps * DT == pytest.approx(1.0, abs=2 * DT)


def test_twist_limiter_output_is_the_twist_of_its_wheels() -> None:
    geometry = Geometry(wheel_radius=0.05, wheel_separation=0.3, left_wheel_sign=-1)
    tl = TwistLimiter(CommandLimits(max_wheel_velocity=5.0), geometry)
    out = tl.step(0.8, -2.0, DT)
    v, w = body_increment(geometry, out.left, out.right)
    assert (v, w) == pytest.approx((out.linear, out.angular))
    assert max(abs(out.left), abs(out.right)) <= 5.0 + 1e-12


def test_settled_is_where_the_limited_steps_end_up() -> None:
    # v capped at 1 m/s, w at 2 rad/s: wheels (1 -+ 2 * 0.2) / 0.1 = 6 and 14 rad/s;
    # acceleration and jerk only delay getting there.
    geometry = Geometry(wheel_radius=0.1, wheel_separation=0.4)
    limits = CommandLimits(AxisLimits(max_velocity=1.0, max_acceleration=3.0),
                           AxisLimits(max_velocity=2.0, max_jerk=50.0), max_wheel_velocity=20.0)
    tl = TwistLimiter(limits, geometry)
    assert tl.settled(5.0, 9.0) == pytest.approx((6.0, 14.0))
    for _ in range(300):
        out = tl.step(5.0, 9.0, DT)
    assert (out.left, out.right) == pytest.approx((6.0, 14.0))
    # With a 10 rad/s wheel limit both scale by 10 / 14 (the curvature kept).
    saturated = TwistLimiter(CommandLimits(AxisLimits(max_velocity=1.0),
                                           AxisLimits(max_velocity=2.0), 10.0), geometry)
    out = saturated.step(5.0, 9.0, DT)
    assert saturated.settled(5.0, 9.0) == pytest.approx((6.0 * 10 / 14, 10.0))
    assert (out.left, out.right) == pytest.approx((6.0 * 10 / 14, 10.0))
    # Overflow is reported, not raised: the caller refuses such a command.
    assert not all(math.isfinite(x) for x in TwistLimiter(
        CommandLimits(max_wheel_velocity=10.0), geometry).settled(1e308, 0.0))


def test_watchdog_expires_by_arrival_and_by_stamp() -> None:
    wd: Watchdog[str] = Watchdog(0.5)
    assert wd.current(0, 0) is None
    wd.accept("go", arrival_ns=1_000_000_000)
    assert wd.current(1_400_000_000, 0) == "go"
    assert wd.current(1_600_000_000, 0) is None
    assert wd.current(1_600_000_000, 0) is None  # stays dropped
    # Stamped: expires 0.5 s after its stamp in ROS time even if it arrived late.
    wd.accept("go", arrival_ns=2_000_000_000, stamp_ns=10_000_000_000)
    assert wd.current(2_100_000_000, 10_400_000_000) == "go"
    assert wd.current(2_200_000_000, 10_600_000_000) is None
    assert wd.is_stale(10_000_000_000, 10_600_000_000)
    assert not wd.is_stale(10_000_000_000, 10_400_000_000)


def test_watchdog_zero_timeout_holds_forever() -> None:
    wd: Watchdog[str] = Watchdog(0.0)
    wd.accept("go", arrival_ns=0, stamp_ns=0)
    assert wd.current(10**15, 10**15) == "go"
    assert not wd.is_stale(0, 10**15)


# ------------------------------------------- diff_drive_controller's deprecated names


def test_ddc_switches_off_clear_those_limits_whatever_the_values() -> None:
    lim = ddc_axis_limits({
        "has_velocity_limits": False, "max_velocity": 1.0, "min_velocity": -1.0,
        "has_acceleration_limits": False, "max_acceleration": 1.0, "max_deceleration": -2.0,
        "has_jerk_limits": False, "max_jerk": 0.0, "min_jerk": 0.0,  # ddc's example file
    })
    assert all(math.isnan(getattr(lim, f)) for f in lim.__dataclass_fields__)


def test_ddc_switches_on_keep_the_values_and_a_zero_jerk_is_refused() -> None:
    lim = ddc_axis_limits({"has_velocity_limits": True, "max_velocity": 1.0,
                           "has_acceleration_limits": True, "max_acceleration": 0.5})
    assert lim.velocity_bounds == (-1.0, 1.0) and lim.forward_bounds[1] == 0.5
    with pytest.raises(LimitError) as err:
        ddc_axis_limits({"has_jerk_limits": True, "max_jerk": 0.0})
    assert err.value.field == "max_jerk" and "0 would forbid" in err.value.reason


def test_ddc_min_acceleration_is_max_acceleration_reverse_when_that_is_unset() -> None:
    assert ddc_axis_limits({"min_acceleration": -0.3}).max_acceleration_reverse == -0.3
    both = ddc_axis_limits({"min_acceleration": -0.3, "max_acceleration_reverse": -0.7})
    assert both.max_acceleration_reverse == -0.7
    assert math.isnan(ddc_axis_limits({}).max_acceleration_reverse)
