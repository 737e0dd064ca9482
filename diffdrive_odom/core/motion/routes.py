"""Scripted routes: timed sequences of body-velocity commands (v, omega).

Pure Python. The demo, the tests, the benchmarks and calibration runs drive the same
paths from here, so "a 4 m UMBmark square" means one thing everywhere. A route is a
list of segments, each a constant twist held for a duration: what a person with a
joystick or a scripted ``cmd_vel`` publisher does, and what a first-order motor still
executes exactly in distance and angle (a lag shifts a segment in time but keeps its
integral), provided a pause lets the wheels settle before the next one.

:func:`pose_after` is where a route ends, segment by segment, with the package's own
CIR step (each constant-twist segment is one exact arc); tests check it against the
textbook arcs of ``test/oracle.py``, never the other way round.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass

from diffdrive_odom.core.errors import ConfigError, require_finite_min
from diffdrive_odom.core.geometry.integration import Pose2D, compose
from diffdrive_odom.core.geometry.se2 import wrap_angle

ORIGIN = Pose2D()


class RouteError(ConfigError):
    """A route setting that cannot be driven (names the setting)."""


@dataclass(frozen=True)
class Segment:
    """Hold the twist (``linear`` m/s, ``angular`` rad/s) for ``duration`` seconds."""

    duration: float
    linear: float = 0.0
    angular: float = 0.0

    def __post_init__(self) -> None:
        require_finite_min(RouteError, "duration", self.duration)
        if not (math.isfinite(self.linear) and math.isfinite(self.angular)):
            raise RouteError("twist", "linear and angular must be finite")


@dataclass(frozen=True)
class Route:
    """A named sequence of segments, starting at rest at the origin."""

    name: str
    segments: tuple[Segment, ...]

    @property
    def duration(self) -> float:
        """Total time [s] including pauses."""
        return math.fsum(s.duration for s in self.segments)

    @property
    def distance(self) -> float:
        """Path length [m] of the axle centre (turns in place add nothing)."""
        return math.fsum(abs(s.linear) * s.duration for s in self.segments)

    @property
    def rotation(self) -> float:
        """Total absolute heading change [rad]."""
        return math.fsum(abs(s.angular) * s.duration for s in self.segments)

    def command_at(self, t: float) -> tuple[float, float]:
        """Return the twist to send at time ``t`` after the start; zero before and after."""
        if t < 0.0:
            return 0.0, 0.0
        start = 0.0
        for seg in self.segments:
            if t < start + seg.duration:
                return seg.linear, seg.angular
            start += seg.duration
        return 0.0, 0.0

    def breakpoints(self) -> list[float]:
        """Return the times at which the command changes (segment starts), plus the end."""
        times = [0.0]
        for seg in self.segments:
            times.append(times[-1] + seg.duration)
        return times

    def then(self, other: Route, name: str | None = None) -> Route:
        """Append ``other`` to this route (it continues from wherever this one ends)."""
        return Route(name or f"{self.name}+{other.name}", self.segments + other.segments)


def arc(pose: Pose2D, linear: float, angular: float, duration: float) -> Pose2D:
    """Closed-form pose after holding (v, omega) for ``duration`` (exact, any curvature).

    A constant twist is a rotation about a fixed CIR, which is exactly the core's
    elementary transform (integration.compose), straight lines included.
    """
    return compose(pose, linear * duration, angular * duration)


def pose_after(
    route: Route,
    t: float | None = None,
    start: Pose2D = ORIGIN,
    twist_map: Callable[[float, float], tuple[float, float]] | None = None,
) -> Pose2D:
    """Pose reached after driving ``route`` for ``t`` seconds (default: all of it).

    ``twist_map`` turns each commanded twist into the twist really executed, e.g. a
    mis-calibrated robot's, so the expected drift of a route has a closed form.
    """
    pose = start
    remaining = route.duration if t is None else t
    for seg in route.segments:
        if remaining <= 0.0:
            break
        dt = min(seg.duration, remaining)
        v, w = (seg.linear, seg.angular) if twist_map is None else twist_map(
            seg.linear, seg.angular)
        pose = arc(pose, v, w, dt)
        remaining -= dt
    return pose


def waypoints(route: Route, start: Pose2D = ORIGIN) -> list[Pose2D]:
    """Return the pose at the start and after each segment (corners of a square...)."""
    poses = [start]
    for seg in route.segments:
        poses.append(arc(poses[-1], seg.linear, seg.angular, seg.duration))
    return poses


def _positive(**values: float) -> None:
    """Refuse (RouteError) any of ``values`` that is not finite and > 0, in order."""
    for field, value in values.items():
        require_finite_min(RouteError, field, value, exclusive=True)


def _pause(pause: float) -> tuple[Segment, ...]:
    return (Segment(pause),) if pause > 0.0 else ()


def from_waypoints(
    points: Iterable[tuple[float, float]],
    linear: float = 0.3,
    angular: float = 0.6,
    pause: float = 0.5,
    start: Pose2D = ORIGIN,
    name: str = "waypoints",
) -> Route:
    """Turn in place towards each point, then drive straight to it (the UMBmark way)."""
    _positive(linear=linear, angular=angular)
    segments: list[Segment] = []
    x, y, theta = start.x, start.y, start.theta
    for px, py in points:
        dx, dy = px - x, py - y
        length = math.hypot(dx, dy)
        if length == 0.0:
            continue
        turn = wrap_angle(math.atan2(dy, dx) - theta)
        if turn != 0.0:
            segments.append(Segment(abs(turn) / angular, 0.0, math.copysign(angular, turn)))
            segments.extend(_pause(pause))
        segments.append(Segment(length / linear, linear, 0.0))
        segments.extend(_pause(pause))
        x, y, theta = px, py, wrap_angle(theta + turn)
    return Route(name, tuple(segments))


def square(
    side: float = 1.0,
    linear: float = 0.3,
    angular: float = 0.6,
    clockwise: bool = False,
    pause: float = 0.5,
    name: str | None = None,
) -> Route:
    """Drive ``side`` metres, turn 90 degrees in place, four times: back at the start."""
    _positive(side=side, linear=linear, angular=angular)
    turn_rate = -angular if clockwise else angular
    segments: list[Segment] = []
    for _ in range(4):
        segments.append(Segment(side / linear, linear, 0.0))
        segments.extend(_pause(pause))
        segments.append(Segment(0.5 * math.pi / angular, 0.0, turn_rate))
        segments.extend(_pause(pause))
    default = f"square_{'cw' if clockwise else 'ccw'}_{side:g}m"
    return Route(name or default, tuple(segments))


def umbmark(
    side: float = 4.0,
    linear: float = 0.3,
    angular: float = 0.6,
    clockwise: bool = True,
    pause: float = 0.5,
) -> Route:
    """One leg of Borenstein's UMBmark: a ``side`` (4 m) square, CW or CCW, turns in place."""
    return square(side, linear, angular, clockwise, pause,
                  name=f"umbmark_{'cw' if clockwise else 'ccw'}_{side:g}m")


