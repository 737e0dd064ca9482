"""Differential-drive geometry and wheel <-> body velocity maps.

Pure Python (no rclpy): the odometry node, the cmd_vel node, the simulator, replay
and calibration all share these few lines so that forward and inverse kinematics can
never drift apart.

Conventions (REP-103): x forward, y left, yaw counter-clockwise. A wheel's *joint*
angle is multiplied by its side's ``sign`` to get the angle that rolls the robot
forward when positive; the Caltech ME/CS 133 notes ("Kinematics and Odometry for a
Differential Drive Vehicle") flip the right wheel, Kumar ("Kinematics of Wheeled
Robots") both, real robots either (see ``left_wheel_sign`` / ``right_wheel_sign``).
The papers are listed in doc/references.md.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TypeVar

import numpy as np
import numpy.typing as npt

from diffdrive_odom.core.errors import ConfigError

FloatOrArray = TypeVar("FloatOrArray", float, npt.NDArray[np.float64])


class GeometryError(ConfigError):
    """A geometry value that would make the kinematics meaningless (names the field)."""


def _positive_finite(field: str, value: float) -> None:
    if not isinstance(value, (int, float)) or not math.isfinite(value) or value <= 0.0:
        raise GeometryError(field, f"must be a finite number > 0, got {value!r}")


@dataclass(frozen=True)
class Geometry:
    """Nominal wheel radius and separation with diff_drive_controller's multipliers.

    The multipliers are kept apart from the nominal values (rather than folded in by
    the user) because calibration estimates exactly these three factors.
    """

    wheel_radius: float
    wheel_separation: float
    left_wheel_radius_multiplier: float = 1.0
    right_wheel_radius_multiplier: float = 1.0
    wheel_separation_multiplier: float = 1.0
    left_wheel_sign: int = 1
    right_wheel_sign: int = 1

    def __post_init__(self) -> None:
        _positive_finite("wheel_radius", self.wheel_radius)
        _positive_finite("wheel_separation", self.wheel_separation)
        _positive_finite("left_wheel_radius_multiplier", self.left_wheel_radius_multiplier)
        _positive_finite("right_wheel_radius_multiplier", self.right_wheel_radius_multiplier)
        _positive_finite("wheel_separation_multiplier", self.wheel_separation_multiplier)
        for field in ("left_wheel_sign", "right_wheel_sign"):
            if getattr(self, field) not in (1, -1):
                raise GeometryError(field, f"must be 1 or -1, got {getattr(self, field)!r}")

    @property
    def left_radius(self) -> float:
        """Effective left wheel radius in metres."""
        return self.wheel_radius * self.left_wheel_radius_multiplier

    @property
    def right_radius(self) -> float:
        """Effective right wheel radius in metres."""
        return self.wheel_radius * self.right_wheel_radius_multiplier

    @property
    def separation(self) -> float:
        """Effective distance between the wheels' contact points in metres."""
        return self.wheel_separation * self.wheel_separation_multiplier


def wheel_arcs(
    geometry: Geometry, d_left: FloatOrArray, d_right: FloatOrArray
) -> tuple[FloatOrArray, FloatOrArray]:
    """Joint angle increments (rad) -> arc lengths (m) rolled by each contact point."""
    s_left = d_left * (geometry.left_wheel_sign * geometry.left_radius)
    s_right = d_right * (geometry.right_wheel_sign * geometry.right_radius)
    return s_left, s_right


def body_increment(
    geometry: Geometry, d_left: FloatOrArray, d_right: FloatOrArray
) -> tuple[FloatOrArray, FloatOrArray]:
    """Joint angle increments -> (arc length of the axle centre, heading change).

    Furlan, Marzorati and Sorrenti, section II, with REP-103 signs: the right wheel
    rolling further turns the robot counter-clockwise,
    ``dtheta = (s_right - s_left) / b``. Works equally on rates (rad/s -> m/s, rad/s):
    the forward kinematics of the "Diff Drive kinematics" notes (after Lynch and Park,
    Modern Robotics ch. 13) and of Carroll and Jha.
    """
    return body_from_arcs(geometry, *wheel_arcs(geometry, d_left, d_right))


def body_from_arcs(
    geometry: Geometry, s_left: FloatOrArray, s_right: FloatOrArray
) -> tuple[FloatOrArray, FloatOrArray]:
    """:func:`body_increment` from the wheels' arcs (m), for a caller that has them already."""
    return 0.5 * (s_left + s_right), (s_right - s_left) / geometry.separation


def wheel_rates(
    geometry: Geometry, linear: FloatOrArray, angular: FloatOrArray
) -> tuple[FloatOrArray, FloatOrArray]:
    """Inverse kinematics: body twist -> joint rates.

    As in the "Diff Drive kinematics" notes (eq. 8-9) and Kumar, "Kinematics of Wheeled
    Robots" (eq. 15-16).

    Returns joint rates in rad/s with the per-side signs applied, so they can be sent
    to the joints as they are.
    """
    half_b = 0.5 * geometry.separation
    left = (linear - angular * half_b) / (geometry.left_wheel_sign * geometry.left_radius)
    right = (linear + angular * half_b) / (geometry.right_wheel_sign * geometry.right_radius)
    return left, right


def point_velocity_to_twist(
    offset: float, velocity_x: float, velocity_y: float
) -> tuple[float, float]:
    """Velocity of a point ``offset`` ahead of the axle (body frame) -> (v, omega).

    Kumar, "Kinematics of Wheeled Robots", section 4: the point P = (l, 0) moves with
    (v, l * omega) in the body frame, so its Jacobian J (eq. 22 at theta = 0) is
    invertible for l != 0.
    """
    if not math.isfinite(offset) or offset == 0.0:
        raise GeometryError("control_point_offset", f"must be finite and non-zero, got {offset!r}")
    return velocity_x, velocity_y / offset


def scale_to_wheel_limit(
    left: float, right: float, max_wheel_rate: float
) -> tuple[float, float, float]:
    """Scale both joint rates by one factor so neither exceeds ``max_wheel_rate``.

    One common factor keeps the ratio of the wheels, hence the path's curvature, and
    never changes a sign (clipping each wheel alone does both). Returns the scaled
    rates and the factor applied (1.0 when within the limit; NaN or <= 0 = no limit).
    """
    if not (max_wheel_rate > 0.0) or not math.isfinite(max_wheel_rate):
        return left, right, 1.0
    largest = max(abs(left), abs(right))
    if largest <= max_wheel_rate:
        return left, right, 1.0
    factor = max_wheel_rate / largest
    return left * factor, right * factor, factor
