"""Velocity commands in, as every node of this package takes them (one subscription rule).

``cmd_vel_node`` follows them and ``odometry_node`` with ``open_loop`` integrates them:
both subscribe through :class:`CommandInput`, so they agree on the type (Twist, or
TwistStamped with ``enable_stamped_cmd_vel``), the QoS and what a zero stamp means.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from geometry_msgs.msg import Twist, TwistStamped
from rclpy.node import Node

from diffdrive_odom.ros.lockstep import Alone, Loop
from diffdrive_odom.ros.qos import CMD_IN_QOS
from diffdrive_odom.wire.conversions import stamp_to_ns

Vector = tuple[float, float, float]
# linear (x, y, z), angular (x, y, z), the stamp [ns] (None: a Twist or a zero stamp)
OnCommand = Callable[[Vector, Vector, "int | None"], None]


class CommandInput:
    """One subscription to velocity commands; each one goes to ``on_command``.

    A zero stamp on a TwistStamped is taken as "now" (None), with a warning said once.
    ``loop``: the node's (:func:`diffdrive_odom.ros.lockstep.join`), in lockstep a counted
    reliable subscription.
    """

    def __init__(self, node: Node, topic: str, stamped: bool, on_command: OnCommand,
                 loop: Loop | None = None) -> None:
        self._node = node
        self._on_command = on_command
        self._zero_stamp_warned = False
        self.stamped = stamped
        subscribe = (loop if loop is not None else Alone(node)).subscription
        self.subscription: Any = (
            subscribe(TwistStamped, topic, self._on_twist_stamped, CMD_IN_QOS)
            if stamped else subscribe(Twist, topic, self._on_twist, CMD_IN_QOS))

    @property
    def type_name(self) -> str:
        """The message type subscribed, as ``ros2 topic info`` names it."""
        return "geometry_msgs/msg/TwistStamped" if self.stamped else "geometry_msgs/msg/Twist"

    def type_mismatch(self) -> str | None:
        """The warning when the topic has a publisher of the other type (nothing can arrive)."""
        topic = self.subscription.topic_name
        expected = self.type_name
        for info in self._node.get_publishers_info_by_topic(topic):
            if info.topic_type != expected:
                return (f"{topic} has a publisher of type {info.topic_type} but this node "
                        f"expects {expected}: set enable_stamped_cmd_vel to "
                        f"{str(expected.endswith('Twist')).lower()}")
        return None

    def destroy(self) -> None:
        """Remove the subscription from the node."""
        self._node.destroy_subscription(self.subscription)

    def _on_twist(self, msg: Twist) -> None:
        self._forward(msg, None)

    def _on_twist_stamped(self, msg: TwistStamped) -> None:
        stamp_ns: int | None = stamp_to_ns(msg.header.stamp)
        if stamp_ns == 0:
            if not self._zero_stamp_warned:
                self._zero_stamp_warned = True
                self._node.get_logger().warning(
                    f"{self.subscription.topic_name} header stamp is zero: taken as 'now' (this "
                    "warning is shown once; stamp commands so that delayed ones can be "
                    "recognised)")
            stamp_ns = None
        self._forward(msg.twist, stamp_ns)

    def _forward(self, twist: Twist, stamp_ns: int | None) -> None:
        lin, ang = twist.linear, twist.angular
        self._on_command((lin.x, lin.y, lin.z), (ang.x, ang.y, ang.z), stamp_ns)
