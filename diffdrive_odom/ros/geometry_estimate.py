"""``~/geometry_estimate``: the online geometry estimate as std_msgs/Float64MultiArray.

One dimension, its label the comma-separated field names of
:data:`diffdrive_odom.core.estimation.online.online_estimate.FIELDS` then
:data:`diffdrive_odom.core.estimation.online.online_scale.SCALE_FIELDS` then
:data:`diffdrive_odom.core.estimation.online.online_apply.APPLY_FIELDS` (so a reader finds each
value by name, and a field added later does not shift silently), its size their count.
Published once a second when the estimate changed (a filter update), reliable and
transient local, so a late subscriber gets the last one.
"""

from __future__ import annotations

from collections.abc import Callable

from rclpy.node import Node
from std_msgs.msg import Float64MultiArray, MultiArrayDimension

from diffdrive_odom.core.estimation.online.online_apply import APPLY_FIELDS
from diffdrive_odom.core.estimation.online.online_estimate import FIELDS as GYRO_FIELDS
from diffdrive_odom.core.estimation.online.online_estimate import OnlineEstimate
from diffdrive_odom.core.estimation.online.online_scale import SCALE_FIELDS, scale_values
from diffdrive_odom.ros.publishers import SteadyPublisher
from diffdrive_odom.ros.qos import qos

TOPIC = "~/geometry_estimate"
PERIOD_S = 1.0
FIELDS = GYRO_FIELDS + SCALE_FIELDS + APPLY_FIELDS
LABEL = ",".join(FIELDS)
QOS = qos(1, reliable=True, latched=True)


def estimate_message(est: OnlineEstimate) -> Float64MultiArray:
    """The message for ``est`` (see the module for the layout)."""
    msg = Float64MultiArray()
    msg.layout.dim = [MultiArrayDimension(label=LABEL, size=len(FIELDS), stride=len(FIELDS))]
    values = (est.values() + scale_values(est.scale, est.multipliers, est.stddevs)
              + (float(est.applied),))
    msg.data = [float(v) for v in values]
    return msg


class GeometryEstimatePublisher(SteadyPublisher):
    """Publishes what ``estimate`` returns when its filter updated (None: nothing)."""

    def __init__(self, node: Node, estimate: Callable[[], OnlineEstimate | None]) -> None:
        self._estimate = estimate
        self._windows = -1
        super().__init__(node, Float64MultiArray, TOPIC, QOS, PERIOD_S, self._tick)

    def _tick(self) -> None:
        est = self._estimate()
        if est is None or est.windows == self._windows:
            return
        self._windows = est.windows
        self._pub.publish(estimate_message(est))
