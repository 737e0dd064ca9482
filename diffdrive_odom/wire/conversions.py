"""Conversions between the core's numbers and what ROS messages carry (pure, no rclpy).

Planar yaw and quaternions, header stamps and integer nanoseconds, covariance
diagonals and the 6x6 row-major matrices of nav_msgs/Odometry. The message types are
described by small Protocols, so the same helpers take rclpy's messages and rosbags'
without importing either.
"""

from __future__ import annotations

import math
from typing import Any, Protocol, TypeVar


def yaw_to_quaternion(theta: float) -> tuple[float, float, float, float]:
    """Planar yaw -> quaternion ``(x, y, z, w)``; continuous in theta across +-pi up to sign."""
    half = 0.5 * theta
    return 0.0, 0.0, math.sin(half), math.cos(half)


class QuaternionLike(Protocol):
    """A quaternion's four components: geometry_msgs/Quaternion (rclpy's or rosbags')."""

    x: float
    y: float
    z: float
    w: float


class StampLike(Protocol):
    """A builtin_interfaces/Time: whole seconds and nanoseconds (rclpy's or rosbags')."""

    sec: int
    nanosec: int


def quaternion_to_yaw(q: QuaternionLike) -> float:
    """Yaw of a quaternion, for any roll/pitch."""
    return math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))


NS_PER_S = 1_000_000_000

S = TypeVar("S", bound=StampLike)


def stamp_to_ns(stamp: StampLike) -> int:
    """A builtin_interfaces/Time (rclpy's or rosbags') -> integer nanoseconds, no rounding."""
    return int(stamp.sec) * NS_PER_S + int(stamp.nanosec)


def split_ns(ns: int) -> tuple[int, int]:
    """Integer nanoseconds -> ``(sec, nanosec)`` of a builtin_interfaces/Time.

    Floor division, as :func:`divmod`: ``nanosec`` is always in ``[0, 1e9)`` (-1 ns is
    ``(-1, 999_999_999)``), so :func:`stamp_to_ns` inverts it exactly, however large.
    """
    sec, nanosec = divmod(int(ns), NS_PER_S)
    return sec, nanosec


def ns_to_stamp(ns: int, stamp: S) -> S:
    """Fill a builtin_interfaces/Time (rclpy's or rosbags') from integer nanoseconds; returns it."""
    stamp.sec, stamp.nanosec = split_ns(ns)
    return stamp


def reference_pose(msg: Any) -> tuple[int, float, float, float]:
    """A nav_msgs/Odometry's or geometry_msgs/PoseStamped's stamp [ns], x, y and yaw.

    rclpy's or rosbags' messages alike: the online estimate's reference pose
    (``online_calibration_reference_topic``), read the same in the node and in replay.
    """
    pose = getattr(msg.pose, "pose", msg.pose)  # Odometry: PoseWithCovariance; PoseStamped: Pose
    return (stamp_to_ns(msg.header.stamp), float(pose.position.x), float(pose.position.y),
            quaternion_to_yaw(pose.orientation))
