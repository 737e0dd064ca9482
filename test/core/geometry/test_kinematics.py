"""Inverse kinematics checked against independent forward kinematics.

FK is the odometry estimator's own (``kinematics.body_increment``) and, for the
control point, Kumar's Jacobian J ("Kinematics of Wheeled Robots", eq. 22) written
out from the text; neither is the code under test. Expected values are the commands
themselves (round trips).
"""

from __future__ import annotations

import math

import numpy as np
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from diffdrive_odom.core.commands.limits import CommandLimits, TwistLimiter
from diffdrive_odom.core.geometry.kinematics import (
    Geometry,
    body_increment,
    point_velocity_to_twist,
    scale_to_wheel_limit,
    wheel_rates,
)

geometries = st.builds(
    Geometry,
    wheel_radius=st.floats(0.01, 0.5),
    wheel_separation=st.floats(0.05, 2.0),
    left_wheel_radius_multiplier=st.floats(0.8, 1.2),
    right_wheel_radius_multiplier=st.floats(0.8, 1.2),
    wheel_separation_multiplier=st.floats(0.8, 1.2),
    left_wheel_sign=st.sampled_from([1, -1]),
    right_wheel_sign=st.sampled_from([1, -1]),
)
speeds = st.floats(-3.0, 3.0)
turn_rates = st.floats(-6.0, 6.0)


def close(a: float, b: float, scale: float = 1.0) -> bool:
    return abs(a - b) <= 1e-9 * max(1.0, scale)


@settings(max_examples=300, deadline=None)
@given(geometry=geometries, v=speeds, w=turn_rates)
def test_forward_of_inverse_is_identity(geometry: Geometry, v: float, w: float) -> None:
    left, right = wheel_rates(geometry, v, w)
    v2, w2 = body_increment(geometry, left, right)
    assert close(v2, v, abs(v) + abs(w))
    assert close(w2, w, abs(v) + abs(w))


@settings(max_examples=100, deadline=None)
@given(geometry=geometries, v=speeds, w=turn_rates)
def test_wheel_signs_make_joint_rates_roll_forward(geometry: Geometry, v: float, w: float) -> None:
    # Straight ahead: each wheel's joint turns in the direction its sign says is forward.
    left, right = wheel_rates(geometry, abs(v) + 0.1, 0.0)
    assert left * geometry.left_wheel_sign > 0
    assert right * geometry.right_wheel_sign > 0


def kumar_jacobian(r: float, d: float, offset: float, theta: float) -> np.ndarray:
    """Kumar, "Kinematics of Wheeled Robots", eq. 22; columns (left, right) in REP-103 order.

    The paper writes theta_dot = -r/d q1 + r/d q2, i.e. its first column is the wheel
    whose faster turning makes the robot turn clockwise: our *left* wheel.
    """
    c, s = math.cos(theta), math.sin(theta)
    k = r * offset / d
    return np.array([
        [r / 2 * c + k * s, r / 2 * c - k * s],
        [r / 2 * s - k * c, r / 2 * s + k * c],
    ])


@settings(max_examples=300, deadline=None)
@given(
    r=st.floats(0.02, 0.3), d=st.floats(0.1, 1.0),
    offset=st.one_of(st.floats(0.05, 1.0), st.floats(-1.0, -0.05)),
    vx=speeds, vy=speeds, theta=st.floats(-math.pi, math.pi),
)
def test_control_point_velocity_recomputed_from_wheels_equals_command(
    r: float, d: float, offset: float, vx: float, vy: float, theta: float
) -> None:
    geometry = Geometry(wheel_radius=r, wheel_separation=d)
    v, w = point_velocity_to_twist(offset, vx, vy)
    left, right = wheel_rates(geometry, v, w)
    # Body frame: P = (l, 0) moves with (v, l w) where (v, w) is the FK of the wheels.
    v2, w2 = body_increment(geometry, left, right)
    scale = abs(vx) + abs(vy) / abs(offset) + 1.0
    assert close(v2, vx, scale)
    assert close(offset * w2, vy, scale)
    # World frame, with Kumar's Jacobian: J q_dot = R(theta) (vx, vy).
    xi = kumar_jacobian(r, d, offset, theta) @ np.array([left, right])
    c, s = math.cos(theta), math.sin(theta)
    expected = np.array([c * vx - s * vy, s * vx + c * vy])
    assert np.allclose(xi, expected, atol=1e-9 * scale)


@settings(max_examples=300, deadline=None)
@given(geometry=geometries, v=speeds, w=turn_rates, limit=st.floats(0.5, 50.0))
def test_saturation_keeps_curvature_direction_and_wheel_limit(
    geometry: Geometry, v: float, w: float, limit: float
) -> None:
    assume(abs(v) > 1e-6 or abs(w) > 1e-6)
    left, right = wheel_rates(geometry, v, w)
    sl, sr, factor = scale_to_wheel_limit(left, right, limit)
    assert max(abs(sl), abs(sr)) <= limit * (1 + 1e-12)
    assert 0.0 < factor <= 1.0
    v2, w2 = body_increment(geometry, sl, sr)
    # Same curvature (v2 : w2 = v : w), same direction of travel and turn.
    assert math.isclose(v2 * w, w2 * v, rel_tol=1e-9, abs_tol=1e-9 * (abs(v) + abs(w)) ** 2)
    tol = 1e-12 * (abs(v) + abs(w)) ** 2  # rounding noise when w or v is ~0
    assert v2 * v >= -tol and w2 * w >= -tol
    if max(abs(left), abs(right)) <= limit:
        assert (sl, sr) == (left, right)


@settings(max_examples=200, deadline=None)
@given(geometry=geometries, speed=st.floats(0.1, 3.0), w=turn_rates, limit=st.floats(0.5, 20.0))
def test_saturation_in_reverse_keeps_reversing_on_the_same_arc(
    geometry: Geometry, speed: float, w: float, limit: float
) -> None:
    # The classic bug: clipping each wheel alone in reverse flips a wheel's sign or
    # changes the turn. Through the whole pipeline (TwistLimiter) it must not.
    tl = TwistLimiter(CommandLimits(max_wheel_velocity=limit), geometry)
    out = tl.step(-speed, w, 0.02)
    assert out.linear < 0.0
    assert max(abs(out.left), abs(out.right)) <= limit * (1 + 1e-12)
    left, right = wheel_rates(geometry, -speed, w)
    assert out.left * left >= 0.0 and out.right * right >= 0.0
    # Same curvature: out.angular / out.linear == w / -speed (cross-multiplied: no
    # division by a tiny w), and the same turn direction.
    assert math.isclose(out.angular * -speed, w * out.linear, rel_tol=1e-9,
                        abs_tol=1e-12 * (speed + abs(w)) ** 2)
    assert out.angular * w >= 0.0
    v2, w2 = body_increment(geometry, out.left, out.right)
    assert close(v2, out.linear, speed) and close(w2, out.angular, abs(w) + speed)
