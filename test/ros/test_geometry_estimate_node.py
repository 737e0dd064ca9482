"""odometry_node's ``~/geometry_estimate`` over real DDS (issue 25 item 2).

The robot stands 1 s while a 200 Hz gyro reads a bias: the online estimate runs (its
filter takes the standing windows for the bias), is not determined (no turn), and comes
out as std_msgs/Float64MultiArray with the documented layout: one dimension, labelled
with the field names, and /diagnostics says the same. A PoseStamped reference
(``online_calibration_reference_topic``) is subscribed and its poses counted (issue 25
item 4; standing, no window closes). In ``online_calibration: apply`` (item 3) it says
the estimate is not applied (not determined).
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

import pytest
from geometry_msgs.msg import PoseStamped
from sensor_msgs.msg import Imu, JointState
from std_msgs.msg import Float64MultiArray

from diffdrive_odom.ros.geometry_estimate import FIELDS, QOS

from diagutil import diagnosed
from rosutil import (
    GEOMETRY,
    NAMES,
    STEP_NS,
    T0_NS,
    gyro_rig,
    send_first,
    spin_for,
    spin_until,
    stamp,
)

pytestmark = [pytest.mark.dds, pytest.mark.process]

BIAS = 0.01  # rad/s


def reading(k: int) -> JointState:
    msg = JointState()
    msg.header.stamp = stamp(T0_NS + k * STEP_NS)
    msg.name = list(NAMES)
    msg.position = [0.0, 0.0]
    return msg


def gyro(ns: int) -> Imu:
    msg = Imu()
    msg.header.stamp = stamp(ns)
    msg.angular_velocity.z = BIAS
    return msg


def pose(ns: int) -> PoseStamped:
    msg = PoseStamped()
    msg.header.stamp = stamp(ns)
    msg.pose.position.x, msg.pose.orientation.w = 2.0, 1.0
    return msg


def stand(ex: Any, joints: Any, imu: Any, ref: Any, first: int, count: int) -> None:
    """Readings ``first`` .. standing, a 200 Hz gyro, a reference pose every fifth."""
    for k in range(first, first + count):
        for j in range(4):
            imu.publish(gyro(T0_NS + k * STEP_NS + j * STEP_NS // 4))
        if k % 5 == 1:
            ref.publish(pose(T0_NS + k * STEP_NS - STEP_NS // 2))
        spin_for(ex, 0.002)
        if k:
            joints.publish(reading(k))
        spin_for(ex, 0.004)


@contextmanager
def estimate_rig(*extra: str) -> Iterator[tuple[Any, Any, list[Any], Any, Any, Any, Any]]:
    """An odometry_node with the gyro and a PoseStamped reference on /ref, and its peer:
    (peer, executor, the geometry estimates heard, joints, imu, odom sink, /ref)."""
    with diagnosed("odometry_node", [*GEOMETRY, "-p", "use_imu:=true", "-p",
                                     "online_calibration_reference_topic:=/ref", "-p",
                                     "online_calibration_reference_type:=pose_stamped",
                                     *extra]) as peer:
        ex = peer.executor
        got: list[Any] = []
        peer.node.create_subscription(Float64MultiArray, "/odometry_node/geometry_estimate",
                                      got.append, QOS)
        joints, imu, sink = gyro_rig(peer.node, ex)
        ref = peer.node.create_publisher(PoseStamped, "/ref", 10)
        yield peer, ex, got, joints, imu, sink, ref


def test_geometry_estimate_has_the_documented_layout() -> None:
    with estimate_rig("-p", "online_calibration:=apply") as (peer, ex, got, joints, imu,
                                                             sink, ref):
        assert spin_until(ex, lambda: ref.get_subscription_count() > 0, 15.0)
        send_first(ex, joints, sink, reading(0))
        stand(ex, joints, imu, ref, 0, 51)
        standing = FIELDS.index("excluded_standstill")
        assert spin_until(ex, lambda: any(m.data[standing] > 0 for m in got), 15.0)
        msg = got[-1]
        assert [d.label for d in msg.layout.dim] == [",".join(FIELDS)]
        assert msg.layout.dim[0].size == len(FIELDS) == len(msg.data)
        value = dict(zip(FIELDS, msg.data, strict=True))
        assert value["determined"] == 0.0 and value["outside"] == 0.0
        assert value["applied"] == 0.0
        # Standing: the ratios keep their start values (the configured geometry).
        assert value["left_wheel_radius_multiplier"] == pytest.approx(1.0, abs=1e-9)
        assert value["wheel_separation_multiplier"] == pytest.approx(1.0, abs=1e-9)
        assert value["excluded_standstill"] > 0 and value["steps"] == 0  # none moving
        assert value["gyro_bias"] == pytest.approx(BIAS, rel=0.05)
        assert value["reference"] == 1.0 and value["scale_determined"] == 0.0
        assert value["reference_poses"] > 0 and value["gyro_scale"] == 1.0
        status = peer.wait_for(lambda s: "online calibration" in s.values, 15.0)
        assert status.values["online calibration"] == "not yet determined"
        assert status.values["online estimate applied"] == "false"
        assert status.values["online scale"] == "from the reference: not yet determined"


def test_the_reference_frame_s_mount_comes_from_tf_static() -> None:
    """online_calibration_reference_frame: marker. Until /tf_static holds base_link ->
    marker, every reference pose is refused (none counted, though the estimate runs);
    once it is latched there, the poses count (the node reads /tf_static itself)."""
    from geometry_msgs.msg import TransformStamped
    from tf2_msgs.msg import TFMessage

    from diffdrive_odom.ros.reference_input import STATIC_QOS

    with estimate_rig("-p", "online_calibration_reference_frame:=marker") as (
            peer, ex, got, joints, imu, sink, ref):
        static = peer.node.create_publisher(TFMessage, "/tf_static", STATIC_QOS)
        assert spin_until(ex, lambda: ref.get_subscription_count() > 0
                          and static.get_subscription_count() > 0, 15.0)
        send_first(ex, joints, sink, reading(0))
        poses, standing = FIELDS.index("reference_poses"), FIELDS.index("excluded_standstill")
        stand(ex, joints, imu, ref, 1, 60)
        # the estimate runs (standing windows) and has seen the wheels past the poses sent
        assert spin_until(ex, lambda: any(m.data[standing] > 5 for m in got), 15.0)
        assert all(m.data[poses] == 0.0 for m in got), [m.data[poses] for m in got]
        t = TransformStamped()
        t.header.frame_id, t.child_frame_id = "base_link", "marker"
        t.transform.translation.x, t.transform.rotation.w = 0.1, 1.0
        static.publish(TFMessage(transforms=[t]))
        spin_for(ex, 0.2)
        stand(ex, joints, imu, ref, 61, 60)
        assert spin_until(ex, lambda: got[-1].data[poses] > 0, 15.0), got[-1].data[poses]
