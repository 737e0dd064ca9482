"""The QoS profiles of this package's topics, in one place so publishers and subscribers agree.

Nodes, the demo's recorder and the bag player build theirs with :func:`qos`; the ones
shared across modules are named here.
"""

from __future__ import annotations

from rclpy.qos import (
    DurabilityPolicy,
    HistoryPolicy,
    QoSProfile,
    ReliabilityPolicy,
)


def qos(depth: int, reliable: bool, latched: bool = False) -> QoSProfile:
    """Keep-last QoS: our topics differ only in depth, reliability and (``/tf_static``) latching.

    ``latched`` is transient-local durability: a late subscriber still gets the last
    messages, as ``/tf_static`` requires; every other topic is volatile.
    """
    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST,
        depth=depth,
        reliability=ReliabilityPolicy.RELIABLE if reliable else ReliabilityPolicy.BEST_EFFORT,
        durability=DurabilityPolicy.TRANSIENT_LOCAL if latched else DurabilityPolicy.VOLATILE,
    )


# A best-effort subscriber matches reliable *and* best-effort publishers, so encoder
# drivers of either kind connect; the deep queue absorbs bursts (bag replay).
SENSOR_IN_QOS = qos(100, reliable=False)
# Commands in (cmd_vel, wheel commands): best effort matches reliable and best-effort
# publishers alike (teleop, Nav2, joystick drivers); only the newest command matters, so
# the queue is short.
CMD_IN_QOS = qos(5, reliable=False)
# What Nav2 and robot_localization expect of odometry.
RELIABLE_OUT_QOS = qos(10, reliable=True)
TF_QOS = qos(100, reliable=True)
# As ROS 2's diagnostic_updater: keep-last 1, reliable, volatile (its create_publisher(..., 1)).
DIAGNOSTICS_QOS = qos(1, reliable=True)
# path_follower_node's ~/done, latched: a late subscriber (a mission script, the demo)
# still learns that the path is done.
DONE_QOS = qos(1, reliable=True, latched=True)
