"""The /diagnostics publisher: a node's health report as diagnostic_updater would send it.

The report itself is computed in :mod:`diffdrive_odom.core.health.diagnostics` (pure); this
module only names the status and publishes it on a steady-clock timer.
"""

from __future__ import annotations

from collections.abc import Callable

from diagnostic_msgs.msg import (
    DiagnosticArray,
    DiagnosticStatus,
    KeyValue,
)
from rclpy.node import Node

from diffdrive_odom.core.health.diagnostics import Report
from diffdrive_odom.ros.publishers import SteadyPublisher
from diffdrive_odom.ros.qos import DIAGNOSTICS_QOS

# As ROS 2's diagnostic_updater: an absolute topic (one per robot, whatever the node's
# namespace), published once a second (its QoS: ros.qos.DIAGNOSTICS_QOS).
DIAGNOSTICS_TOPIC = "/diagnostics"
DIAGNOSTICS_PERIOD_S = 1.0


def diagnostic_status_name(node: Node, task: str) -> str:
    """``"<node>: <task>"`` as diagnostic_updater names a status.

    At the root namespace that is the bare node name (its default); in a namespace
    the fully qualified one (its ``diagnostic_updater.use_fqn``), so that two robots'
    nodes do not share a status name on the aggregator.
    """
    base = node.get_name() if node.get_namespace() == "/" else node.get_fully_qualified_name()
    return f"{base}: {task}"


class DiagnosticsPublisher(SteadyPublisher):
    """Publishes ``report()`` as a one-status DiagnosticArray on /diagnostics at 1 Hz.

    The timer runs on the steady clock, like the wheel-command heartbeat, so a paused
    /clock (use_sim_time) does not silence the health report; the array is stamped
    from the node's clock, as diagnostic_updater stamps it. ``hardware_id`` "none" is
    diagnostic_updater's advice for a status that belongs to no device.
    """

    def __init__(
        self,
        node: Node,
        task: str,
        report: Callable[[], Report],
        hardware_id: str = "none",
        period_s: float = DIAGNOSTICS_PERIOD_S,
    ) -> None:
        self._report = report
        self.name = diagnostic_status_name(node, task)
        self.hardware_id = hardware_id
        super().__init__(node, DiagnosticArray, DIAGNOSTICS_TOPIC, DIAGNOSTICS_QOS, period_s,
                         self.publish)

    def publish(self) -> None:
        """Publish the current report now (the timer calls this once a period)."""
        report = self._report()
        status = DiagnosticStatus()
        status.level = bytes([int(report.level)])
        status.name = self.name
        status.message = report.message
        status.hardware_id = self.hardware_id
        status.values = [KeyValue(key=k, value=v) for k, v in report.values]
        msg = DiagnosticArray()
        msg.header.stamp = self._node.get_clock().now().to_msg()
        msg.status = [status]
        self._pub.publish(msg)
