"""Stamp faults against the real odometry node over DDS: far in the future, then back.

A driver drives straight at 5 rad/s (0.5 m/s with r = 0.1 m), 50 Hz. One reading is
stamped 100 s ahead; later the driver's clock steps back 0.3 s for the last 0.5 s.
Positions are absolute, so the truth at the last reading is the wheel angle times the
radius, and the twist is 0.5 m/s throughout: no restart at the origin, no lost
motion, no twist spike, no NaN.
"""

from __future__ import annotations

import math
from itertools import pairwise

import pytest

from rosutil import (
    STEP_NS,
    T0_NS,
    OdomRigs,
    R,
    ns_of,
    reading,
    send_first,
    spin_for,
)

pytestmark = [pytest.mark.dds, pytest.mark.process]

RAD_PER_STEP = 0.1  # 5 rad/s at 50 Hz
BACK_NS = 300_000_000


def test_far_future_and_stepped_back_stamps_keep_pose_and_twist(odom_rig: OdomRigs) -> None:
    proc, out, _, ex, pub, sink = odom_rig("-p", "publish_rate:=0.0")
    send_first(ex, pub, sink, reading(T0_NS, [0.0, 0.0]))

    def send(k: int, offset_ns: int = 0) -> None:
        angle = RAD_PER_STEP * k
        pub.publish(reading(T0_NS + k * STEP_NS + offset_ns, [angle, angle]))
        spin_for(ex, 0.005)

    for k in range(1, 51):
        send(k)
    future_ns = T0_NS + 50 * STEP_NS + 100 * 10**9
    pub.publish(reading(future_ns, [5.0, 5.0]))  # a lone reading 100 s ahead
    spin_for(ex, 0.005)
    for k in range(51, 76):
        send(k)
    for k in range(76, 100):  # the clock steps back 0.3 s: stamps 1.22 s .. 1.68 s
        send(k, -BACK_NS)
    last = 100
    send_first(ex, pub, sink, reading(T0_NS + last * STEP_NS - BACK_NS,
                                      [RAD_PER_STEP * last] * 2))
    outlier = out.wait_for("future_stamp", "100.000 s")
    spin_for(ex, 0.2)
    assert proc.poll() is None, out.text()
    odom = sink.odom
    assert odom and all(
        math.isfinite(v) for o in odom for v in (
            o.pose.pose.position.x, o.pose.pose.position.y, o.pose.pose.orientation.z,
            o.pose.pose.orientation.w, o.twist.twist.linear.x, o.twist.twist.angular.z)
    )
    assert not any(ns_of(o.header.stamp) == future_ns for o in odom)
    assert not out.matching("restarted at the origin"), out.text()
    assert len(outlier) == 1, out.text()
    xs = [o.pose.pose.position.x for o in odom]
    assert all(b >= a for a, b in pairwise(xs)), "went backwards"
    final = [o for o in odom if ns_of(o.header.stamp) == T0_NS + last * STEP_NS - BACK_NS][-1]
    assert math.isclose(final.pose.pose.position.x, R * RAD_PER_STEP * last, abs_tol=1e-9)
    assert final.pose.pose.position.y == 0.0
    # Every twist after the first reading is the true 0.5 m/s (main spiked to 8 m/s).
    twists = [o.twist.twist.linear.x for o in odom if ns_of(o.header.stamp) > T0_NS]
    assert twists and all(math.isclose(v, 0.5, rel_tol=1e-9) for v in twists), twists
