"""Encoder decoding: joint lookup by name, counts, counter wrap, averaging, velocity input."""

from __future__ import annotations

import math

import pytest

from diffdrive_odom.core.estimation.wheels.encoders import (
    EncoderConfig,
    EncoderConfigError,
    JointLookup,
    WheelReading,
    decode,
    in_counter_range,
    increment,
    side_mean,
    unwrap_difference,
)

LEFT, RIGHT = "left_wheel_joint", "right_wheel_joint"
ONE = EncoderConfig((LEFT,), (RIGHT,))
TWO = EncoderConfig(("fl", "rl"), ("fr", "rr"))


# ---------------------------------------------------------------- configuration


@pytest.mark.parametrize(
    ("kwargs", "field"),
    [
        ({"left_wheel_names": ()}, "left_wheel_names"),
        ({"right_wheel_names": ()}, "right_wheel_names"),
        ({"left_wheel_names": ("",)}, "left_wheel_names"),
        ({"right_wheel_names": ("a", "b")}, "right_wheel_names"),
        ({"right_wheel_names": (LEFT,)}, "right_wheel_names"),
        ({"ticks_per_revolution": -1.0}, "ticks_per_revolution"),
        ({"ticks_per_revolution": math.nan}, "ticks_per_revolution"),
        ({"ticks_per_revolution": math.inf}, "ticks_per_revolution"),
        ({"counter_bits": 16}, "encoder_counter_bits"),  # wrap without ticks
        ({"counter_bits": 65, "ticks_per_revolution": 100.0}, "encoder_counter_bits"),
        ({"counter_bits": -1, "ticks_per_revolution": 100.0}, "encoder_counter_bits"),
    ],
)
def test_bad_encoder_config_names_the_parameter(kwargs: dict[str, object], field: str) -> None:
    args: dict[str, object] = {"left_wheel_names": (LEFT,), "right_wheel_names": (RIGHT,)}
    args.update(kwargs)
    with pytest.raises(EncoderConfigError) as err:
        EncoderConfig(**args)  # type: ignore[arg-type]
    assert err.value.field == field
    assert field in str(err.value)


def test_radians_per_unit() -> None:
    assert ONE.radians_per_unit == 1.0
    tpr = EncoderConfig((LEFT,), (RIGHT,), ticks_per_revolution=2796.8)
    assert tpr.radians_per_unit == pytest.approx(2 * math.pi / 2796.8, rel=1e-15)
    # One revolution of counts is one turn of the wheel.
    assert 2796.8 * tpr.radians_per_unit == pytest.approx(2 * math.pi, rel=1e-15)


# ------------------------------------------------------------------- unwrapping


@pytest.mark.parametrize(
    ("previous", "current", "bits", "expected"),
    [
        (65530.0, 5.0, 16, 11.0),  # unsigned 16-bit, forward over the wrap
        (5.0, 65530.0, 16, -11.0),  # backward over the wrap
        (32767.0, -32768.0, 16, 1.0),  # signed 16-bit
        (-32768.0, 32767.0, 16, -1.0),
        (100.0, 30000.0, 16, 29900.0),  # under half the span: taken as is
        (4294967290.0, 3.0, 32, 9.0),
        (-2147483648.0, 2147483647.0, 32, -1.0),
        (100.0, 70000.0, 0, 69900.0),  # no wrap configured
    ],
)
def test_unwrap_difference(previous: float, current: float, bits: int, expected: float) -> None:
    assert unwrap_difference(current - previous, bits) == expected


# -------------------------------------------------------------- lookup, decode


def test_lookup_by_name_in_any_order_with_extra_joints() -> None:
    lookup = JointLookup(TWO)
    names = ["caster", "rr", "fl", "arm", "fr", "rl"]
    assert lookup.indices(names) == (2, 5, 4, 1)  # fl, rl, fr, rr
    assert lookup.indices(names) == (2, 5, 4, 1)  # cached answer is the same
    assert lookup.indices(["fl", "rl", "fr"]) is None
    assert lookup.indices([]) is None


def test_lookup_stays_right_past_its_cache_size() -> None:
    lookup = JointLookup(ONE)
    for k in range(100):
        extra = [f"extra_{k}_{i}" for i in range(k % 5)]
        names = [*extra, RIGHT, LEFT]
        assert lookup.indices(names) == (len(extra) + 1, len(extra))
        assert lookup.indices([*extra, LEFT]) is None


def test_decode_picks_the_wheels_in_config_order() -> None:
    reading = decode(JointLookup(ONE), 7, ["x", RIGHT, LEFT], [9.0, 2.0, 1.0], [])
    assert reading == WheelReading(7, (1.0, 2.0), False)


def test_decode_uses_velocity_when_position_is_empty() -> None:
    reading = decode(JointLookup(ONE), 7, [RIGHT, LEFT], [], [0.5, -0.25])
    assert reading == WheelReading(7, (-0.25, 0.5), True)


def test_decode_falls_back_to_velocity_when_every_wheel_position_is_nan() -> None:
    # ros2_control's joint_state_broadcaster fills a missing position interface with NaN.
    reading = decode(JointLookup(ONE), 7, [LEFT, RIGHT], [math.nan, math.nan], [0.5, -0.25])
    assert reading == WheelReading(7, (0.5, -0.25), True)


def test_decode_ignores_a_bad_value_on_a_joint_that_is_not_a_wheel() -> None:
    reading = decode(JointLookup(ONE), 7, ["arm", LEFT, RIGHT], [math.nan, 1.0, 2.0], [])
    assert reading == WheelReading(7, (1.0, 2.0), False)


