"""The odometry node's pose inputs: ``~/set_pose`` and ``~/reset_odometry``.

Both modes (wheels, open loop) take them the same way. ``~/set_pose``
(geometry_msgs/PoseWithCovarianceStamped) is private (``~/``), like ``~/reset_odometry``
(std_srvs/Trigger), so it cannot meet robot_localization's own
``set_pose`` (relative, same type) that usually runs beside this node. The rule (what is
refused, when the pose takes effect) is the core's
(:mod:`diffdrive_odom.core.estimation.setpose`); here the message becomes a request and
the outcome a log line: an accepted pose named once (INFO), a refused one with its
reason (WARN, throttled per reason).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Protocol

from geometry_msgs.msg import PoseWithCovarianceStamped
from rclpy.node import Node
from std_srvs.srv import Trigger

from diffdrive_odom.core.estimation.setpose import PoseRefusal, PoseRequest
from diffdrive_odom.ros.throttle import KeyedThrottle
from diffdrive_odom.wire.conversions import stamp_to_ns

TOPIC = "~/set_pose"
RESET_SERVICE = "~/reset_odometry"


def pose_request(msg: PoseWithCovarianceStamped) -> PoseRequest:
    """The message's fields as the core takes them."""
    p, q = msg.pose.pose.position, msg.pose.pose.orientation
    return PoseRequest(stamp_to_ns(msg.header.stamp), msg.header.frame_id, (p.x, p.y, p.z),
                       (q.x, q.y, q.z, q.w), tuple(msg.pose.covariance))


class PoseTaker(Protocol):
    """What takes a set pose: the reading pipeline, or open loop's odometry."""

    def set_pose(self, request: PoseRequest) -> str | PoseRefusal:
        """The line naming the pose set (or held), or why it is refused."""
        ...


class PoseInputs:
    """One odometry node's ``~/reset_odometry`` service and ``~/set_pose`` subscription.

    ``reset`` puts the pose back to the origin; ``pipeline`` takes a set pose.
    """

    def __init__(self, node: Node, reset: Callable[[], None], pipeline: PoseTaker,
                 throttle: KeyedThrottle) -> None:
        self._node, self._reset = node, reset
        self._pipeline, self._throttle = pipeline, throttle
        self._srv = node.create_service(Trigger, RESET_SERVICE, self._on_reset)
        self._sub = node.create_subscription(PoseWithCovarianceStamped, TOPIC, self._on_pose, 10)

    def destroy(self) -> None:
        """Remove the service and the subscription from the node."""
        self._node.destroy_service(self._srv)
        self._node.destroy_subscription(self._sub)

    def _on_pose(self, msg: PoseWithCovarianceStamped) -> None:
        out = self._pipeline.set_pose(pose_request(msg))
        if isinstance(out, PoseRefusal):
            self._throttle.warning(f"set_pose_{out.code}",
                                   f"set_pose refused [{out.code}]: {out.reason}")
        else:
            self._node.get_logger().info(out)

    def _on_reset(self, request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        self._reset()
        response.success = True
        response.message = "odometry reset to the origin"
        self._node.get_logger().info(response.message)
        return response
