"""The CIR step (Furlan, Marzorati, Sorrenti) against closed forms derived by hand.

Expected values come from circle geometry: constant wheel rates give a constant
curvature, so the exact path is a line or a circle whose radius, period and end
points follow from r, b and the wheel rates alone.
"""

from __future__ import annotations

import math
from decimal import Decimal, localcontext

import numpy as np
import numpy.typing as npt
import pytest

from diffdrive_odom.core.geometry.integration import (
    Pose2D,
    cir_increment,
    compose,
    compose_jacobians,
    integrate_batch,
)
from diffdrive_odom.core.geometry.kinematics import Geometry, body_increment
from diffdrive_odom.core.geometry.se2 import wrap_angle

import oracle

Matrix = npt.NDArray[np.float64]


def drive(
    geometry: Geometry, left: float, right: float, duration: float, steps: int
) -> list[Pose2D]:
    """Constant joint rates (rad/s) for ``duration`` split into ``steps`` equal readings."""
    dt = duration / steps
    ds, dtheta = body_increment(geometry, left * dt, right * dt)
    poses = [Pose2D()]
    for _ in range(steps):
        poses.append(compose(poses[-1], ds, dtheta))
    return poses


def angle_diff(a: float, b: float) -> float:
    """Smallest signed difference of two headings."""
    return abs(wrap_angle(a - b))


# ---------------------------------------------------------------- closed forms


@pytest.mark.parametrize("rate", [3.0, -2.5, 1e-9])
@pytest.mark.parametrize("steps", [1, 7, 1000])
def test_equal_wheel_speeds_drive_straight(rate: float, steps: int) -> None:
    geometry = Geometry(wheel_radius=0.07, wheel_separation=0.31)
    duration = 4.0
    poses = drive(geometry, rate, rate, duration, steps)
    for pose in poses:
        # Equal arcs give dtheta == 0 exactly, so the path never leaves the x axis.
        assert pose.y == 0.0
        assert pose.theta == 0.0
    assert poses[-1].x == pytest.approx(0.07 * rate * duration, rel=1e-12, abs=1e-18)


