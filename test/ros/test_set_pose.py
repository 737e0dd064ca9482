"""~/set_pose over DDS: odometry_node and odometry_lifecycle_node (the same endpoints).

Readings drive straight (1 cm a reading); expected poses are the requested ones and the
oracle's arcs from there (test/oracle.py). Each request is followed only once the node
has named it in its log (held until seen), so no reading overtakes it.
"""

from __future__ import annotations

import math
from typing import Any

import pytest
from geometry_msgs.msg import PoseWithCovarianceStamped
from lifecycle_msgs.msg import Transition
from sensor_msgs.msg import JointState

import oracle
from rosutil import (
    GEOMETRY,
    STEP_NS,
    T0_NS,
    LifecycleManager,
    OdomRigs,
    Output,
    drive_straight,
    listen,
    node_process,
    ns_of,
    ros_test_node,
    spin_until,
    stamp,
    wait_for_subscriber,
    wait_ready,
    yaw,
)

pytestmark = [pytest.mark.dds, pytest.mark.process]

DS = 0.01  # m per reading: drive_straight's 0.1 rad a step on 0.1 m wheels


def request(x: float, y: float, heading: float, stamp_ns: int = 0, frame: str = "odom",
            xx: float = 0.04, tt: float = 0.0025) -> PoseWithCovarianceStamped:
    msg = PoseWithCovarianceStamped()
    msg.header.stamp = stamp(stamp_ns)
    msg.header.frame_id = frame
    msg.pose.pose.position.x, msg.pose.pose.position.y = x, y
    msg.pose.pose.orientation.z = math.sin(heading / 2)
    msg.pose.pose.orientation.w = math.cos(heading / 2)
    cov = [0.0] * 36
    cov[0], cov[7], cov[35] = xx, xx, tt
    msg.pose.covariance = cov
    return msg


def at(sink: Any, k: int) -> Any:
    got = [o for o in sink.odom if ns_of(o.header.stamp) == T0_NS + k * STEP_NS]
    return got[-1] if got else None


def near(o: Any, want: tuple[float, float, float]) -> bool:
    p = o.pose.pose
    return (math.isclose(p.position.x, want[0], abs_tol=1e-9)
            and math.isclose(p.position.y, want[1], abs_tol=1e-9)
            and abs(math.remainder(yaw(p.orientation) - want[2], math.tau)) < 1e-9)


def test_set_pose_now_ahead_and_refused(odom_rig: OdomRigs) -> None:
    _, out, node, ex, pub, sink = odom_rig()
    set_pub = node.create_publisher(PoseWithCovarianceStamped, "/odometry_node/set_pose", 10)
    assert wait_for_subscriber(ex, set_pub)
    drive_straight(pub, ex, sink, 0, 10, 0.1)
    assert spin_until(ex, lambda: at(sink, 10) is not None)

    set_pub.publish(request(5.0, 5.0, 1.0, frame="map"))  # refused, with its reason
    assert out.wait_for("set_pose refused [frame]", "'map'", "'odom'"), out.text()
    set_pub.publish(request(2.0, -1.0, 0.7))  # stamp 0: the pose at the last reading
    assert out.wait_for("set_pose: x=2 m", "last reading"), out.text()
    drive_straight(pub, ex, sink, 11, 4, 0.1, prime=False)
    assert spin_until(ex, lambda: at(sink, 15) is not None)
    start = (2.0, -1.0, 0.7)
    assert near(at(sink, 11), oracle.arc(DS, 0.0, start))
    assert near(at(sink, 15), oracle.arc(5 * DS, 0.0, start))
    a = -DS * math.sin(0.7)  # one step of P' = F P F^T (+ wheel noise ~1e-8)
    assert at(sink, 11).pose.covariance[0] == pytest.approx(0.04 + a * a * 0.0025, abs=1e-7)
    assert len(out.matching("set_pose")) == 2  # each named once

    ahead = T0_NS + 20 * STEP_NS + 5_000_000
    set_pub.publish(request(-3.0, 4.0, -2.5, stamp_ns=ahead))
    assert out.wait_for("set_pose: x=-3 m", "held"), out.text()
    drive_straight(pub, ex, sink, 16, 9, 0.1, prime=False)
    assert spin_until(ex, lambda: at(sink, 25) is not None)
    assert near(at(sink, 20), oracle.arc(10 * DS, 0.0, start))  # not yet
    assert near(at(sink, 21), (-3.0, 4.0, -2.5))  # the pose at the reading reaching it
    assert near(at(sink, 25), oracle.arc(4 * DS, 0.0, (-3.0, 4.0, -2.5)))


def test_the_lifecycle_node_takes_it_too() -> None:
    name = "/odometry_lifecycle_node"
    with node_process("odometry_lifecycle_node", ["--ros-args", *GEOMETRY]) as proc, \
            ros_test_node() as (node, ex):
        out = Output(proc)
        sink = listen(node, "/odom")
        pub = node.create_publisher(JointState, "/joint_states", 10)
        set_pub = node.create_publisher(PoseWithCovarianceStamped, f"{name}/set_pose", 10)
        manager = LifecycleManager(node, ex, name)
        for transition in (Transition.TRANSITION_CONFIGURE, Transition.TRANSITION_ACTIVATE):
            assert manager.change(transition)
        assert manager.state() == "active"
        wait_ready(ex, pub, sink, proc)
        assert wait_for_subscriber(ex, set_pub)
        drive_straight(pub, ex, sink, 0, 5, 0.1)
        assert spin_until(ex, lambda: at(sink, 5) is not None)
        set_pub.publish(request(1.0, 1.0, -1.0))
        assert out.wait_for("set_pose: x=1 m", "last reading"), out.text()
        drive_straight(pub, ex, sink, 6, 2, 0.1, prime=False)
        assert spin_until(ex, lambda: at(sink, 8) is not None)
        assert near(at(sink, 6), oracle.arc(DS, 0.0, (1.0, 1.0, -1.0)))
