"""Paths as Kumar's law follows them: lines, circles and filleted polylines (pure core).

A path is a chain of primitives, each an implicit function ``gamma(x, y) = 0``
(V. Kumar, "Kinematics of Wheeled Robots", section 5) whose ``gamma`` is a signed
distance (positive left of the direction of travel), so ``|grad gamma| = 1`` and the
law's path error is the cross-track error in metres. A polyline is a chain of lines
and circular fillets at its corners, so the gradient ``Gamma`` is continuous where
one primitive hands over to the next (a sharp corner would turn ``Gamma`` by the
corner's angle in one step, right into the singular configuration of the law's
eq. 28: heading along ``Gamma``; see :mod:`diffdrive_odom.core.motion.path_following`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Protocol

from diffdrive_odom.core.errors import ConfigError
from diffdrive_odom.core.geometry.integration import Pose2D
from diffdrive_odom.core.geometry.se2 import wrap_angle
from diffdrive_odom.core.motion.routes import ORIGIN, Route, waypoints

Point = tuple[float, float]


class PathError(ConfigError):
    """A path or gain setting the law cannot follow (names the setting)."""


def require_finite(field_name: str, *values: float) -> None:
    """Raise PathError naming ``field_name`` unless every value is a finite number."""
    if not all(isinstance(v, (int, float)) and math.isfinite(v) for v in values):
        raise PathError(field_name, f"must be finite numbers, got {values!r}")


# --------------------------------------------------------------------- primitives


class Primitive(Protocol):
    """One piece of a path: an implicit function, its gradient and arc length."""

    @property
    def length(self) -> float:
        """Arc length [m] (inf for a closed primitive followed forever)."""

    def gamma(self, p: Point) -> float:
        """Signed distance [m] of ``p``: > 0 left of the direction of travel."""

    def gradient(self, p: Point) -> Point:
        """``Gamma = (d gamma/dx, d gamma/dy)`` at ``p`` (a unit vector)."""

    def progress(self, p: Point) -> float:
        """Arc length [m] from the start to the projection of ``p`` (may be < 0 or > length)."""

    def project(self, p: Point) -> Point:
        """Closest point of the primitive's whole curve (line or circle) to ``p``."""


@dataclass(frozen=True)
class Line:
    """The straight line through ``start`` and ``end``, travelled from start to end."""

    start: Point
    end: Point

    def __post_init__(self) -> None:
        require_finite("line", *self.start, *self.end)
        if self.start == self.end:
            raise PathError("line", f"start and end are the same point {self.start}")

    @property
    def length(self) -> float:
        """Distance start -> end [m]."""
        return math.dist(self.start, self.end)

    @property
    def tangent(self) -> Point:
        """Unit direction of travel."""
        n = self.length
        return ((self.end[0] - self.start[0]) / n, (self.end[1] - self.start[1]) / n)

    def gamma(self, p: Point) -> float:
        """``n . (p - start)`` with ``n`` the left normal."""
        tx, ty = self.tangent
        return tx * (p[1] - self.start[1]) - ty * (p[0] - self.start[0])

    def gradient(self, p: Point) -> Point:
        """The left normal (constant)."""
        tx, ty = self.tangent
        return (-ty, tx)

    def progress(self, p: Point) -> float:
        """``t . (p - start)``."""
        tx, ty = self.tangent
        return tx * (p[0] - self.start[0]) + ty * (p[1] - self.start[1])

    def project(self, p: Point) -> Point:
        """Foot of the perpendicular from ``p``."""
        s = self.progress(p)
        tx, ty = self.tangent
        return (self.start[0] + s * tx, self.start[1] + s * ty)


@dataclass(frozen=True)
class Arc:
    """A circle about ``center`` of ``radius``, from angle ``start_angle`` through ``sweep``.

    ``sweep`` > 0 travels counter-clockwise, < 0 clockwise; ``sweep = inf`` (or -inf)
    is the whole circle followed forever.
    """

    center: Point
    radius: float
    start_angle: float
    sweep: float

    def __post_init__(self) -> None:
        require_finite("circle_center", *self.center)
        require_finite("circle_radius", self.radius)
        if self.radius <= 0.0:
            raise PathError("circle_radius", f"must be > 0, got {self.radius!r}")
        if self.sweep == 0.0 or math.isnan(self.sweep):
            raise PathError("sweep", f"must be non-zero, got {self.sweep!r}")

    @property
    def direction(self) -> float:
        """+1 counter-clockwise, -1 clockwise."""
        return math.copysign(1.0, self.sweep)

    @property
    def length(self) -> float:
        """``radius * |sweep|`` [m]."""
        return self.radius * abs(self.sweep)

    def _offset(self, p: Point) -> tuple[float, float, float]:
        dx, dy = p[0] - self.center[0], p[1] - self.center[1]
        return dx, dy, math.hypot(dx, dy)

    def gamma(self, p: Point) -> float:
        """``direction * (radius - |p - center|)``: inside is left of a CCW circle."""
        return self.direction * (self.radius - self._offset(p)[2])

    def gradient(self, p: Point) -> Point:
        """``-direction * (p - center) / |p - center|`` (any unit vector at the centre)."""
        dx, dy, r = self._offset(p)
        if r == 0.0:
            dx, dy, r = math.cos(self.start_angle), math.sin(self.start_angle), 1.0
        return (-self.direction * dx / r, -self.direction * dy / r)

    def progress(self, p: Point) -> float:
        """``radius`` times the angle travelled from the start (in (-pi, 2 pi - pi] around it)."""
        dx, dy, _ = self._offset(p)
        turned = self.direction * wrap_angle(math.atan2(dy, dx) - self.start_angle)
        if math.isinf(self.sweep):
            return self.radius * (turned % (2.0 * math.pi))
        # Angles up to half the remaining circle past the end count as "past the end".
        slack = 0.5 * (2.0 * math.pi - abs(self.sweep))
        if turned < -slack:
            turned += 2.0 * math.pi
        return self.radius * turned

    def project(self, p: Point) -> Point:
        """Closest point of the circle (the start point when ``p`` is the centre)."""
        dx, dy, r = self._offset(p)
        if r == 0.0:
            dx, dy, r = math.cos(self.start_angle), math.sin(self.start_angle), 1.0
        return (self.center[0] + self.radius * dx / r, self.center[1] + self.radius * dy / r)


