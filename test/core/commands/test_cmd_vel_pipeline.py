"""Fuzzing the pure cmd_vel pipeline: nonsense never gets out, and never poisons it.

hypothesis (derandomized, so every run sees the same cases) draws a robot and a
configuration of every shape the node accepts -- several wheels per side, each
output format, control point on/off, velocity/acceleration/jerk limits set or not,
wheel saturation -- then arbitrary Twists (huge, inf, NaN, tiny, denormal) and
arbitrary tick spacings. Every tick must be finite and within the plausibility
bound; afterwards an ordinary command within the limits must be followed exactly:
the closed-form inverse kinematics (v -+ w b/2) / r per joint sign, in the output
unit, once the limiter has settled.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import Any

import pytest
from fuzzing import examples
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from diffdrive_odom.core.commands.cmd_vel_pipeline import (
    DROP_REASONS,
    IMPLAUSIBLE,
    TICKS_PER_SECOND,
    WHEEL_COMMAND_FORMATS,
    CommandPipeline,
)
from diffdrive_odom.settings.cmd_vel import DEFAULT_PLAUSIBLE_WHEEL_VELOCITY, cmd_vel_settings
from diffdrive_odom.settings.errors import ParameterError

FUZZ = settings(max_examples=examples(2000), derandomize=True, deadline=None, database=None,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
NAN = math.nan
SETTLE_S = 12.0  # > the slowest convergence the drawn limits allow (see robots())


@dataclass(frozen=True)
class Robot:
    """The parameters and what the test needs to know about them."""

    params: dict[str, Any]
    r: float
    b: float
    signs: tuple[int, int]
    per_side: int
    k: float  # output units per rad/s
    plausible: float  # [rad/s]
    v_cap: float  # a clean command's |v| and |w| stay below these
    w_cap: float
    wheel_cap: float  # [rad/s]
    offset: float
    rate: float


@functools.cache
def _nan_or(low: float, high: float) -> st.SearchStrategy[float]:
    # Built once per bounds: a new one_of per draw is validated anew each time (a third of
    # the draw's cost), and the same strategy draws the same values.
    return st.one_of(st.just(NAN), st.floats(low, high))


def _maybe(draw: Any, low: float, high: float, scale: float = 1.0) -> float:
    """NaN (no limit) or a value in [low, high] * scale."""
    value: float = draw(_nan_or(low, high))
    return value * scale


@st.composite
def robots(draw: Any) -> Robot:
    """A valid configuration; limits scale with the fastest plausible speed.

    Accelerations of at least 2 speeds/s and jerks of at least 20 speeds/s^2 bound
    the time from any plausible state to a new target by a few seconds (SETTLE_S);
    the property checked does not depend on that scale.
    """
    r = draw(st.floats(0.02, 0.3))
    b = draw(st.floats(0.1, 1.0))
    signs = (draw(st.sampled_from((1, -1))), draw(st.sampled_from((1, -1))))
    per_side = draw(st.integers(1, 3))
    fmt = draw(st.sampled_from(WHEEL_COMMAND_FORMATS))
    tpr = draw(st.sampled_from((1.0, 90.0, 4096.0, 2.0**20)))
    plausible = draw(st.sampled_from((DEFAULT_PLAUSIBLE_WHEEL_VELOCITY, 50.0)))
    speed = plausible * r  # [m/s] the fastest plausible body speed
    turn = 2.0 * speed / b  # [rad/s]
    params: dict[str, Any] = {
        "wheel_radius": r, "wheel_separation": b,
        "left_wheel_sign": signs[0], "right_wheel_sign": signs[1],
        "left_wheel_names": [f"l{i}" for i in range(per_side)],
        "right_wheel_names": [f"r{i}" for i in range(per_side)],
        "ticks_per_revolution": tpr, "wheel_command_format": fmt,
        "max_plausible_wheel_velocity": plausible,
        "cmd_vel_timeout": draw(st.sampled_from((0.0, 0.1, 0.5))),
        "wheel_command_rate": draw(st.floats(5.0, 200.0)),
        "control_point_offset": draw(st.one_of(st.just(0.0), st.floats(0.05, 1.0),
                                               st.floats(-1.0, -0.05))),
        "max_wheel_velocity": _maybe(draw, 0.01, 1.0, plausible),
    }
    caps = []
    for axis, scale in (("linear.x", speed), ("angular.z", turn)):
        p = {
            "max_velocity": _maybe(draw, 0.01, 1.0, scale),
            "min_velocity": _maybe(draw, -1.0, -0.01, scale),
            "max_acceleration": _maybe(draw, 2.0, 50.0, scale),
            "max_deceleration": _maybe(draw, -50.0, -2.0, scale),
            "max_jerk": _maybe(draw, 20.0, 500.0, scale),
        }
        params.update({f"{axis}.{name}": value for name, value in p.items()})
        high = p["max_velocity"] if not math.isnan(p["max_velocity"]) else scale
        low = -p["min_velocity"] if not math.isnan(p["min_velocity"]) else high
        caps.append(min(high, low, scale))
    wheel_cap = params["max_wheel_velocity"]
    return Robot(params, r, b, signs, per_side,
                 tpr / (2 * math.pi) if fmt == TICKS_PER_SECOND else 1.0, plausible,
                 caps[0], caps[1], plausible if math.isnan(wheel_cap) else wheel_cap,
                 params["control_point_offset"], params["wheel_command_rate"])


# Twist parts: anything a float can be, with the famous offenders spelled out.
parts = st.one_of(
    st.floats(-3.0, 3.0),
    st.floats(),
    st.sampled_from((1e308, -1e308, 1e306, 1e300, 5e-324, -5e-324, 2.2e-308, 0.0, -0.0,
                     math.inf, -math.inf, NAN)),
)
twists = st.tuples(st.tuples(parts, parts, parts), st.tuples(parts, parts, parts))
# Time between events [ns]: none, a clock tick, normal periods, stalls.
gaps = st.one_of(st.sampled_from((0, 1, 1000)), st.integers(0, 50_000_000),
                 st.integers(0, 3_000_000_000))
# A command (optionally stamped, maybe stale) or a tick.
events = st.lists(st.tuples(st.sampled_from(("cmd", "tick")), gaps, twists,
                            st.one_of(st.none(), st.integers(0, 2_000_000_000))),
                  max_size=40)


def closed_form(robot: Robot, v: float, w: float) -> list[float]:
    """Each joint's rate from the geometry alone, in the output unit."""
    left = (v - w * robot.b / 2) / (robot.signs[0] * robot.r) * robot.k
    right = (v + w * robot.b / 2) / (robot.signs[1] * robot.r) * robot.k
    return [left] * robot.per_side + [right] * robot.per_side


