"""Path following with Kumar's control law (pure core, no rclpy).

V. Kumar, "Kinematics of Wheeled Robots", sections 4 and 5: the path is an implicit
function ``gamma(x, y) = 0``; the controlled point P sits ``l`` ahead of the axle,
where the Jacobian J (eq. 22) is invertible; the path error ``e1 = gamma(P)`` is made
to obey ``de1/dt = -k_p e1`` (eq. 23-24) and the speed error ``e2 = v_des - v``
``e2 + k_i int(e2) = 0`` (eq. 26-27). Both conditions together are the 2x2 system of
eq. 28, solved here for the wheel rates and turned into ``(v, omega)`` by the forward
kinematics (:func:`diffdrive_odom.core.kinematics.body_increment`).

Every path primitive's ``gamma`` is a signed distance (positive left of the direction
of travel), so ``|grad gamma| = 1`` and ``e1`` is the cross-track error of P in metres.
A polyline is a chain of lines and circular fillets at its corners, so the gradient
``Gamma`` is continuous where one primitive hands over to the next (a sharp corner
would turn ``Gamma`` by the corner's angle in one step, right into the singular
configuration of eq. 28: heading along ``Gamma``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np
import numpy.typing as npt

from diffdrive_odom.core.errors import ConfigError
from diffdrive_odom.core.integration import Pose2D
from diffdrive_odom.core.kinematics import Geometry, body_increment
from diffdrive_odom.core.routes import ORIGIN, Route, waypoints
from diffdrive_odom.core.se2 import wrap_angle

Point = tuple[float, float]
Matrix2 = npt.NDArray[np.float64]


class PathError(ConfigError):
    """A path or gain setting the law cannot follow (names the setting)."""


def _finite(field_name: str, *values: float) -> None:
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
        _finite("line", *self.start, *self.end)
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
        _finite("circle_center", *self.center)
        _finite("circle_radius", self.radius)
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
    _finite("corner_radius", corner_radius)
    if corner_radius <= 0.0:
        raise PathError("corner_radius", f"must be > 0 (sharp corners make eq. 28 singular "
                                         f"at the switch), got {corner_radius!r}")
    pts: list[Point] = []
    for p in points:
        _finite("points", *p)
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
    """The corners of a scripted route (:mod:`diffdrive_odom.core.routes`: squares, UMBmark).

    Turns in place and pauses add no corner, so consecutive equal points are merged.
    """
    pts: list[Point] = []
    for pose in waypoints(route, start):
        p = (round(pose.x, 9), round(pose.y, 9))
        if not pts or p != pts[-1]:
            pts.append(p)
    return pts


# ------------------------------------------------------------------------ the law


@dataclass(frozen=True)
class Gains:
    """The law's settings: ``k_p`` [1/s], ``k_i`` [1/s], look-ahead ``l`` [m], speed [m/s].

    ``max_angular_velocity`` bounds omega [rad/s] (the law asks for a lot when the
    robot heads across the path, where eq. 28 is nearly singular); ``min_alignment``
    is the smallest ``|Gamma . n|`` (n = the robot's left axis) the law divides by.
    """

    k_p: float = 1.0
    k_i: float = 1.0
    look_ahead: float = 0.1
    desired_speed: float = 0.2
    max_angular_velocity: float = 2.0
    min_alignment: float = 0.2
    max_speed_correction: float = 0.5

    def __post_init__(self) -> None:
        for name in ("k_p", "k_i", "look_ahead", "desired_speed", "max_angular_velocity",
                     "min_alignment", "max_speed_correction"):
            _finite(name, getattr(self, name))
        if self.look_ahead == 0.0:
            raise PathError("look_ahead", "must be non-zero: at l = 0 the matrix of Kumar's "
                                          "eq. 28 is singular (the axle centre cannot move "
                                          "sideways)")
        if self.look_ahead < 0.0:
            raise PathError("look_ahead", f"must be > 0: a point behind the axle makes the "
                                          f"heading unstable when driving forward, got "
                                          f"{self.look_ahead!r}")
        if self.k_p <= 0.0:
            raise PathError("k_p", f"must be > 0, got {self.k_p!r}")
        if self.k_i < 0.0:
            raise PathError("k_i", f"must be >= 0 (0 = no integral feedback), got {self.k_i!r}")
        if self.desired_speed <= 0.0:
            raise PathError("desired_speed", f"must be > 0, got {self.desired_speed!r}")
        if self.max_angular_velocity <= 0.0:
            raise PathError("max_angular_velocity",
                            f"must be > 0, got {self.max_angular_velocity!r}")
        if not 0.0 < self.min_alignment <= 1.0:
            raise PathError("min_alignment", f"must be in (0, 1], got {self.min_alignment!r}")
        if not 0.0 <= self.max_speed_correction <= 1.0:
            raise PathError("max_speed_correction",
                            f"must be in [0, 1], got {self.max_speed_correction!r}")


def forward_matrix(geometry: Geometry) -> Matrix2:
    """``[[dv/dq_l, dv/dq_r], [domega/dq_l, domega/dq_r]]``: Kumar's H (eq. 18), body frame.

    Built from the one forward map in :mod:`diffdrive_odom.core.kinematics` (it is linear).
    """
    v_l, w_l = body_increment(geometry, 1.0, 0.0)
    v_r, w_r = body_increment(geometry, 0.0, 1.0)
    return np.array([[v_l, v_r], [w_l, w_r]], dtype=np.float64)


def point_jacobian(geometry: Geometry, look_ahead: float, theta: float) -> Matrix2:
    """Kumar's J (eq. 21-22): wheel rates -> world velocity of P, ``l`` ahead of the axle.

    P moves with ``(v, l omega)`` in the body frame (as
    :func:`diffdrive_odom.core.kinematics.point_velocity_to_twist` inverts), rotated by theta.
    """
    c, s = math.cos(theta), math.sin(theta)
    body_to_point = np.array([[c, -look_ahead * s], [s, look_ahead * c]], dtype=np.float64)
    return body_to_point @ forward_matrix(geometry)


def law_matrix(geometry: Geometry, look_ahead: float, theta: float, grad: Point) -> Matrix2:
    """The coefficient matrix of eq. 28: ``[Gamma J; speed row of H]``.

    Its determinant is ``-l (Gamma . n) det H`` with ``n = (-sin theta, cos theta)``:
    non-singular for ``l != 0`` unless the robot heads along ``Gamma`` (across the path).
    """
    row1 = np.array(grad, dtype=np.float64) @ point_jacobian(geometry, look_ahead, theta)
    return np.vstack([row1, forward_matrix(geometry)[0]])


def control_point(pose: Pose2D, look_ahead: float) -> Point:
    """Kumar's eq. 20: ``X_P = (x + l cos theta, y + l sin theta)``."""
    return (pose.x + look_ahead * math.cos(pose.theta),
            pose.y + look_ahead * math.sin(pose.theta))


@dataclass(frozen=True)
class Command:
    """One step of the law: the twist to send and what it was computed from."""

    linear: float
    angular: float
    cross_track_error: float  # e1 = gamma(P) [m], > 0 = P left of the path
    progress: float  # arc length [m] of P's projection along the path
    speed_error: float  # e2 = v_des - v [m/s]
    done: bool
    near_singular: bool  # |Gamma . n| was raised to min_alignment
    limited: bool  # omega was clipped to max_angular_velocity


@dataclass
class PathFollower:
    """State of the law along one path: the current primitive and the integral of e2."""

    path: Path
    gains: Gains
    geometry: Geometry
    index: int = 0
    integral: float = 0.0
    done: bool = False
    laps: int = 0  # whole turns of a closed path, so its progress keeps growing
    _starts: list[float] = field(default_factory=list)
    _last_progress: float = 0.0

    def __post_init__(self) -> None:
        self._starts = self.path.starts()

    def set_path(self, path: Path) -> None:
        """Start following ``path`` from its beginning (the integral is kept: same robot)."""
        self.path = path
        self._starts = path.starts()
        self.index = 0
        self.done = False
        self.laps = 0
        self._last_progress = 0.0

    def _advance(self, p: Point) -> float:
        """Move to the primitive P is on (never back); returns P's progress along the path."""
        prims = self.path.primitives
        while self.index < len(prims) - 1 and prims[self.index].progress(p) >= \
                prims[self.index].length:
            self.index += 1
        prim = prims[self.index]
        total = self._starts[self.index] + prim.progress(p)
        if self.path.closed and isinstance(prim, Arc):
            lap = 2.0 * math.pi * prim.radius
            if total < self._last_progress - 0.5 * lap:
                self.laps += 1
            elif total > self._last_progress + 0.5 * lap and self.laps > 0:
                self.laps -= 1
            self._last_progress = total
            return total + self.laps * lap
        return min(max(total, 0.0), self.path.length)

    def step(self, pose: Pose2D, speed: float, dt: float) -> Command:
        """Return the twist for ``pose``.

        ``speed`` is the measured forward speed, ``dt`` [s] the time since the previous
        step (0 = do not integrate).
        """
        g = self.gains
        p = control_point(pose, g.look_ahead)
        progress = self._advance(p)
        prim = self.path.primitives[self.index]
        e1 = prim.gamma(p)
        e2 = g.desired_speed - speed
        if not self.path.closed and progress >= self.path.length:
            self.done = True
        if self.done:
            return Command(0.0, 0.0, e1, progress, e2, True, False, False)
        # Eq. 27 with the integral bounded (anti-windup): integrate only while the
        # correction is inside its bound, or when the error pulls it back in.
        bound = g.max_speed_correction * g.desired_speed
        candidate = self.integral + e2 * max(dt, 0.0)
        if abs(g.k_i * candidate) <= bound or abs(candidate) < abs(self.integral):
            self.integral = candidate
        grad = prim.gradient(p)
        n = (-math.sin(pose.theta), math.cos(pose.theta))
        along = grad[0] * n[0] + grad[1] * n[1]
        near_singular = abs(along) < g.min_alignment
        if near_singular:
            lift = math.copysign(g.min_alignment, along if along != 0.0 else 1.0) - along
            grad = (grad[0] + lift * n[0], grad[1] + lift * n[1])
        a = law_matrix(self.geometry, g.look_ahead, pose.theta, grad)
        rhs = np.array([-g.k_p * e1, g.desired_speed + g.k_i * self.integral])
        q_dot = np.linalg.solve(a, rhs)
        linear, angular = body_increment(self.geometry, float(q_dot[0]), float(q_dot[1]))
        limited = abs(angular) > g.max_angular_velocity
        if limited:
            angular = math.copysign(g.max_angular_velocity, angular)
        return Command(linear, angular, e1, progress, e2, False, near_singular, limited)
