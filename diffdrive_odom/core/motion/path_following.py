"""Path following with Kumar's control law: the law and the follower's state (pure core).

V. Kumar, "Kinematics of Wheeled Robots", sections 4 and 5: the path
(:mod:`diffdrive_odom.core.motion.paths`) is an implicit function ``gamma(x, y) = 0``; the
controlled point P sits ``l`` ahead of the axle, where the Jacobian J (eq. 22) is
invertible; the path error ``e1 = gamma(P)`` is made to obey ``de1/dt = -k_p e1``
(eq. 23-24) and the speed error ``e2 = v_des - v`` ``e2 + k_i int(e2) = 0`` (eq.
26-27). Both conditions together are the 2x2 system of eq. 28, solved here for the
wheel rates and turned into ``(v, omega)`` by the forward kinematics
(:func:`diffdrive_odom.core.geometry.kinematics.body_increment`). Every primitive's ``gamma``
is a signed distance, so ``e1`` is the cross-track error of P in metres.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from diffdrive_odom.core.geometry.integration import Pose2D
from diffdrive_odom.core.geometry.kinematics import Geometry, body_increment
from diffdrive_odom.core.motion.paths import Arc, Path, PathError, Point, Primitive, require_finite

Matrix2 = npt.NDArray[np.float64]


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
            require_finite(name, getattr(self, name))
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

    Built from the one forward map in :mod:`diffdrive_odom.core.geometry.kinematics` (it is linear).
    """
    v_l, w_l = body_increment(geometry, 1.0, 0.0)
    v_r, w_r = body_increment(geometry, 0.0, 1.0)
    return np.array([[v_l, v_r], [w_l, w_r]], dtype=np.float64)


def point_jacobian(geometry: Geometry, look_ahead: float, theta: float) -> Matrix2:
    """Kumar's J (eq. 21-22): wheel rates -> world velocity of P, ``l`` ahead of the axle.

    P moves with ``(v, l omega)`` in the body frame (as
    :func:`diffdrive_odom.core.geometry.kinematics.point_velocity_to_twist` inverts), rotated by
    theta.
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


# rad off the path's direction beyond which the robot turns in place (_turn_round), and
# the step [m] P is moved to see which way the path's progress goes.
REVERSED = math.radians(120.0)
FORWARD = math.radians(45.0)  # and within which it stops turning round
PROBE = 1e-3


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
    _turning: bool = False  # turning round in place (_turn_round), until facing forward

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
        self._turning = False

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

    def _turn_round(self, pose: Pose2D, p: Point, prim: Primitive) -> float:
        """Turning in place [rad/s] while the robot faces back along the path, else 0.

        Kumar's law holds P on the path at the asked forward speed, either way along it: a
        robot that overshot a corner and came round facing back (the closed loop at 4x real
        time on a stale pose) followed the path backwards for ever. Facing more than
        :data:`REVERSED` off the path's direction (its progress falling as P moves ahead),
        it turns in place, the shorter way, at ``max_angular_velocity``, until it faces
        within :data:`FORWARD` of it (hysteresis: the law, taking over at the edge, would
        turn it back out); then the law takes over.
        """
        def ahead(theta: float) -> float:
            q = (p[0] + PROBE * math.cos(theta), p[1] + PROBE * math.sin(theta))
            return (prim.progress(q) - prim.progress(p)) / PROBE

        along = ahead(pose.theta)  # cos of the heading's angle off the path's direction
        limit = math.cos(FORWARD if self._turning else REVERSED)
        self._turning = -1.5 < along < limit  # else facing forward (or a closed path wrapped)
        if not self._turning:
            return 0.0
        side = 1.0 if ahead(pose.theta + 0.1) > ahead(pose.theta - 0.1) else -1.0
        return side * self.gains.max_angular_velocity

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
        turn = self._turn_round(pose, p, prim)
        if turn:
            return Command(0.0, turn, e1, progress, e2, False, False, True)
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
