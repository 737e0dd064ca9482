"""The online estimate's reference pose on the odometry node (issue 25 item 4), and its mount.

``online_calibration_reference_topic`` (read-only; '' = none): a lidar odometry, motion
capture or AMCL, as ``nav_msgs/Odometry`` or ``geometry_msgs/PoseStamped``
(``online_calibration_reference_type``). Thin: each message becomes a stamp and a
planar pose (:func:`~diffdrive_odom.wire.conversions.reference_pose`, as replay reads a
bag's) for the pipeline, which moves it onto the base frame by the reference's mount and
matches it to the wheels and the gyro
(:mod:`~diffdrive_odom.core.estimation.online.online_scale`). A refused pose is named,
throttled per reason. Low rate (a few to a hundred Hz): rclpy's own deserialisation.

The mount is ``online_calibration_reference_offset``, or, with
``online_calibration_reference_frame``, the transform ``base_frame_id`` -> that frame on
/tf_static (tf2 is not on PyPI: the node reads the latched topic itself, as tf2's static
listener does; a direct transform only, no chain). Until it has come, poses are refused
(``no_mount``) and the warning says what is awaited.
"""

from __future__ import annotations

from typing import Any

from geometry_msgs.msg import PoseStamped
from nav_msgs.msg import Odometry
from rclpy.node import Node

from diffdrive_odom.core.estimation.online.online_scale import POSE_STAMPED, ReferenceConfig
from diffdrive_odom.core.estimation.pipeline import ReadingPipeline
from diffdrive_odom.core.geometry.mount import Mount
from diffdrive_odom.ros.qos import SENSOR_IN_QOS, qos
from diffdrive_odom.ros.throttle import KeyedThrottle
from diffdrive_odom.wire.conversions import quaternion_to_yaw, reference_pose

STATIC_QOS = qos(100, reliable=True, latched=True)  # tf2's static listener's


class ReferenceSubscription:
    """The reference topic's subscription, feeding the pipeline's online scale."""

    def __init__(self, node: Node, config: ReferenceConfig, pipeline: ReadingPipeline,
                 throttle: KeyedThrottle, base_frame: str = "base_link") -> None:
        self._node, self._pipeline, self._throttle = node, pipeline, throttle
        self._base, self._frame = base_frame.lstrip("/"), config.frame
        self._mount: Mount | None = None if config.frame else config.mount
        kind = PoseStamped if config.kind == POSE_STAMPED else Odometry
        self._sub = node.create_subscription(kind, config.topic, self._on_pose, SENSOR_IN_QOS)
        self._static = None
        if config.frame:
            # Here, not at the top: tf2_msgs is no PyPI package (runtime.run names it).
            from tf2_msgs.msg import TFMessage

            self._static = node.create_subscription(TFMessage, "/tf_static", self._on_static,
                                                    STATIC_QOS)

    def destroy(self) -> None:
        """Remove the subscriptions from the node."""
        self._node.destroy_subscription(self._sub)
        if self._static is not None:
            self._node.destroy_subscription(self._static)

    def _on_static(self, msg: Any) -> None:
        for t in msg.transforms:
            if (str(t.header.frame_id).lstrip("/"), str(t.child_frame_id).lstrip("/")) != (
                    self._base, self._frame):
                continue
            p = t.transform.translation
            mount = Mount(float(p.x), float(p.y), quaternion_to_yaw(t.transform.rotation))
            if mount != self._mount:
                self._mount = mount
                self._pipeline.set_reference_mount(mount)
                self._node.get_logger().info(
                    f"reference mount from /tf_static, {self._base} -> {self._frame}: "
                    f"{mount.text()}")

    def _on_pose(self, msg: Any) -> None:
        stamp, x, y, yaw = reference_pose(msg)
        code = self._pipeline.feed_reference(stamp, x, y, yaw)
        if code == "no_mount":
            self._throttle.warning(
                "reference_no_mount", f"reference pose dropped [no_mount]: waiting for the "
                f"transform {self._base} -> {self._frame} on /tf_static "
                "(online_calibration_reference_frame)")
        elif code:
            self._throttle.warning(f"reference_{code}", f"reference pose dropped [{code}]: "
                                   f"stamp {stamp * 1e-9:.3f} s on {self._sub.topic_name}")
