"""A driver's clock against the real odometry_node process over DDS: a clock never
synced (1000 s + t), one second of far-future stamps, arrays longer than the names.

The driver drives straight, both wheels 0.1 rad per reading (r = 0.1 m), so the pose
at reading k is x = 0.01 k whatever the stamps say.
"""

from __future__ import annotations

import math
import time

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
    spin_until,
)

pytestmark = [pytest.mark.dds, pytest.mark.process]

RAD_PER_STEP = 0.1
DRIVER_T0_NS = 1000 * 10**9  # the driver's clock: 1000 s since its boot


def angles(k: int) -> list[float]:
    return [RAD_PER_STEP * k] * 2


@pytest.mark.parametrize("stamp_source", ["header", "receive_time"])
def test_a_driver_on_its_own_clock_is_named_once_or_stamped_on_receipt(
        stamp_source: str, odom_rig: OdomRigs,
) -> None:
    """header: /odom carries the driver's 1000 s stamps and the node says so once, with
    the offset and both fixes; receive_time: /odom is stamped on the node's clock."""
    proc, out, _, ex, pub, sink = odom_rig("-p", f"stamp_source:={stamp_source}")
    before_ns = time.time_ns()
    pub.publish(reading(DRIVER_T0_NS, angles(0)))
    assert spin_until(ex, lambda: bool(sink.odom), 10.0), out.text()
    for k in range(1, 51):
        pub.publish(reading(DRIVER_T0_NS + k * STEP_NS, angles(k)))
        spin_for(ex, 0.005)
    def arrived() -> bool:
        return math.isclose(sink.odom[-1].pose.pose.position.x, R * RAD_PER_STEP * 50,
                            abs_tol=1e-9)

    if stamp_source == "receive_time":
        # Received 5 ms apart, most readings fall between two publications of the
        # 50 Hz gate, the last one too (CI once): the wheels then stand, and a
        # standing reading comes every 50 ms until the end pose is published.
        deadline = time.monotonic() + 10.0
        k = 51
        while not arrived() and time.monotonic() < deadline:
            pub.publish(reading(DRIVER_T0_NS + k * STEP_NS, angles(50)))
            spin_for(ex, 0.05)
            k += 1
    assert spin_until(ex, arrived, 10.0), out.text()
    after_ns = time.time_ns()
    named = out.wait_for("header stamps are", "behind the time they were received",
                         timeout=2.0 if stamp_source == "header" else 0.5)
    assert proc.poll() is None, out.text()
    stamps = [ns_of(o.header.stamp) for o in sink.odom]
    if stamp_source == "header":
        assert len(named) == 1, out.text()
        assert "WARN" in named[0] and "stamp_source: receive_time" in named[0]
        assert "sync the driver's clock" in named[0].lower()
        offset = float(named[0].split("header stamps are ")[1].split(" s ")[0])
        assert (before_ns - DRIVER_T0_NS) * 1e-9 - 5.0 < offset < (after_ns - DRIVER_T0_NS) * 1e-9
        assert stamps == [DRIVER_T0_NS + k * STEP_NS for k in range(51)]
    else:
        assert named == [], out.text()
        assert all(before_ns <= s <= after_ns for s in stamps), (before_ns, stamps, after_ns)


def test_one_second_of_far_future_stamps_keeps_the_timeline_and_the_pose(
        odom_rig: OdomRigs) -> None:
    """The issue's fault: a 50 Hz driver on a synced clock (stamped when sent), one
    second of it stamped 1000 s ahead. On main the burst was published, taken as the
    timeline, and the return restarted odometry at the origin. Now nothing stamped in
    the future is published, the burst's 50 readings are counted as future_stamp, and
    the pose is the straight line's."""
    burst = range(51, 101)
    last = 150
    proc, out, _, ex, pub, sink = odom_rig()
    send_first(ex, pub, sink, reading(time.time_ns(), angles(0)))
    sent: list[int] = []
    for k in range(1, last + 1):
        spin_for(ex, 0.02)
        sent.append(time.time_ns() + (1000 * 10**9 if k in burst else 0))
        pub.publish(reading(sent[-1], angles(k)))
    assert spin_until(ex, lambda: any(ns_of(o.header.stamp) == sent[-1] for o in sink.odom),
                      10.0), out.text()
    dropped = out.wait_for("future_stamp", "50 readings")
    assert proc.poll() is None, out.text()
    stamps = [ns_of(o.header.stamp) for o in sink.odom]
    assert max(stamps) == sent[-1], "a far-future pose was published"
    assert len(dropped) == 1 and out.matching("clock_jump"), out.text()
    assert not out.matching("restarted at the origin"), out.text()
    final = [o for o in sink.odom if ns_of(o.header.stamp) == sent[-1]][-1]
    assert math.isclose(final.pose.pose.position.x, R * RAD_PER_STEP * last, abs_tol=1e-9)
    assert final.pose.pose.position.y == 0.0


def test_more_positions_than_names_is_refused_with_a_warning(odom_rig: OdomRigs) -> None:
    """3 positions for 2 names between good readings: dropped (bad_array), the pose goes
    on from the good ones. On main the first two values were integrated."""
    proc, out, _, ex, pub, sink = odom_rig()
    send_first(ex, pub, sink, reading(T0_NS, angles(0)))
    pub.publish(reading(T0_NS + STEP_NS, [0.1, 0.5, 0.1]))  # yaw would jump
    spin_for(ex, 0.005)
    end_ns = T0_NS + 2 * STEP_NS
    pub.publish(reading(end_ns, angles(2)))
    assert spin_until(ex, lambda: any(ns_of(o.header.stamp) == end_ns for o in sink.odom),
                      10.0), out.text()
    warned = out.wait_for("bad_array", "3 entries for 2 names")
    assert proc.poll() is None, out.text()
    assert len(warned) == 1 and "WARN" in warned[0], out.text()
    assert [ns_of(o.header.stamp) for o in sink.odom] == [T0_NS, end_ns]
    final = sink.odom[-1].pose.pose
    assert math.isclose(final.position.x, R * RAD_PER_STEP * 2, abs_tol=1e-12)
    assert final.position.y == 0.0 and final.orientation.z == 0.0
