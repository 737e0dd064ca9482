"""``odometry_node``: sensor_msgs/JointState -> nav_msgs/Odometry and odom -> base_link.

Thin rclpy shell around :class:`diffdrive_odom.odometry.OdometryEstimator`: it only
declares parameters, converts messages and logs the estimator's verdicts. Output is
stamped with the JointState's own header stamp (the measurement time), never the
time the message happened to be processed.
"""

from __future__ import annotations

import math
from typing import Any

from geometry_msgs.msg import TransformStamped
from nav_msgs.msg import Odometry
from rclpy.node import Node
from sensor_msgs.msg import JointState
from std_srvs.srv import Trigger
from tf2_msgs.msg import TFMessage

from diffdrive_odom import ros_common
from diffdrive_odom.odometry import (
    OdometryEstimator,
    PublishGate,
    Status,
    Verdict,
    covariance_matrix,
    yaw_to_quaternion,
)
from diffdrive_odom.params import (
    GEOMETRY_PARAMS,
    ODOMETRY_PARAMS,
    OdometrySettings,
    ParamValue,
    odometry_settings,
)

NODE_NAME = "odometry_node"


class OdometryNode(Node):
    """Publishes wheel odometry computed from encoder readings."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(NODE_NAME, **kwargs)
        values = ros_common.declare(self, GEOMETRY_PARAMS + ODOMETRY_PARAMS)
        settings = self._build(values)
        self._settings = settings
        self._estimator = OdometryEstimator(
            settings.geometry, settings.encoders, settings.estimator
        )
        self._pose_cov = covariance_matrix(settings.pose_covariance_diagonal)
        self._twist_cov = covariance_matrix(settings.twist_covariance_diagonal)
        self._gate = PublishGate(settings.publish_rate)
        self._guard = ros_common.ParameterGuard(self, values, self._build, self._apply)

        self._odom_pub = self.create_publisher(Odometry, "odom", ros_common.RELIABLE_OUT_QOS)
        self._tf_pub = self.create_publisher(TFMessage, "/tf", ros_common.TF_QOS)
        self.create_subscription(
            JointState, "joint_states", self._on_joint_state, ros_common.SENSOR_IN_QOS
        )
        self.create_service(Trigger, "~/reset_odometry", self._on_reset)
        g = settings.geometry
        self.get_logger().info(
            f"wheel odometry: r_left={g.left_radius:.6g} m, r_right={g.right_radius:.6g} m, "
            f"b={g.separation:.6g} m, {settings.odom_frame_id} -> {settings.base_frame_id}, "
            f"joints {list(settings.encoders.left_wheel_names)} / "
            f"{list(settings.encoders.right_wheel_names)}"
        )

    def _build(self, values: dict[str, ParamValue]) -> OdometrySettings:
        return odometry_settings(values, self.get_namespace())

    def _apply(self, settings: OdometrySettings) -> None:
        """Install accepted runtime changes; the pose carries on without a jump."""
        old = self._settings
        self._settings = settings
        self._pose_cov = covariance_matrix(settings.pose_covariance_diagonal)
        self._twist_cov = covariance_matrix(settings.twist_covariance_diagonal)
        self._gate.rate = settings.publish_rate
        if settings.encoders != old.encoders or settings.estimator != old.estimator:
            # The units of the reference reading changed: keep the pose, take the next
            # reading as the new reference.
            pose = self._estimator.pose
            self._estimator = OdometryEstimator(
                settings.geometry, settings.encoders, settings.estimator
            )
            self._estimator.pose = pose
        else:
            self._estimator.set_geometry(settings.geometry)
        self.get_logger().info("parameters updated")

    def _on_reset(self, request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        self._estimator.reset()
        self._gate.last_ns = None
        response.success = True
        response.message = "odometry reset to the origin"
        self.get_logger().info(response.message)
        return response

    def _on_joint_state(self, msg: JointState) -> None:
        stamp_ns = ros_common.stamp_to_ns(msg.header.stamp)
        if stamp_ns <= 0:
            self._warn("joint_states header stamp is zero: message dropped (odometry is "
                       "stamped with the measurement time, so the driver must stamp it)")
            return
        verdict = self._estimator.update(stamp_ns, msg.name, msg.position, msg.velocity)
        self._report(verdict)
        if verdict.has_new_pose and self._gate.due(stamp_ns):
            self._publish(msg.header.stamp)

    def _report(self, verdict: Verdict) -> None:
        if verdict.status is Status.TIME_RESET:
            self.get_logger().warning(verdict.reason)
        elif verdict.status in (Status.DROPPED, Status.REANCHORED):
            self._warn(f"joint_states reading {verdict.status.value}: {verdict.reason}")

    def _warn(self, text: str) -> None:
        self.get_logger().warning(text, throttle_duration_sec=ros_common.WARN_THROTTLE_S)

    def _publish(self, stamp: Any) -> None:
        est = self._estimator
        pose, s = est.pose, self._settings
        values = (pose.x, pose.y, pose.theta, est.linear, est.angular)
        if not all(math.isfinite(v) for v in values):  # cannot happen; never publish NaN
            self._warn("non-finite odometry suppressed")
            return
        qx, qy, qz, qw = yaw_to_quaternion(pose.theta)
        odom = Odometry()
        odom.header.stamp = stamp
        odom.header.frame_id = s.odom_frame_id
        odom.child_frame_id = s.base_frame_id
        p = odom.pose.pose
        p.position.x, p.position.y = pose.x, pose.y
        p.orientation.x, p.orientation.y, p.orientation.z, p.orientation.w = qx, qy, qz, qw
        odom.pose.covariance = self._pose_cov
        odom.twist.twist.linear.x = est.linear
        odom.twist.twist.angular.z = est.angular
        odom.twist.covariance = self._twist_cov
        self._odom_pub.publish(odom)
        if s.enable_odom_tf:
            tf = TransformStamped()
            tf.header = odom.header
            tf.child_frame_id = s.base_frame_id
            t = tf.transform
            t.translation.x, t.translation.y = pose.x, pose.y
            t.rotation = p.orientation
            self._tf_pub.publish(TFMessage(transforms=[tf]))


def main(args: list[str] | None = None) -> int:
    """Console script / ``ros2 run diffdrive_odom odometry_node``."""
    return ros_common.run(OdometryNode, args)


if __name__ == "__main__":
    raise SystemExit(main())
