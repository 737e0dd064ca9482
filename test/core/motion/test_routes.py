"""Routes: shapes checked against geometry worked out by hand (textbook arc formulas)."""

from __future__ import annotations

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from diffdrive_odom.core.geometry.integration import Pose2D
from diffdrive_odom.core.motion import routes
from diffdrive_odom.core.motion.routes import RouteError, Segment

import oracle


@given(
    st.floats(-1.0, 1.0), st.floats(-3.0, 3.0).filter(lambda w: abs(w) > 1e-3),
    st.floats(0.0, 5.0), st.floats(-math.pi, math.pi),
)
def test_arc_equals_the_textbook_integral(v: float, w: float, t: float, th: float) -> None:
    p = routes.arc(Pose2D(0.3, -0.2, th), v, w, t)
    x, y, theta = oracle.arc(v * t, w * t, (0.3, -0.2, th))
    assert p.x == pytest.approx(x, abs=1e-9)
    assert p.y == pytest.approx(y, abs=1e-9)
    assert math.remainder(p.theta - theta, 2 * math.pi) == pytest.approx(0.0, abs=1e-9)


def test_straight_arc_is_exact() -> None:
    p = routes.arc(Pose2D(1.0, 2.0, math.pi / 2), 0.5, 0.0, 4.0)
    assert (p.x, p.y, p.theta) == pytest.approx((1.0, 4.0, math.pi / 2), abs=1e-15)


@pytest.mark.parametrize("clockwise", [False, True])
def test_square_visits_its_corners_and_returns(clockwise: bool) -> None:
    side = 2.0
    route = routes.square(side, 0.4, 0.8, clockwise=clockwise)
    sign = -1.0 if clockwise else 1.0
    corners = [(side, 0.0), (side, sign * side), (0.0, sign * side), (0.0, 0.0)]
    drive_ends = [p for p, seg in zip(routes.waypoints(route)[1:], route.segments, strict=True)
                  if seg.linear != 0.0]
    assert len(drive_ends) == 4
    for p, (cx, cy) in zip(drive_ends, corners, strict=True):
        assert (p.x, p.y) == pytest.approx((cx, cy), abs=1e-12)
    end = routes.pose_after(route)
    assert (end.x, end.y, end.theta) == pytest.approx((0.0, 0.0, 0.0), abs=1e-12)
    assert route.distance == pytest.approx(4 * side)
    assert route.rotation == pytest.approx(2 * math.pi)
    # 4 drives of side/v, 4 quarter turns at w, 8 pauses of 0.5 s.
    assert route.duration == pytest.approx(4 * side / 0.4 + 2 * math.pi / 0.8 + 8 * 0.5)


def test_umbmark_is_a_4m_square_clockwise_then_counter_clockwise() -> None:
    route = routes.umbmark_both()
    assert route.distance == pytest.approx(32.0)
    assert route.rotation == pytest.approx(4 * math.pi)
    half = len(route.segments) // 2
    turns = [s.angular for s in route.segments if s.angular != 0.0]
    assert len(turns) == 8  # four corners each way
    assert all(w < 0 for w in turns[:4]) and all(w > 0 for w in turns[4:])
    cw_end = routes.waypoints(route)[half]
    assert (cw_end.x, cw_end.y, cw_end.theta) == pytest.approx((0, 0, 0), abs=1e-12)
    pts = routes.waypoints(route)
    assert min(p.y for p in pts) == pytest.approx(-4.0) and max(p.y for p in pts) == (
        pytest.approx(4.0))


def test_circle_and_figure_eight() -> None:
    circle = routes.circle(1.5, 0.3)
    seg = circle.segments[0]
    mid = routes.pose_after(circle, seg.duration / 2)
    assert (mid.x, mid.y) == pytest.approx((0.0, 3.0), abs=1e-12)
    end = routes.pose_after(circle)
    assert (end.x, end.y) == pytest.approx((0.0, 0.0), abs=1e-12)

    eight = routes.figure_eight(1.0, 0.25)
    lap = eight.segments[0].duration
    top = routes.pose_after(eight, lap / 2)
    middle = routes.pose_after(eight, lap)
    bottom = routes.pose_after(eight, 1.5 * lap)
    end = routes.pose_after(eight)
    assert (top.x, top.y) == pytest.approx((0.0, 2.0), abs=1e-12)
    assert (middle.x, middle.y, middle.theta) == pytest.approx((0, 0, 0), abs=1e-12)
    assert (bottom.x, bottom.y) == pytest.approx((0.0, -2.0), abs=1e-12)
    assert (end.x, end.y, end.theta) == pytest.approx((0, 0, 0), abs=1e-12)
    assert eight.distance == pytest.approx(4 * math.pi)


def test_from_waypoints_reaches_every_point() -> None:
    points = [(1.0, 0.0), (1.0, 1.0), (-0.5, 2.0), (0.0, 0.0)]
    route = routes.from_waypoints(points, 0.3, 0.5)
    reached = [(p.x, p.y) for p, s in zip(routes.waypoints(route)[1:], route.segments, strict=True)
               if s.linear != 0.0]
    for (x, y), (px, py) in zip(reached, points, strict=True):
        assert (x, y) == pytest.approx((px, py), abs=1e-12)
    expected = 1.0 + 1.0 + math.hypot(1.5, 1.0) + math.hypot(0.5, 2.0)
    assert route.distance == pytest.approx(expected)


def test_command_at_follows_the_segments() -> None:
    route = routes.Route("r", (Segment(1.0, 0.2, 0.0), Segment(0.5, 0.0, 1.0)))
    assert route.command_at(-0.1) == (0.0, 0.0)
    assert route.command_at(0.0) == (0.2, 0.0)
    assert route.command_at(0.999) == (0.2, 0.0)
    assert route.command_at(1.0) == (0.0, 1.0)
    assert route.command_at(1.5) == (0.0, 0.0)
    assert route.breakpoints() == [0.0, 1.0, 1.5]


def test_twist_map_gives_the_executed_path() -> None:
    # A robot that drives 10 % too far on every straight line.
    route = routes.square(1.0, 0.5, 1.0, pause=0.0)
    end = routes.pose_after(route, twist_map=lambda v, w: (1.1 * v, w))
    assert (end.x, end.y) == pytest.approx((0.0, 0.0), abs=1e-12)  # a bigger square
    corner = routes.pose_after(route, 2.0, twist_map=lambda v, w: (1.1 * v, w))
    assert corner.x == pytest.approx(1.1)


def test_make_route_and_bad_values() -> None:
    for name in routes.names():
        assert routes.make_route(name).distance > 0.0
    assert routes.make_route("umbmark").distance == pytest.approx(32.0)
    with pytest.raises(RouteError):
        routes.make_route("zigzag")
    with pytest.raises(RouteError):
        routes.square(-1.0)
    with pytest.raises(RouteError):
        Segment(math.nan, 0.1, 0.0)