def circle(center: Point, radius: float, start: Point | None = None,
           clockwise: bool = False) -> Arc:
    """The whole circle, followed forever, starting nearest ``start`` (default angle 0)."""
    angle = 0.0 if start is None else math.atan2(start[1] - center[1], start[0] - center[0])
    return Arc(center, radius, angle, -math.inf if clockwise else math.inf)


# ------------------------------------------------------------------------- paths


@dataclass(frozen=True)
class Path:
    """Primitives travelled one after the other; ``closed`` ones are followed forever."""

    primitives: tuple[Primitive, ...]

    def __post_init__(self) -> None:
        if not self.primitives:
            raise PathError("path", "has no primitive")

    @property
    def length(self) -> float:
        """Total arc length [m] (inf when the path never ends)."""
        return math.fsum(p.length for p in self.primitives)

    @property
    def closed(self) -> bool:
        """True when the path never ends (a whole circle)."""
        return math.isinf(self.length)

    def starts(self) -> list[float]:
        """Arc length at which each primitive starts."""
        out, s = [], 0.0
        for p in self.primitives:
            out.append(s)
            s += p.length
        return out


def line(start: Point, end: Point) -> Path:
    """A straight segment."""
    return Path((Line(start, end),))


def polyline(points: Sequence[Point], corner_radius: float) -> Path:
    """Lines through ``points`` with a circular fillet of ``corner_radius`` at each corner.

    The fillet is tangent to both lines, so gamma's gradient turns continuously; it
    shrinks where the lines are too short to hold it. Repeated points are dropped.
    """
    require_finite("corner_radius", corner_radius)
    if corner_radius <= 0.0:
        raise PathError("corner_radius", f"must be > 0 (sharp corners make eq. 28 singular "
                                         f"at the switch), got {corner_radius!r}")
    pts: list[Point] = []
    for p in points:
        require_finite("points", *p)
        if not pts or (float(p[0]), float(p[1])) != pts[-1]:
            pts.append((float(p[0]), float(p[1])))
    if len(pts) < 2:
        raise PathError("points", f"needs at least 2 distinct points, got {len(pts)}")
    # Tangent length cut from each side of corner i, and the fillet it carries.
    cuts = [0.0] * len(pts)
    fillets: list[Arc | None] = [None] * len(pts)
    for i in range(1, len(pts) - 1):
        a, b, c = pts[i - 1], pts[i], pts[i + 1]
        turn = wrap_angle(math.atan2(c[1] - b[1], c[0] - b[0])
                          - math.atan2(b[1] - a[1], b[0] - a[0]))
        if abs(turn) < 1e-9:
            continue
        if abs(abs(turn) - math.pi) < 1e-9:
            raise PathError("points", f"the path turns back on itself at {b}")
        half = math.tan(0.5 * abs(turn))
        room = 0.5 * min(math.dist(a, b), math.dist(b, c))
        radius = min(corner_radius, room / half)
        cuts[i] = radius * half
        # Centre: on the inner side, radius away from both lines.
        ux, uy = (b[0] - a[0]) / math.dist(a, b), (b[1] - a[1]) / math.dist(a, b)
        side = math.copysign(1.0, turn)
        tx, ty = b[0] - cuts[i] * ux, b[1] - cuts[i] * uy
        center = (tx - side * radius * uy, ty + side * radius * ux)
        start_angle = math.atan2(ty - center[1], tx - center[0])
        fillets[i] = Arc(center, radius, start_angle, turn)
    prims: list[Primitive] = []
    for i in range(len(pts) - 1):
        a, b = pts[i], pts[i + 1]
        d = math.dist(a, b)
        ux, uy = (b[0] - a[0]) / d, (b[1] - a[1]) / d
        s0, s1 = cuts[i], d - cuts[i + 1]
        if s1 - s0 > 1e-12:
            prims.append(Line((a[0] + s0 * ux, a[1] + s0 * uy), (a[0] + s1 * ux, a[1] + s1 * uy)))
        fillet = fillets[i + 1]
        if fillet is not None:
            prims.append(fillet)
    return Path(tuple(prims))


def route_points(route: Route, start: Pose2D = ORIGIN) -> list[Point]:
    """The corners of a scripted route (:mod:`diffdrive_odom.core.motion.routes`: squares, UMBmark).

    Turns in place and pauses add no corner, so consecutive equal points are merged.
    """
    pts: list[Point] = []
    for pose in waypoints(route, start):
        p = (round(pose.x, 9), round(pose.y, 9))
        if not pts or p != pts[-1]:
            pts.append(p)
    return pts

