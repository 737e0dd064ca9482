"""The online estimate's reference pose on the odometry node (issue 25 item 4).

``online_calibration_reference_topic`` (read-only; '' = none): a lidar odometry, motion
capture or AMCL, as ``nav_msgs/Odometry`` or ``geometry_msgs/PoseStamped``
(``online_calibration_reference_type``). Thin: each message becomes a stamp and a
planar pose (:func:`~diffdrive_odom.wire.conversions.reference_pose`, as replay reads a
bag's) for the pipeline, which matches it to the wheels and the gyro
(:mod:`~diffdrive_odom.core.estimation.online.online_scale`). A refused pose is named,
throttled per reason. Low rate (a few to a hundred Hz): rclpy's own deserialisation.
"""

from __future__ import annotations

from typing import Any

from geometry_msgs.msg import PoseStamped
from nav_msgs.msg import Odometry
from rclpy.node import Node

from diffdrive_odom.core.estimation.online.online_scale import POSE_STAMPED, ReferenceConfig
from diffdrive_odom.core.estimation.pipeline import ReadingPipeline
from diffdrive_odom.ros.qos import SENSOR_IN_QOS
from diffdrive_odom.ros.throttle import KeyedThrottle
from diffdrive_odom.wire.conversions import reference_pose


class ReferenceSubscription:
    """The reference topic's subscription, feeding the pipeline's online scale."""

    def __init__(self, node: Node, config: ReferenceConfig,
                 pipeline: ReadingPipeline, throttle: KeyedThrottle) -> None:
        self._node, self._pipeline, self._throttle = node, pipeline, throttle
        kind = PoseStamped if config.kind == POSE_STAMPED else Odometry
        self._sub = node.create_subscription(kind, config.topic, self._on_pose, SENSOR_IN_QOS)

    def destroy(self) -> None:
        """Remove the subscription from the node."""
        self._node.destroy_subscription(self._sub)

    def _on_pose(self, msg: Any) -> None:
        stamp, x, y, yaw = reference_pose(msg)
        code = self._pipeline.feed_reference(stamp, x, y, yaw)
        if code:
            self._throttle.warning(f"reference_{code}", f"reference pose dropped [{code}]: "
                                   f"stamp {stamp * 1e-9:.3f} s on {self._sub.topic_name}")