def assert_sane(pipeline: CommandPipeline, robot: Robot, rates: tuple[float, ...]) -> None:
    bound = robot.plausible * robot.k
    assert len(rates) == 2 * robot.per_side
    assert all(math.isfinite(x) and abs(x) <= bound for x in rates), (rates, bound)
    assert pipeline.bound == pytest.approx(bound)


@pytest.mark.slow  # hypothesis: thousands of runs, 15-25 s
@FUZZ
@given(robots(), events, st.floats(-0.9, 0.9), st.floats(-0.9, 0.9))
def test_nonsense_never_gets_out_and_a_clean_command_is_then_followed(
        robot: Robot, history: list[Any], fv: float, fw: float) -> None:
    pipeline = CommandPipeline(cmd_vel_settings(robot.params))
    now = 10**12
    for kind, gap, (linear, angular), age in history:
        now += gap
        if kind == "cmd":
            refusal = pipeline.accept(linear, angular, now, now,
                                      None if age is None else now - age)
            assert refusal is None or refusal.reason in DROP_REASONS
        else:
            tick = pipeline.tick(now, now)
            assert_sane(pipeline, robot, tick.rates)
            assert math.isfinite(tick.linear) and math.isfinite(tick.angular)
    assert set(pipeline.dropped) == set(DROP_REASONS)

    # A clean command within every limit: velocity bounds, wheel limit, plausibility.
    v, w = fv * robot.v_cap, fw * robot.w_cap
    largest = max(abs(x) for x in closed_form(robot, v, w)) / robot.k
    if largest > 0.9 * robot.wheel_cap:
        v, w = (x * 0.9 * robot.wheel_cap / largest for x in (v, w))
    expected = closed_form(robot, v, w)
    linear = (v, w * robot.offset, 0.0) if robot.offset else (v, 0.0, 0.0)
    angular = (0.0, 0.0, 0.0 if robot.offset else w)
    step = round(2e9 / robot.rate)  # the longest step the pipeline takes
    followed = 0
    for _ in range(math.ceil(SETTLE_S * robot.rate / 2)):
        now += step
        assert pipeline.accept(linear, angular, now, now) is None
        tick = pipeline.tick(now, now)
        assert_sane(pipeline, robot, tick.rates)
        followed = followed + 1 if list(tick.rates) == pytest.approx(
            expected, rel=1e-9, abs=1e-9 * robot.k) else 0
        if followed == 3:
            break
    assert followed == 3, (list(tick.rates), expected)


