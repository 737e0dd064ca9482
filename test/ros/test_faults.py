"""Driver faults against the real odometry node over DDS: what the user sees and gets.

The node runs as its own process; its log lines are read from its output as they
come, so a warning that should appear at once is checked at once.
"""

from __future__ import annotations

import math

import pytest

from rosutil import (
    STEP_NS,
    T0_NS,
    OdomRigs,
    R,
    ns_of,
    odometry_node,
    reading,
    send_first,
    spin_for,
    spin_until,
)

pytestmark = [pytest.mark.dds, pytest.mark.process]


def test_driver_restart_after_a_pause_keeps_the_pose(odom_rig: OdomRigs) -> None:
    """Counters 0 -> 20 rad, a 4 s pause, counters from 0 again: no 20 rad backwards."""
    proc, out, _, ex, pub, sink = odom_rig()
    send_first(ex, pub, sink, reading(T0_NS, [0.0, 0.0]))
    for k in range(1, 51):  # 20 rad in 1 s on both wheels: 2 m straight
        pub.publish(reading(T0_NS + k * STEP_NS, [0.4 * k, 0.4 * k]))
        spin_for(ex, 0.005)
    before_ns = T0_NS + 50 * STEP_NS
    assert spin_until(ex, lambda: any(ns_of(o.header.stamp) == before_ns for o in sink.odom))
    restart_ns = before_ns + 4 * 10**9
    for k in range(26):  # the driver comes back counting from 0: 5 rad in 0.5 s
        pub.publish(reading(restart_ns + k * STEP_NS, [0.2 * k, 0.2 * k]))
        spin_for(ex, 0.005)
    last_ns = restart_ns + 25 * STEP_NS
    assert spin_until(ex, lambda: any(ns_of(o.header.stamp) == last_ns for o in sink.odom))
    gap = out.wait_for("max_reading_gap")
    assert proc.poll() is None
    before = [o for o in sink.odom if ns_of(o.header.stamp) == before_ns][-1]
    assert math.isclose(before.pose.pose.position.x, R * 20.0, abs_tol=1e-9)
    final = [o for o in sink.odom if ns_of(o.header.stamp) == last_ns][-1]
    # Where the motion before the pause left it, plus the 5 rad after: 2.5 m.
    assert math.isclose(final.pose.pose.position.x, R * 25.0, abs_tol=1e-9)
    assert final.pose.pose.position.y == 0.0
    assert len(gap) == 1 and "4.000 s" in gap[0], out.text()


def test_wrong_joint_names_are_named_at_once(odom_rig: OdomRigs) -> None:
    proc, out, _, ex, pub, sink = odom_rig()
    wrong = ["wheel_left", "wheel_right"]
    for k in range(40):  # until discovery lets one through; later ones are throttled
        pub.publish(reading(T0_NS + k * STEP_NS, [0.1 * k, 0.1 * k], names=wrong))
        spin_for(ex, 0.05)
        if out.matching("lacks"):
            break
    lines = out.wait_for("lacks", timeout=10.0)
    spin_for(ex, 0.5)
    assert proc.poll() is None
    assert lines, out.text()
    line = lines[0]
    for name in ("left_wheel_joint", "right_wheel_joint", "wheel_left", "wheel_right"):
        assert name in line, line
    assert len(out.matching("lacks")) == 1  # the rest within the period held back
    assert not sink.odom


def test_two_different_bad_inputs_are_both_reported(odom_rig: OdomRigs) -> None:
    """One throttle per reason: a NaN right after a short array still gets its line."""
    _, out, _, ex, pub, sink = odom_rig()
    send_first(ex, pub, sink, reading(T0_NS, [0.0, 0.0]))
    pub.publish(reading(T0_NS + STEP_NS, [1.0]))  # shorter than the names
    spin_for(ex, 0.05)
    pub.publish(reading(T0_NS + 2 * STEP_NS, [math.nan, 1.0]))
    spin_for(ex, 0.05)
    pub.publish(reading(T0_NS + 3 * STEP_NS, [0.1, 0.1]))
    last_ns = T0_NS + 3 * STEP_NS
    assert spin_until(ex, lambda: any(ns_of(o.header.stamp) == last_ns for o in sink.odom))
    short = out.wait_for("position has 1 entries for 2 names")
    nan = out.wait_for("NaN or infinite")
    assert short and nan, out.text()


def test_bytes_that_are_no_joint_state_are_dropped_and_the_drive_goes_on(
        odom_rig: OdomRigs) -> None:
    """The node reads JointState bytes itself: a sender's cut-off message or a corrupt
    count is dropped with a warning, and the next good reading moves the pose exactly."""
    from rclpy.serialization import serialize_message

    proc, out, _, ex, pub, sink = odom_rig()
    send_first(ex, pub, sink, reading(T0_NS, [0.0, 0.0]))
    good = serialize_message(reading(T0_NS + STEP_NS, [1.0, 1.0]))
    pub.publish(good[: len(good) // 2])  # cut off
    corrupt = bytearray(good)
    corrupt[20:24] = b"\xff\xff\xff\xff"  # the name count (after an empty frame_id): 4e9
    pub.publish(bytes(corrupt))
    spin_for(ex, 0.05)
    last_ns = T0_NS + 2 * STEP_NS
    pub.publish(reading(last_ns, [1.0, 1.0]))
    assert spin_until(ex, lambda: any(ns_of(o.header.stamp) == last_ns for o in sink.odom))
    dropped = out.wait_for("not a JointState")
    assert proc.poll() is None
    assert dropped, out.text()
    final = next(o for o in sink.odom if ns_of(o.header.stamp) == last_ns)
    assert math.isclose(final.pose.pose.position.x, R * 1.0, abs_tol=1e-12)
    assert not any(ns_of(o.header.stamp) == T0_NS + STEP_NS for o in sink.odom)


def test_silent_input_is_reported_with_the_resolved_topic() -> None:
    """Namespace and remap applied: the name in the warning is the one really subscribed."""
    with odometry_node("-r", "__ns:=/robot1", "-r", "joint_states:=wheel_states") as (proc, out):
        lines = out.wait_for("no JointState", timeout=20.0)
        assert proc.poll() is None
    assert lines, out.text()
    assert "/robot1/wheel_states" in lines[0]
    assert len(lines) == 1


def test_nan_positions_fall_back_to_velocity_and_say_so_once(odom_rig: OdomRigs) -> None:
    """ros2_control without a position interface: NaN positions, velocities filled."""
    _, out, _, ex, pub, sink = odom_rig()
    nan2 = [math.nan, math.nan]
    send_first(ex, pub, sink, reading(T0_NS, nan2, [2.0, 2.0]))
    for k in range(1, 51):  # 2 rad/s for 1 s: 2 rad on each wheel
        pub.publish(reading(T0_NS + k * STEP_NS, nan2, [2.0, 2.0]))
        spin_for(ex, 0.005)
    last_ns = T0_NS + 50 * STEP_NS
    assert spin_until(ex, lambda: any(ns_of(o.header.stamp) == last_ns for o in sink.odom))
    lines = out.wait_for("integrating wheel velocities")
    spin_for(ex, 0.3)
    final = [o for o in sink.odom if ns_of(o.header.stamp) == last_ns][-1]
    assert math.isclose(final.pose.pose.position.x, R * 2.0, abs_tol=1e-9)
    assert len(lines) == 1 and len(out.matching("integrating wheel velocities")) == 1, out.text()