def umbmark_both(
    side: float = 4.0, linear: float = 0.3, angular: float = 0.6, pause: float = 0.5
) -> Route:
    """UMBmark as Borenstein runs it: the square clockwise, then counter-clockwise.

    The two directions separate the two dominant systematic errors (unequal wheel
    diameters bend both squares the same way, a wrong wheelbase bends them oppositely).
    """
    cw = umbmark(side, linear, angular, True, pause)
    ccw = umbmark(side, linear, angular, False, pause)
    return cw.then(ccw, name=f"umbmark_{side:g}m")


def circle(
    radius: float = 1.0,
    linear: float = 0.3,
    laps: float = 1.0,
    clockwise: bool = False,
    pause: float = 0.5,
) -> Route:
    """``laps`` turns around a circle of ``radius`` (left of the start for CCW)."""
    _positive(radius=radius, linear=linear, laps=laps)
    angular = (-linear if clockwise else linear) / radius
    duration = 2.0 * math.pi * radius * laps / linear
    return Route(f"circle_{radius:g}m", (Segment(duration, linear, angular), *_pause(pause)))


def figure_eight(radius: float = 1.0, linear: float = 0.3, pause: float = 0.5) -> Route:
    """Drive a lap counter-clockwise, then a lap clockwise: an 8 through the start."""
    left = circle(radius, linear, 1.0, clockwise=False, pause=0.0)
    right = circle(radius, linear, 1.0, clockwise=True, pause=pause)
    return left.then(right, name=f"figure_eight_{radius:g}m")


# name -> builder(size, linear, angular); ``size`` is a side or radius in metres.
BUILDERS: dict[str, Callable[[float, float, float], Route]] = {
    "square": lambda s, v, w: square(s, v, w, clockwise=False),
    "square_cw": lambda s, v, w: square(s, v, w, clockwise=True),
    "circle": lambda s, v, w: circle(s, v),
    "figure_eight": lambda s, v, w: figure_eight(s, v),
    "umbmark_cw": lambda s, v, w: umbmark(s, v, w, clockwise=True),
    "umbmark_ccw": lambda s, v, w: umbmark(s, v, w, clockwise=False),
    "umbmark": lambda s, v, w: umbmark_both(s, v, w),
}

DEFAULT_SIZE: dict[str, float] = {
    "square": 1.0, "square_cw": 1.0, "circle": 1.0, "figure_eight": 1.0,
    "umbmark_cw": 4.0, "umbmark_ccw": 4.0, "umbmark": 4.0,
}


def make_route(
    name: str, size: float | None = None, linear: float = 0.3, angular: float = 0.6
) -> Route:
    """Build a route by name (see :data:`BUILDERS`); ``size`` defaults per route."""
    if name not in BUILDERS:
        raise RouteError("route", f"unknown route {name!r}; one of {sorted(BUILDERS)}")
    return BUILDERS[name](DEFAULT_SIZE[name] if size is None else size, linear, angular)


def names() -> Sequence[str]:
    """Route names accepted by :func:`make_route`."""
    return tuple(BUILDERS)
