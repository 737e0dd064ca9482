"""Publishers that follow a managed node's state: one call for plain and lifecycle nodes.

So the odometry endpoints and the /diagnostics publisher are written once for
``odometry_node`` and ``odometry_lifecycle_node``.
"""

from __future__ import annotations

from typing import Any, cast

from rclpy.lifecycle import LifecycleNode
from rclpy.node import Node
from rclpy.publisher import Publisher
from rclpy.qos import QoSProfile


def create_publisher(node: Node, msg_type: Any, topic: str, qos_profile: QoSProfile) -> Publisher:
    """A publisher; on a managed node a lifecycle one, so it publishes only while active."""
    if isinstance(node, LifecycleNode):
        return cast(Publisher, node.create_lifecycle_publisher(msg_type, topic, qos_profile))
    return node.create_publisher(msg_type, topic, qos_profile)


def destroy_publisher(node: Node, publisher: Publisher) -> None:
    """Undo :func:`create_publisher` (a managed node also forgets the managed entity)."""
    if isinstance(node, LifecycleNode):
        node.destroy_lifecycle_publisher(publisher)
    else:
        node.destroy_publisher(publisher)
