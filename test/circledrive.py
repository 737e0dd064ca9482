"""One circle driven at constant wheel speeds: the stream the stamp and count rules' tests share.

Wheels at 4 and 6 rad/s, r = 0.1 m, b = 0.4 m (0.5 m/s and 0.5 rad/s), read every 20 ms
from ``T0``; the encoders' positions are the true cumulative wheel angles, so the pose
after any stretch is the oracle's arc however the readings are grouped, held or lost.
"""

from __future__ import annotations

from diffdrive_odom.core.geometry.integration import Pose2D
from diffdrive_odom.core.geometry.se2 import wrap_angle

import oracle

NAMES = ["left_wheel_joint", "right_wheel_joint"]
T0 = 1_700_000_000 * 10**9  # the true time the drive starts [ns]
PERIOD = 0.02  # s, 50 Hz
R, B = 0.1, 0.4
SPEEDS = (4.0, 6.0)  # rad/s
V = R * (SPEEDS[0] + SPEEDS[1]) / 2  # 0.5 m/s
W = R * (SPEEDS[1] - SPEEDS[0]) / B  # 0.5 rad/s


def ns(t: float) -> int:
    """The stamp [ns] of true time ``t`` [s] of the drive."""
    return T0 + round(t * 1e9)


def positions(t: float) -> list[float]:
    """The true cumulative wheel angles at true time ``t``."""
    return [SPEEDS[0] * t, SPEEDS[1] * t]


def circle(t: float) -> Pose2D:
    """Where the robot is after ``t`` seconds of the drive (the oracle's arc)."""
    return Pose2D(*oracle.arc(V * t, W * t))


def assert_pose(got: Pose2D, expected: Pose2D, tol: float = 1e-9) -> None:
    """``got`` is ``expected`` within ``tol`` [m, rad]."""
    assert abs(got.x - expected.x) <= tol, (got, expected)
    assert abs(got.y - expected.y) <= tol, (got, expected)
    assert abs(wrap_angle(got.theta - expected.theta)) <= tol, (got, expected)
