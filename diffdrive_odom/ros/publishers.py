"""Publishers that follow a managed node's state: one call for plain and lifecycle nodes.

So the odometry endpoints and the /diagnostics publisher are written once for
``odometry_node`` and ``odometry_lifecycle_node``; ``odom`` with ``/tf``
(:class:`OdometryOutput`) once for both of its modes, encoders and open loop; and a
report on a steady timer (:class:`SteadyPublisher`) once for every node.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, cast

from nav_msgs.msg import Odometry
from rclpy.clock import Clock, ClockType
from rclpy.lifecycle import LifecycleNode
from rclpy.node import Node
from rclpy.publisher import Publisher
from rclpy.qos import QoSProfile

from diffdrive_odom.core.estimation.config import OdometrySettings
from diffdrive_odom.core.estimation.publication import Publication
from diffdrive_odom.ros.lockstep import Alone, Loop
from diffdrive_odom.ros.qos import RELIABLE_OUT_QOS, TF_QOS
from diffdrive_odom.wire.odometry import OdometryLayout, TransformLayout


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


class SteadyPublisher:
    """A publisher fed by a timer on the steady clock (/diagnostics, ~/geometry_estimate).

    Steady time, so a paused /clock (use_sim_time) does not silence the report.
    """

    def __init__(self, node: Node, msg_type: Any, topic: str, qos_profile: QoSProfile,
                 period_s: float, tick: Callable[[], None]) -> None:
        self._node = node
        self._pub = create_publisher(node, msg_type, topic, qos_profile)
        self._timer = node.create_timer(period_s, tick,
                                        clock=Clock(clock_type=ClockType.STEADY_TIME))

    def destroy(self) -> None:
        """Remove the timer and the publisher from the node."""
        self._node.destroy_timer(self._timer)
        destroy_publisher(self._node, self._pub)


class OdometryOutput:
    """The odometry node's ``odom`` and ``/tf`` (``enable_odom_tf``), whichever mode feeds it.

    What stays the same from message to message (frames, a static covariance) is filled
    once per settings (:meth:`configure`); each pose then only writes the stamp, pose and
    twist into the same bytes. ``loop``: the node's (:func:`diffdrive_odom.ros.lockstep.join`),
    in lockstep both are counted.
    """

    def __init__(self, node: Node, settings: OdometrySettings, loop: Loop | None = None
                 ) -> None:
        # Here, not at the top: tf2_msgs is no PyPI package, and --help must work without
        # it (runtime.run turns its absence into one line saying how to get it).
        from tf2_msgs.msg import TFMessage

        self._node = node
        loop = loop if loop is not None else Alone(node)
        self._odom_pub = create_publisher(node, Odometry, "odom", RELIABLE_OUT_QOS)
        self._tf_pub = create_publisher(node, TFMessage, "/tf", TF_QOS)
        self._publish_odom = loop.publish(self._odom_pub)
        self._publish_tf = loop.publish(self._tf_pub)
        self.configure(settings)

    def configure(self, settings: OdometrySettings) -> None:
        """The frames and ``enable_odom_tf`` of (new) settings; the covariance is written next."""
        self._odom = OdometryLayout(settings.odom_frame_id, settings.base_frame_id)
        self._tf = TransformLayout(settings.odom_frame_id, settings.base_frame_id)
        self._with_tf = settings.enable_odom_tf
        self._covariance_stale = True

    def publish(self, stamp_ns: int, out: Publication, static_covariance: bool = False) -> None:
        """``out`` stamped ``stamp_ns`` (the only place that sets the published covariance).

        ``static_covariance``: it is the parameters' diagonals, written only after
        :meth:`configure`; else (propagated) it is written every message.
        """
        if not static_covariance or self._covariance_stale:
            self._odom.covariance(out.pose_covariance, out.twist_covariance)
            self._covariance_stale = False
        x, y, theta = out.pose.x, out.pose.y, out.pose.theta
        self._publish_odom(self._odom.planar(stamp_ns, x, y, theta, out.linear, out.angular))
        if self._with_tf:
            self._publish_tf(self._tf.planar(stamp_ns, x, y, theta))

    def destroy(self) -> None:
        """Remove both publishers from the node."""
        destroy_publisher(self._node, self._tf_pub)
        destroy_publisher(self._node, self._odom_pub)


def frames_text(settings: OdometrySettings) -> str:
    """The frames as a start-up line says them: the transform only where /tf gets it."""
    odom, base = settings.odom_frame_id, settings.base_frame_id
    if settings.enable_odom_tf:
        return f"{odom} -> {base} on /tf"
    return f"odom in frame {odom} (child {base}), no /tf (enable_odom_tf false)"