# --- the cases reproduced on main, one by one ----------------------------------------------

BASE = {"wheel_radius": 0.1, "wheel_separation": 0.4}


@pytest.mark.parametrize(("extra", "linear"), [
    ({"control_point_offset": 0.1}, (0.0, 1e308, 0.0)),  # w = vy / l overflows
    ({"wheel_command_format": "ticks_per_second", "ticks_per_revolution": 4096.0},
     (1e306, 0.0, 0.0)),  # finite in rad/s, inf in counts/s
    ({}, (1e300, 0.0, 0.0)),  # 1e301 rad/s with no limit set
    ({"max_wheel_velocity": 20.0}, (1e308, 0.0, 0.0)),  # inf * (20 / inf) = NaN
])
def test_absurd_commands_are_refused_and_the_previous_one_stays(
        extra: dict[str, Any], linear: tuple[float, float, float]) -> None:
    pipeline = CommandPipeline(cmd_vel_settings({**BASE, **extra}))
    k = pipeline.settings.output_per_rad_s
    assert pipeline.accept((0.5, 0.0, 0.0), (0.0, 0.0, 0.0), 0, 0) is None
    refusal = pipeline.accept(linear, (0.0, 0.0, 0.0), 1000, 1000)
    assert refusal is not None and refusal.reason == IMPLAUSIBLE
    assert "max_plausible_wheel_velocity" in refusal.text
    assert pipeline.dropped == {"non_finite": 0, "stale_stamp": 0, "implausible": 1}
    tick = pipeline.tick(2000, 2000)
    assert tick.refused is None and tick.commanding
    assert list(tick.rates) == pytest.approx([0.5 / 0.1 * k] * 2)  # still the 0.5 m/s


def test_a_velocity_limit_makes_a_huge_command_a_capped_one() -> None:
    # The bound applies after the limits: 1e300 m/s capped to 1 m/s is a plain command.
    pipeline = CommandPipeline(cmd_vel_settings({**BASE, "linear.x.max_velocity": 1.0}))
    assert pipeline.accept((1e300, 0.0, 0.0), (0.0, 0.0, 0.0), 0, 0) is None
    tick = pipeline.tick(0, 0)
    assert list(tick.rates) == pytest.approx([10.0, 10.0])
    assert pipeline.limited["velocity"] == 1


def test_an_output_beyond_the_bound_after_a_runtime_change_sends_zeros() -> None:
    # Accepted at r = 0.1 (500 rad/s); the wheels shrink at runtime to r = 0.001: 50000.
    pipeline = CommandPipeline(cmd_vel_settings(BASE))
    assert pipeline.accept((50.0, 0.0, 0.0), (0.0, 0.0, 0.0), 0, 0) is None
    assert list(pipeline.tick(0, 0).rates) == pytest.approx([500.0, 500.0])
    pipeline.configure(cmd_vel_settings({**BASE, "wheel_radius": 0.001}))
    tick = pipeline.tick(20_000_000, 20_000_000)
    assert tick.refused is not None and tick.refused.reason == IMPLAUSIBLE
    assert tick.rates == (0.0, 0.0) and not tick.commanding
    assert pipeline.dropped["implausible"] == 1
    assert pipeline.tick(40_000_000, 40_000_000).rates == (0.0, 0.0)  # the command is gone


@pytest.mark.parametrize("field", ["linear.x.max_velocity", "angular.z.max_acceleration",
                                   "linear.x.max_jerk", "max_wheel_velocity"])
def test_infinite_limits_are_refused_by_name(field: str) -> None:
    with pytest.raises(ParameterError) as err:
        cmd_vel_settings({**BASE, field: math.inf})
    assert err.value.name == field
