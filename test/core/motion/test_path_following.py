"""The pure path-following core: implicit functions, gradients, projections, eq. 28.

Expected values are closed forms (distances to a line and a circle, the determinant
of Kumar's eq. 28 worked by hand), never the code's own output. Kumar, "Kinematics
of Wheeled Robots", sections 4 and 5.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from diffdrive_odom.core.errors import ConfigError
from diffdrive_odom.core.geometry.integration import Pose2D, compose
from diffdrive_odom.core.geometry.kinematics import Geometry
from diffdrive_odom.core.motion.path_following import Gains, PathFollower, law_matrix
from diffdrive_odom.core.motion.paths import Arc, Line, Path, circle, line, polyline, route_points
from diffdrive_odom.core.motion.routes import square
from diffdrive_odom.settings.errors import ParameterError
from diffdrive_odom.settings.follower import FOLLOWER_PARAMS, follower_settings
from diffdrive_odom.settings.params import defaults

coord = st.floats(-10.0, 10.0)
G = Geometry(0.05, 0.30)


@given(coord, coord, coord, coord, coord, coord)
def test_line_gamma_gradient_and_projection(ax: float, ay: float, bx: float, by: float,
                                            px: float, py: float) -> None:
    assume(math.hypot(bx - ax, by - ay) > 1e-3)
    seg = Line((ax, ay), (bx, by))
    d = math.hypot(bx - ax, by - ay)
    cross = ((bx - ax) * (py - ay) - (by - ay) * (px - ax)) / d  # > 0 left of a -> b
    assert seg.gamma((px, py)) == pytest.approx(cross, abs=1e-9)
    gx, gy = seg.gradient((px, py))
    assert (gx, gy) == pytest.approx((-(by - ay) / d, (bx - ax) / d))
    fx, fy = seg.project((px, py))
    assert math.hypot(px - fx, py - fy) == pytest.approx(abs(cross), abs=1e-9)
    assert seg.gamma((fx, fy)) == pytest.approx(0.0, abs=1e-9)
    along = ((px - ax) * (bx - ax) + (py - ay) * (by - ay)) / d
    assert seg.progress((px, py)) == pytest.approx(along, abs=1e-9)


@given(coord, coord, st.floats(0.1, 5.0), coord, coord, st.booleans())
def test_circle_gamma_gradient_and_projection(cx: float, cy: float, r: float, px: float,
                                              py: float, cw: bool) -> None:
    dist = math.hypot(px - cx, py - cy)
    assume(dist > 1e-3)
    arc = circle((cx, cy), r, clockwise=cw)
    sign = -1.0 if cw else 1.0  # inside is left of a counter-clockwise circle
    assert arc.gamma((px, py)) == pytest.approx(sign * (r - dist), abs=1e-9)
    # Numerical gradient of the closed form.
    h = 1e-6
    num = ((arc.gamma((px + h, py)) - arc.gamma((px - h, py))) / (2 * h),
           (arc.gamma((px, py + h)) - arc.gamma((px, py - h))) / (2 * h))
    assert arc.gradient((px, py)) == pytest.approx(num, abs=1e-5)
    fx, fy = arc.project((px, py))
    assert math.hypot(fx - cx, fy - cy) == pytest.approx(r)
    assert math.hypot(px - fx, py - fy) == pytest.approx(abs(r - dist), abs=1e-9)


def test_arc_progress_is_radius_times_angle() -> None:
    quarter = Arc((0.0, 0.0), 2.0, 0.0, math.pi / 2)
    assert quarter.length == pytest.approx(math.pi)
    assert quarter.progress((0.0, 5.0)) == pytest.approx(math.pi)
    assert quarter.progress((3.0, 3.0)) == pytest.approx(math.pi / 2)
    clockwise = Arc((0.0, 0.0), 1.0, 0.0, -math.pi / 2)
    assert clockwise.progress((0.0, -1.0)) == pytest.approx(math.pi / 2)


def test_square_polyline_has_tangent_fillets_and_the_expected_length() -> None:
    side, rho = 2.0, 0.25
    path = polyline([(0, 0), (side, 0), (side, side), (0, side), (0, 0)], rho)
    # Four sides cut by rho at each inner corner, three quarter circles.
    assert path.length == pytest.approx(4 * side - 6 * rho + 3 * (math.pi / 2) * rho)
    assert not path.closed
    arcs = [p for p in path.primitives if isinstance(p, Arc)]
    assert [a.center for a in arcs] == [pytest.approx((side - rho, rho)),
                                        pytest.approx((side - rho, side - rho)),
                                        pytest.approx((rho, side - rho))]
    # Where one primitive ends the next starts, with the same gradient (G1).
    for a, b in zip(path.primitives, path.primitives[1:], strict=False):
        end = a.end if isinstance(a, Line) else None
        if end is None:
            assert isinstance(a, Arc)
            ang = a.start_angle + a.sweep
            end = (a.center[0] + a.radius * math.cos(ang), a.center[1] + a.radius * math.sin(ang))
        assert a.gamma(end) == pytest.approx(0.0, abs=1e-12)
        assert b.gamma(end) == pytest.approx(0.0, abs=1e-12)
        assert a.gradient(end) == pytest.approx(b.gradient(end), abs=1e-12)


def test_route_points_are_the_square_corners() -> None:
    assert route_points(square(2.0)) == [(0, 0), (2, 0), (2, 2), (0, 2), (0, 0)]


@settings(max_examples=300)
@given(st.floats(-math.pi, math.pi), st.floats(-math.pi, math.pi),
       st.floats(0.01, 1.0) | st.floats(-1.0, -0.01), st.floats(0.01, 0.5),
       st.floats(0.05, 1.0), st.floats(0.5, 1.5), st.floats(0.5, 1.5))
def test_eq_28_is_non_singular_for_l_non_zero(theta: float, normal: float, look: float,
                                              r: float, b: float, ml: float,
                                              mr: float) -> None:
    """det = -l (Gamma . n) r_l r_r / b, n = (-sin theta, cos theta): zero only at l = 0
    or with the robot heading along Gamma (straight across the path)."""
    geometry = Geometry(r, b, ml, mr)
    grad = (math.cos(normal), math.sin(normal))
    along = -grad[0] * math.sin(theta) + grad[1] * math.cos(theta)
    a = law_matrix(geometry, look, theta, grad)
    det = -look * along * (r * ml) * (r * mr) / b
    assert np.linalg.det(a) == pytest.approx(det, rel=1e-9, abs=1e-15)
    assume(abs(along) > 1e-3)
    assert abs(np.linalg.det(a)) > 0.0
    assert np.isfinite(np.linalg.cond(a))


def test_look_ahead_zero_is_refused_naming_the_parameter() -> None:
    with pytest.raises(ConfigError) as err:
        Gains(look_ahead=0.0)
    assert err.value.field == "look_ahead"
    values = {**defaults(FOLLOWER_PARAMS), "wheel_radius": 0.05, "wheel_separation": 0.3,
              "follower.look_ahead": 0.0}
    with pytest.raises(ParameterError) as perr:
        follower_settings(values)
    assert perr.value.name == "follower.look_ahead"


def drive(path: Path, pose: Pose2D, gains: Gains, seconds: float,
          dt: float = 0.005) -> list[tuple[float, float, bool]]:
    """Exact unicycle motion under the law: (t, e1, done) per step."""
    f = PathFollower(path, gains, G)
    out, v = [], 0.0
    for i in range(int(seconds / dt)):
        c = f.step(pose, v, dt)
        v = c.linear
        pose = compose(pose, c.linear * dt, c.angular * dt)
        out.append((i * dt, c.cross_track_error, c.done))
    return out


def test_law_makes_the_path_error_decay_as_exp_minus_k_p_t() -> None:
    k_p = 1.5
    log = drive(line((0.0, 0.0), (50.0, 0.0)), Pose2D(0.0, 0.3, 0.0),
                Gains(k_p=k_p, max_angular_velocity=10.0), 3.0)  # omega never clipped
    for t, e1, _ in log[::50]:
        assert e1 == pytest.approx(0.3 * math.exp(-k_p * t), rel=0.02, abs=1e-4)


def test_open_path_ends_done_with_zero_command() -> None:
    gains = Gains(desired_speed=0.5)
    log = drive(line((0.0, 0.0), (1.0, 0.0)), Pose2D(), gains, 4.0)
    assert log[-1][2]
    f = PathFollower(line((0.0, 0.0), (1.0, 0.0)), gains, G)
    c = f.step(Pose2D(2.0, 0.0, 0.0), 0.5, 0.01)
    assert c.done and c.linear == 0.0 and c.angular == 0.0


@pytest.mark.parametrize("heading", [math.pi, 0.75 * math.pi, -0.75 * math.pi])
def test_a_robot_facing_back_along_the_path_turns_round_then_follows_it(heading: float) -> None:
    """Kumar's law holds P on the path either way along it; a robot more than 120 deg off
    the path's direction (it overshot a corner and came round) turns in place, the
    shorter way, at max_angular_velocity, until it faces within 45 deg; then the law
    takes it forward (in the demo it had followed the square's side backwards for ever)."""
    gains = Gains(desired_speed=0.4, max_angular_velocity=2.0)
    f = PathFollower(line((0.0, 0.0), (5.0, 0.0)), gains, G)
    pose, dt = Pose2D(1.0, 0.0, heading), 0.005
    c = f.step(pose, 0.0, dt)
    assert c.linear == 0.0 and abs(c.angular) == 2.0
    assert math.copysign(1.0, c.angular) == -math.copysign(1.0, heading)  # the shorter way
    turned = 0
    while c.linear == 0.0:
        pose = compose(pose, 0.0, c.angular * dt)
        c = f.step(pose, 0.0, dt)
        turned += 1
    # It stops turning in place once within 45 deg of the path's direction (+x), turning
    # at 2 rad/s all the way (it does not move: P's direction off the path is the heading's).
    assert abs(math.remainder(pose.theta, 2 * math.pi)) <= math.radians(45.0) + 2.0 * dt
    assert turned * dt * 2.0 == pytest.approx(abs(heading) - math.radians(45.0), abs=0.02)
    assert (pose.x, pose.y) == (1.0, 0.0)
    log = drive(line((0.0, 0.0), (5.0, 0.0)), pose, gains, 12.0)
    assert log[-1][2]  # reached the end: followed forwards
