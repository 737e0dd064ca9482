"""Gyrodometry through a logger's holds and gaps (issue 37): the wheels' interval, every count.

A constant-twist circle (``oracle.arc``): wheels read at 50 Hz, a perfect gyro at 200 Hz,
both stamped and received at the true time, fed as the node feeds them. The logger
holds the wheels' counts for 0.3 s (longer than the driver's repeats the gyro expects,
0.25 s) and releases them 1 ms after its previous row, or writes no wheel row for 3 s
while the IMU goes on. The gyro must compare over the same interval as the wheels (no
slip where nothing slipped), take the gap's turn from its own samples (none refused as
``future_stamp``), and end on the circle.
"""

from __future__ import annotations

import math

import pytest

from diffdrive_odom.core.estimation.pipeline import ReadingPipeline
from diffdrive_odom.core.geometry.se2 import wrap_angle
from diffdrive_odom.settings.odometry import odometry_settings

from oracle import arc

R, B = 0.05, 0.3
V, W = 0.3, 0.4  # m/s, rad/s
NAMES = ["left_wheel_joint", "right_wheel_joint"]
T0 = 1_000_000_000_000
LEFT, RIGHT = (V - 0.5 * W * B) / R, (V + 0.5 * W * B) / R  # rad/s


def ns(t: float) -> int:
    return T0 + round(t * 1e9)


def drive(hold: tuple[float, float] | None, gap: tuple[float, float] | None,
          seconds: float = 8.0) -> ReadingPipeline:
    """The circle through the pipeline (use_imu), the wheels held or missing as given."""
    pipe = ReadingPipeline(odometry_settings(
        {"wheel_radius": R, "wheel_separation": B, "use_imu": True}))
    events: list[tuple[int, str, list[float]]] = []
    for k in range(round(seconds * 200) + 1):
        events.append((ns(k / 200), "i", [W]))
    for k in range(round(seconds * 50) + 1):
        t = k / 50
        if gap and gap[0] < t < gap[1]:
            continue
        counted = t
        if hold and hold[0] < t < hold[1]:
            counted = hold[0]
        events.append((ns(t), "j", [LEFT * counted, RIGHT * counted]))
        if hold and hold[0] < t < hold[1] <= t + 1 / 50:  # released 1 ms after this row
            events.append((ns(t + 0.001), "j", [LEFT * (t + 0.001), RIGHT * (t + 0.001)]))
    for stamp, kind, values in sorted(events, key=lambda e: (e[0], e[1])):
        if kind == "i":
            pipe.feed_imu(stamp, 0.0, 0.0, values[0], receive_ns=stamp)
        else:
            pipe.feed(stamp, NAMES, values, receive_ns=stamp)
    return pipe


@pytest.mark.parametrize(("hold", "gap"), [((3.0, 3.3), None), (None, (3.0, 6.0))],
                         ids=["0.3 s hold", "3 s gap"])
def test_the_gyro_judges_over_the_wheels_interval_and_loses_no_turn(
        hold: tuple[float, float] | None, gap: tuple[float, float] | None) -> None:
    pipe = drive(hold, gap)
    stats = pipe.stats
    assert stats.gyro is not None
    assert dict(stats.gyro.dropped) == {}  # no IMU sample refused, through the gap too
    assert stats.gyro.slips.steps == 0, stats.gyro.slips  # nothing slipped
    assert stats.reanchors == 0 and stats.gap_reanchors == 0
    assert stats.gaps_integrated == (1 if gap else 0)
    x, y, theta = arc(V * 8.0, W * 8.0)
    pose = pipe.estimator.pose
    assert abs(wrap_angle(pose.theta - theta)) <= 1e-6, (pose, theta)
    assert math.hypot(pose.x - x, pose.y - y) <= 1e-6, (pose, x, y)