@pytest.mark.parametrize(
    ("radius", "separation", "left", "right"),
    [
        (0.5, 1.0, 1.0, 5.0),  # ELEC6530 homework section 2.2: right 5x the left
        (0.033, 0.16, 4.0, 2.0),  # clockwise
        (0.1, 0.4, -3.0, -1.0),  # reversing in a circle
        (0.05, 0.3, -1.0, 2.0),  # CIR between the wheels
    ],
)
def test_unequal_speeds_drive_a_circle_back_to_start(
    radius: float, separation: float, left: float, right: float
) -> None:
    geometry = Geometry(radius, separation)
    v = radius * (left + right) / 2.0
    omega = radius * (right - left) / separation
    circle = v / omega  # signed: centre at (0, circle)
    period = 2.0 * math.pi * separation / (radius * abs(right - left))
    steps = 1000
    poses = drive(geometry, left, right, period, steps)
    for pose in poses:
        assert math.hypot(pose.x, pose.y - circle) == pytest.approx(abs(circle), abs=1e-12)
    end = poses[-1]
    assert end.x == pytest.approx(0.0, abs=1e-12)
    assert end.y == pytest.approx(0.0, abs=1e-12)
    assert angle_diff(end.theta, 0.0) < 1e-12
    half = poses[steps // 2]  # opposite point of the circle, heading reversed
    assert half.x == pytest.approx(0.0, abs=1e-12)
    assert half.y == pytest.approx(2.0 * circle, abs=1e-12)
    assert angle_diff(half.theta, math.pi) < 1e-12


@pytest.mark.parametrize("rate", [2.0, -0.7])
def test_spin_in_place(rate: float) -> None:
    geometry = Geometry(wheel_radius=0.05, wheel_separation=0.25)
    duration = 3.0
    poses = drive(geometry, -rate, rate, duration, 300)
    for pose in poses:
        assert pose.x == 0.0  # opposite arcs: ds == 0 exactly, the centre never moves
        assert pose.y == 0.0
        assert -math.pi < pose.theta <= math.pi  # kept wrapped, turn after turn
    expected = 2.0 * 0.05 * rate * duration / 0.25
    assert angle_diff(poses[-1].theta, expected) < 1e-12


@pytest.mark.parametrize("steps", [1, 10, 1000])
def test_quarter_circle_lands_on_1_1(steps: int) -> None:
    # Radius 1 m about (0, 1) with b = 0.5: the left wheel rolls on radius 0.75, the
    # right on 1.25, both through pi/2; joint angles are arcs / r.
    radius, separation = 0.1, 0.5
    geometry = Geometry(radius, separation)
    left_joint = 0.75 * (math.pi / 2) / radius
    right_joint = 1.25 * (math.pi / 2) / radius
    pose = Pose2D()
    for _ in range(steps):
        pose = compose(pose, *body_increment(geometry, left_joint / steps, right_joint / steps))
    assert pose.x == pytest.approx(1.0, abs=1e-12)
    assert pose.y == pytest.approx(1.0, abs=1e-12)
    assert pose.theta == pytest.approx(math.pi / 2, abs=1e-12)


@pytest.mark.parametrize("steps", [1, 100])
def test_unit_robot_left_1_right_2_for_1s(steps: int) -> None:
    # v = (1 + 2) / 2 = 1.5 m/s, omega = (2 - 1) / 1 = 1 rad/s, radius 1.5 m.
    pose = drive(Geometry(1.0, 1.0), 1.0, 2.0, 1.0, steps)[-1]
    x, y, _ = oracle.arc(1.5, 1.0)
    assert pose.x == pytest.approx(x, abs=1e-13)
    assert pose.y == pytest.approx(y, abs=1e-13)
    assert pose.theta == pytest.approx(1.0, abs=1e-13)


def test_each_wheel_arc_is_its_distance_to_the_cir_times_the_angle() -> None:
    # Furlan, Marzorati, Sorrenti section II: s_right = d * angle with d the right
    # wheel's distance to the CIR; s_left = (d + b) * angle (the left wheel is b further from it).
    geometry = Geometry(0.2, 0.6)
    ds, dtheta = body_increment(geometry, 0.3, 0.9)
    s_left, s_right = 0.2 * 0.3, 0.2 * 0.9
    cir_y = ds / dtheta  # CIR at (0, cir_y) in the robot frame; wheels at y = +-b/2
    assert s_right == pytest.approx((cir_y + 0.3) * dtheta, rel=1e-14)
    assert s_left == pytest.approx((cir_y - 0.3) * dtheta, rel=1e-14)


# ------------------------------------------------------ the straight-line limit


def taylor_reference(ds: float, angle: float) -> tuple[float, float]:
    """``R sin a`` and ``R (1 - cos a)`` with ``R = ds / a`` as Taylor series, in 60 digits.

    R sin a = ds (1 - a^2/3! + a^4/5! - ...), R (1 - cos a) = ds (a/2! - a^3/4! + ...),
    summed in Decimal so the reference itself carries no float rounding.
    """
    with localcontext() as ctx:
        ctx.prec = 60
        a, d = Decimal(angle), Decimal(ds)
        powers = [Decimal(1)]  # a^0 .. a^41, built by products (Decimal 0 ** 0 is undefined)
        for _ in range(41):
            powers.append(powers[-1] * a)
        sin_over_a = sum(
            (Decimal((-1) ** k) * powers[2 * k] / math.factorial(2 * k + 1) for k in range(20)),
            Decimal(0))
        one_minus_cos_over_a = sum(
            (Decimal((-1) ** k) * powers[2 * k + 1] / math.factorial(2 * k + 2)
             for k in range(20)),
            Decimal(0))
        return float(d * sin_over_a), float(d * one_minus_cos_over_a)


def within_ulps(got: float, expected: float, ulps: int) -> bool:
    """True when ``got`` is at most ``ulps`` units in the last place from ``expected``."""
    return abs(got - expected) <= ulps * math.ulp(expected)


ANGLES = [1e-3, 1e-4, 1e-5, 1e-6, 1e-7, 1e-8, 1e-9, 1e-10, 1e-11, 1e-12, 1e-300, 0.0]


@pytest.mark.parametrize("angle", ANGLES + [-a for a in ANGLES if a])
@pytest.mark.parametrize("ds", [1.0, 0.37, -2.5])
def test_straight_line_limit_is_within_two_ulp_of_the_series(ds: float, angle: float) -> None:
    dx, dy = cir_increment(ds, angle)
    ref_x, ref_y = taylor_reference(ds, angle)
    assert within_ulps(dx, ref_x, 2), (dx, ref_x)
    if angle == 0.0:
        assert dy == 0.0 and dx == ds
    else:
        assert within_ulps(dy, ref_y, 2), (dy, ref_y)
        assert math.copysign(1.0, dy) == math.copysign(1.0, ds * angle)


def test_taylor_reference_agrees_with_closed_form_at_moderate_angle() -> None:
    # Guards the reference: at a = 0.5 the direct formula has no cancellation.
    ref_x, ref_y = taylor_reference(0.9, 0.5)
    assert ref_x == pytest.approx(0.9 / 0.5 * math.sin(0.5), rel=1e-15)
    assert ref_y == pytest.approx(0.9 / 0.5 * (1 - math.cos(0.5)), rel=1e-15)


def homogeneous(x: float, y: float, theta: float) -> Matrix:
    c, s = math.cos(theta), math.sin(theta)
    return np.array([[c, -s, x], [s, c, y], [0.0, 0.0, 1.0]])


@pytest.mark.parametrize(("s_left", "s_right"), [(0.2, 0.45), (0.5, 0.1), (-0.3, 0.25)])
def test_three_primitive_transforms_compose_to_the_step(s_left: float, s_right: float) -> None:
    # Furlan, Marzorati, Sorrenti sections II-V, REP-103 signs: angle = (s_right -
    # s_left) / b; the CIR is on the wheel axle at distance d = s_right / angle from the
    # right wheel (y = -b/2).
    b = 0.4
    angle = (s_right - s_left) / b
    cir_y = -b / 2 + s_right / angle
    to_cir = homogeneous(0.0, cir_y, 0.0)
    rotate = homogeneous(0.0, 0.0, angle)
    back = homogeneous(0.0, -cir_y, 0.0)
    elementary = to_cir @ rotate @ back
    previous = Pose2D(1.5, -0.7, 2.9)
    world = homogeneous(previous.x, previous.y, previous.theta) @ elementary

    ds, dtheta = body_increment(Geometry(1.0, b), s_left, s_right)
    assert cir_increment(ds, dtheta) == pytest.approx(
        (elementary[0, 2], elementary[1, 2]), abs=1e-14)
    pose = compose(previous, ds, dtheta)
    assert pose.x == pytest.approx(world[0, 2], abs=1e-14)
    assert pose.y == pytest.approx(world[1, 2], abs=1e-14)
    assert angle_diff(pose.theta, math.atan2(world[1, 0], world[0, 0])) < 1e-14


# --------------------------------------------------------------- the Jacobians


def compose_vector(v: Matrix) -> Matrix:
    pose = compose(Pose2D(v[0], v[1], v[2]), v[3], v[4])
    return np.array([pose.x, pose.y, pose.theta])


@pytest.mark.parametrize(
    "point",
    [
        (0.3, -1.2, 0.7, 0.25, 0.4),
        (-2.0, 0.5, -2.2, -0.6, -1.3),
        (1.0, 1.0, 1.0, 0.3, 0.0),  # straight step
        (0.0, 0.0, -0.4, 0.8, 2e-5),  # series branch of sinc'
        (0.0, 0.0, 0.1, 0.0, 0.5),  # pure rotation
    ],
)
def test_compose_jacobians_match_central_differences(
    point: tuple[float, float, float, float, float]
) -> None:
    at = np.array(point, dtype=np.float64)
    h = 1e-6
    numeric = np.zeros((3, 5))
    for j in range(5):
        step = np.zeros(5)
        step[j] = h
        plus, minus = compose_vector(at + step), compose_vector(at - step)
        diff = plus - minus
        diff[2] = wrap_angle(float(diff[2]))
        numeric[:, j] = diff / (2 * h)
    f_pose, f_step = compose_jacobians(Pose2D(*point[:3]), point[3], point[4])
    analytic = np.hstack([np.array(f_pose), np.array(f_step)])
    np.testing.assert_allclose(analytic, numeric, atol=1e-8, rtol=0)


# ------------------------------------------------------------- batch and wraps


def test_integrate_batch_equals_repeated_compose() -> None:
    rng = np.random.default_rng(20240611)
    n = 5000
    ds = rng.uniform(-0.05, 0.1, n)
    dtheta = rng.uniform(-0.3, 0.3, n)
    dtheta[rng.integers(0, n, 300)] = 0.0  # straight steps mixed in
    dtheta[rng.integers(0, n, 100)] = 1e-13
    start = Pose2D(3.0, -4.0, 3.0)
    xs, ys, thetas = integrate_batch(ds, dtheta, start)
    pose = start
    for i in range(n):
        pose = compose(pose, float(ds[i]), float(dtheta[i]))
        assert -math.pi < pose.theta <= math.pi
        assert abs(xs[i] - pose.x) < 1e-9
        assert abs(ys[i] - pose.y) < 1e-9
        assert angle_diff(float(thetas[i]), pose.theta) < 1e-9
    # The batch heading is unwrapped: the plain running sum.
    assert thetas[-1] == pytest.approx(3.0 + math.fsum(dtheta.tolist()), abs=1e-9)


def test_wrap_angle_fixed_points() -> None:
    assert wrap_angle(0.0) == 0.0
    assert wrap_angle(math.pi) == math.pi
    assert wrap_angle(-math.pi) == math.pi  # the half-open interval (-pi, pi]
    assert wrap_angle(-3.0) == -3.0
    assert wrap_angle(3.0) == 3.0
    assert wrap_angle(2 * math.pi) == 0.0
    assert wrap_angle(0.5 + 2 * math.pi) == pytest.approx(0.5, abs=1e-15)
    assert wrap_angle(-0.5 - 4 * math.pi) == pytest.approx(-0.5, abs=1e-15)


def test_wrap_angle_range_and_congruence() -> None:
    rng = np.random.default_rng(7)
    for value in np.concatenate([rng.uniform(-1e3, 1e3, 2000), rng.uniform(-1e7, 1e7, 200)]):
        x = float(value)
        wrapped = wrap_angle(x)
        assert -math.pi < wrapped <= math.pi
        turns = (x - wrapped) / (2 * math.pi)
        assert turns == pytest.approx(round(turns), abs=1e-9 * max(1.0, abs(turns)))
        if -math.pi < x <= math.pi:
            assert wrapped == x


@pytest.mark.parametrize("angle", [2e-4, 1e-4, 0.99e-4, 1e-6, -3e-5, 0.7, -2.5])
def test_the_oracle_arc_is_the_series_and_the_ode(angle: float) -> None:
    """Guards test/oracle.py: its arc is the 60-digit series, and the ODE's solution."""
    x, y, th = oracle.arc(1.3, angle)
    ref_x, ref_y = taylor_reference(1.3, angle)
    assert x == pytest.approx(ref_x, rel=1e-11) and y == pytest.approx(ref_y, rel=1e-11)
    assert th == angle
    # x' = cos th, y' = sin th, th' = angle / s over s in [0, 1.3], by RK4 in 2000 steps.
    n, h = 2000, 1.3 / 2000
    px = py = 0.0
    for i in range(n):
        t0, tm, t1 = (angle / 1.3 * h * k for k in (i, i + 0.5, i + 1))
        px += h / 6 * (math.cos(t0) + 4 * math.cos(tm) + math.cos(t1))
        py += h / 6 * (math.sin(t0) + 4 * math.sin(tm) + math.sin(t1))
    assert math.hypot(px - x, py - y) < 1e-12