@pytest.mark.parametrize(
    ("names", "position", "velocity"),
    [
        ([LEFT], [1.0], []),  # a wheel missing
        ([LEFT, RIGHT], [1.0], []),  # position shorter than names
        ([LEFT, RIGHT], [], [1.0]),  # velocity shorter than names
        ([LEFT, RIGHT], [], []),  # nothing filled
        ([LEFT, RIGHT], [math.nan, 1.0], []),
        ([LEFT, RIGHT], [1.0, math.inf], []),
        ([LEFT, RIGHT], [], [-math.inf, 0.0]),
        ([LEFT, RIGHT], [math.nan, 1.0], [0.5, 0.5]),  # one NaN: a glitch
        ([LEFT, RIGHT], [math.nan, math.nan], [math.nan, 0.5]),
        ([LEFT, RIGHT], [1.0, 1.0], [0.5]),  # velocity shorter than names
    ],
)
def test_decode_rejects_unusable_arrays_with_a_reason(
    names: list[str], position: list[float], velocity: list[float]
) -> None:
    result = decode(JointLookup(ONE), 7, names, position, velocity)
    assert isinstance(result, str) and result


# -------------------------------------------------------------------- increments


def test_several_wheels_per_side_are_averaged() -> None:
    previous = WheelReading(0, (1.0, 3.0, -2.0, 10.0), False)
    current = WheelReading(500_000_000, (1.5, 3.25, -1.0, 10.5), False)
    inc = increment(TWO, previous, current)
    assert inc.dt == pytest.approx(0.5, abs=1e-15)
    assert inc.d_left == pytest.approx((0.5 + 0.25) / 2, abs=1e-15)
    assert inc.d_right == pytest.approx((1.0 + 0.5) / 2, abs=1e-15)


def test_counts_are_scaled_and_unwrapped() -> None:
    config = EncoderConfig((LEFT,), (RIGHT,), ticks_per_revolution=2796.8, counter_bits=16)
    previous = WheelReading(0, (65000.0, 100.0), False)
    current = WheelReading(10_000_000, (1000.0, 100.0 - 2796.8), False)  # 1536 ticks; -1 rev
    inc = increment(config, previous, current)
    assert inc.d_left == pytest.approx(1536 * 2 * math.pi / 2796.8, rel=1e-14)
    assert inc.d_right == pytest.approx(-2 * math.pi, rel=1e-14)


def test_velocity_is_integrated_by_the_trapezoidal_rule() -> None:
    previous = WheelReading(1_000_000_000, (1.0, 2.0), True)
    current = WheelReading(1_500_000_000, (3.0, -2.0), True)
    inc = increment(ONE, previous, current)
    # Linear speed change over 0.5 s: the area is the mean of the ends times dt.
    assert inc.d_left == pytest.approx(0.5 * (1.0 + 3.0) * 0.5, abs=1e-15)
    assert inc.d_right == pytest.approx(0.0, abs=1e-15)


def test_velocity_in_counts_per_second_is_scaled() -> None:
    config = EncoderConfig((LEFT,), (RIGHT,), ticks_per_revolution=1000.0)
    previous = WheelReading(0, (500.0, 1000.0), True)
    current = WheelReading(2_000_000_000, (500.0, 1000.0), True)
    inc = increment(config, previous, current)
    assert inc.d_left == pytest.approx(2 * math.pi, rel=1e-15)  # 1000 counts = 1 turn
    assert inc.d_right == pytest.approx(4 * math.pi, rel=1e-15)


# ------------------------------------------------------ values that cannot be steps


@pytest.mark.parametrize("values", [[1.7e308, 1.7e308], [math.inf, -math.inf],
                                    [math.nan, 1.0], [math.inf, 1.0]])
def test_a_side_mean_that_is_no_finite_number_is_nan(values: list[float]) -> None:
    assert math.isnan(side_mean(values))


def test_a_side_mean_of_large_finite_values_is_exact() -> None:
    assert side_mean([1e308, -1e308, 3.0]) == 1.0  # fsum: no cancellation error


def test_unwrap_passes_non_finite_differences_through() -> None:
    assert unwrap_difference(math.inf, 16) == math.inf
    assert math.isnan(unwrap_difference(math.nan, 16))


@pytest.mark.parametrize(("value", "bits", "inside"),
                         [(-32768.0, 16, True), (-32768.5, 16, False), (65535.0, 16, True),
                          (65536.0, 16, False), (1.7e308, 64, False), (1.7e308, 0, True),
                          (-(2.0**63), 64, True), (2.0**64, 64, False)])
def test_counter_range_covers_signed_and_unsigned(value: float, bits: int, inside: bool) -> None:
    assert in_counter_range(value, bits) is inside


def test_decode_refuses_a_count_outside_the_counter() -> None:
    lookup = JointLookup(ONE)
    got = decode(lookup, 1, [LEFT, RIGHT], [70000.0, 0.0], [], counter_bits=16)
    assert not isinstance(got, WheelReading) and got.code == "out_of_range"
    assert isinstance(decode(lookup, 1, [LEFT, RIGHT], [70000.0, 0.0], []), WheelReading)


def test_a_wheel_far_off_its_side_shows_in_the_peak() -> None:
    a = WheelReading(0, (0.0, 0.0, 0.0, 0.0), False)
    b = WheelReading(10**8, (-5.0, 5.0, 1.0, 1.0), False)
    inc = increment(TWO, a, b)
    assert (inc.d_left, inc.d_right, inc.peak) == (0.0, 1.0, 5.0)
    huge = WheelReading(10**8, (1.7e308, -1.7e308, 0.0, 0.0), False)
    assert math.isnan(increment(TWO, WheelReading(0, (-1.7e308, 1.7e308, 0.0, 0.0), False),
                                huge).peak)
