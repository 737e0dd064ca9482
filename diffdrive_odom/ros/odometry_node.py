"""``odometry_node``: sensor_msgs/JointState -> nav_msgs/Odometry and odom -> base_link.

Thin rclpy shell around :class:`diffdrive_odom.core.estimation.pipeline.ReadingPipeline` (the same
reading path replay and the demo use): it only declares parameters, converts
messages and logs the verdicts, one throttle per reason. Output is
stamped with the JointState's own header stamp (the measurement time), never the
time the message happened to be processed.

Messages cross rclpy as their serialised bytes (:mod:`diffdrive_odom.wire`): at 1 kHz,
rclpy's conversions to and from Python objects cost more than the odometry itself.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Generic, TypeVar

from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.serialization import deserialize_message
from sensor_msgs.msg import Imu, JointState

from diffdrive_odom.core.estimation.config import OdometrySettings
from diffdrive_odom.core.estimation.pipeline import IMU_SILENT, ReadingPipeline
from diffdrive_odom.core.estimation.publication import Refusal, pipeline_publication
from diffdrive_odom.core.estimation.results import Outcome
from diffdrive_odom.core.estimation.wheels.timeline import Status
from diffdrive_odom.core.health.diagnostics import (
    RateMeter,
    ReadingHealth,
    Report,
    Reporter,
    odometry_report,
)
from diffdrive_odom.ros.diagnostics import DiagnosticsPublisher
from diffdrive_odom.ros.geometry_estimate import GeometryEstimatePublisher
from diffdrive_odom.ros.lockstep import join
from diffdrive_odom.ros.parameters import ParameterGuard, declare
from diffdrive_odom.ros.publishers import OdometryOutput, frames_text
from diffdrive_odom.ros.qos import SENSOR_IN_QOS
from diffdrive_odom.ros.reference_input import ReferenceSubscription
from diffdrive_odom.ros.runtime import run
from diffdrive_odom.ros.set_pose import PoseInputs
from diffdrive_odom.ros.throttle import KeyedThrottle
from diffdrive_odom.settings.odometry import ODOMETRY_PARAMS, odometry_settings, online_warning
from diffdrive_odom.settings.params import ParamValue
from diffdrive_odom.wire.imu import ImuFields, decode_imu
from diffdrive_odom.wire.jointstate import JointArrays, JointStateDecoder

if TYPE_CHECKING:
    from diffdrive_odom.ros.open_loop import OpenLoopEndpoints

NODE_NAME = "odometry_node"
T = TypeVar("T")
NO_INPUT_WARN_S = 5.0  # s of steady time without a reading before saying so


class OdometryEndpoints:
    """Everything ``odometry_node`` does, on the node it is given.

    Both the plain :class:`OdometryNode` and the managed
    :class:`~diffdrive_odom.ros.odometry_lifecycle_node.OdometryLifecycleNode` (which builds
    one at configure and destroys it at cleanup) use this one class, so the two never
    differ in a rule, a topic or a QoS. On a LifecycleNode its publishers are lifecycle
    publishers: readings are integrated whenever it exists, published only while active.
    With ``lockstep`` the readings and their odometry are counted for the simulation's
    loop (:mod:`diffdrive_odom.ros.lockstep`). Raises ParameterError (before creating
    anything) for values that cannot work.
    """

    def __init__(self, node: Node, values: dict[str, ParamValue]) -> None:
        self._node = node
        settings = self._build(values)
        self._loop = join(node, bool(values["lockstep"]))
        self._output = OdometryOutput(node, settings, self._loop)
        self._pipeline = ReadingPipeline(settings)
        self._decoder = JointStateDecoder()
        self._throttle = KeyedThrottle(node.get_logger())
        self._guard = ParameterGuard(node, values, self._build, self._apply)
        self._sub = self._loop.subscription(
            JointState, "joint_states", self._on_joint_state, SENSOR_IN_QOS, raw=True
        )
        # use_imu is read-only: the subscription exists for the node's whole life or not.
        self._imu_sub = None if settings.gyro is None else self._loop.subscription(
            Imu, "imu", self._on_imu, SENSOR_IN_QOS, raw=True)
        self._pose_inputs = PoseInputs(node, self._pipeline.reset, self._pipeline, self._throttle)
        # Steady time: with use_sim_time and no /clock a ROS-time timer would never fire,
        # and a missing clock is one of the mistakes this warning is for.
        self._input_timer = node.create_timer(
            NO_INPUT_WARN_S, self._check_input, clock=Clock(clock_type=ClockType.STEADY_TIME)
        )
        self._started = time.monotonic()
        self._last_rx: float | None = None
        self._rate = RateMeter(start=self._started)
        self._reporter = Reporter(odometry_report)
        self._diagnostics = DiagnosticsPublisher(node, "odometry", self._diagnose)
        # With the gyro (read-only) the online estimate may run: monitor at any time.
        self._estimate_pub = None if settings.gyro is None else GeometryEstimatePublisher(
            node, lambda: self._pipeline.stats.online)
        if online_warning(settings):
            node.get_logger().warning(online_warning(settings))
        ref = None if settings.gyro is None or settings.online is None else (
            settings.online.reference)  # read-only: for the node's whole life or not
        self._ref_sub = None if ref is None else ReferenceSubscription(
            node, ref, self._pipeline, self._throttle, settings.base_frame_id)
        g = settings.geometry
        node.get_logger().info(
            f"wheel odometry: r_left={g.left_radius:.6g} m, r_right={g.right_radius:.6g} m, "
            f"b={g.separation:.6g} m, {frames_text(settings)}, "
            f"joints {list(settings.encoders.left_wheel_names)} / "
            f"{list(settings.encoders.right_wheel_names)}"
        )

    def destroy(self) -> None:
        """Remove every endpoint, timer and parameter check from the node; the pose goes."""
        node = self._node
        self._guard.close()
        self._diagnostics.destroy()
        if self._estimate_pub is not None:
            self._estimate_pub.destroy()
        node.destroy_timer(self._input_timer)
        self._pose_inputs.destroy()
        node.destroy_subscription(self._sub)
        if self._imu_sub is not None:
            node.destroy_subscription(self._imu_sub)
        if self._ref_sub is not None:
            self._ref_sub.destroy()
        self._output.destroy()
        self._loop.destroy()

    def _build(self, values: dict[str, ParamValue]) -> OdometrySettings:
        return odometry_settings(values, self._node.get_namespace())

    def _apply(self, settings: OdometrySettings) -> None:
        """Install accepted runtime changes; the pose carries on without a jump."""
        self._output.configure(settings)
        self._pipeline.reconfigure(settings)
        self._node.get_logger().info("parameters updated")

    def _check_input(self) -> None:
        """Say once if nothing arrived: the topic name (namespace, remap) is the usual cause."""
        self._input_timer.cancel()
        if self._pipeline.stats.readings == 0:
            topic = self._sub.topic_name
            self._node.get_logger().warning(
                f"no JointState received on {topic} in {NO_INPUT_WARN_S:g} s "
                f"({self._node.count_publishers(topic)} publisher(s) on it): check the driver's "
                "topic, this node's namespace and remaps"
            )

    def _diagnose(self) -> Report:
        """The /diagnostics status: input rate and age, and what the pipeline dropped."""
        now = time.monotonic()
        stats = self._pipeline.stats
        return self._reporter(ReadingHealth(
            uptime_s=now - self._started,
            reading_rate_hz=self._rate.rate(now),
            since_last_reading_s=None if self._last_rx is None else now - self._last_rx,
            dropped=dict(stats.dropped),
            reanchors=stats.reanchors,
            causes=dict(stats.causes),
            gap_reanchors=stats.gap_reanchors,
            gaps_integrated=stats.gaps_integrated,
            time_resets=stats.time_resets,
            velocity_fallback=stats.velocity_fallback,
            gyro=stats.gyro,
            online=stats.online,
        ))

    def _on_imu(self, raw: bytes) -> None:
        """One gyro sample to the pipeline; a refused one is named (throttled per reason)."""
        got = self._decode(raw, decode_imu, IMU_FALLBACK)
        if got is None:
            return
        sec, nanosec, wx, wy, wz, cov = got
        clock = self._node.get_clock()  # the receive time, as for joint_states
        code = self._pipeline.feed_imu(
            sec * 1_000_000_000 + nanosec, wx, wy, wz, receive_ns=clock.now().nanoseconds,
            check_clock=not getattr(clock, "ros_time_is_active", False), covariance=cov)
        if code:
            self._throttle.warning(f"imu_{code}", f"imu sample dropped [{code}]: stamp "
                                   f"{sec}.{nanosec:09d}, angular_velocity "
                                   f"({wx:.6g}, {wy:.6g}, {wz:.6g}) rad/s")

    def _on_joint_state(self, raw: bytes) -> None:
        self._last_rx = t = time.monotonic()
        self._rate.add(t)
        msg = self._decode(raw, self._decoder.decode, JOINT_STATE_FALLBACK)
        if msg is None:
            return
        clock = self._node.get_clock()
        # The receive time on this node's clock: the stamp with stamp_source receive_time,
        # and what a driver's own clock is checked against (not on simulated time, whose
        # clock the drivers of a simulation stamp with anyway).
        outcome = self._pipeline.feed(
            msg.sec * 1_000_000_000 + msg.nanosec, msg.name, msg.position, msg.velocity,
            receive_ns=clock.now().nanoseconds,
            check_clock=not getattr(clock, "ros_time_is_active", False))
        self._report(outcome)
        if outcome.publish:
            self._publish(outcome.stamp_ns)

    def _decode(self, raw: bytes, fast: Callable[[bytes], T | None],
                fallback: Fallback[T]) -> T | None:
        """A message's fields, or None (with a throttled warning) if unreadable.

        ``fast`` decodes the bytes (:mod:`diffdrive_odom.wire.cdr`); rclpy's own
        deserialisation takes what it leaves (big-endian senders).
        """
        try:
            if (got := fast(raw)) is not None:
                return got
        except ValueError:
            pass
        try:
            msg = deserialize_message(raw, fallback.msg_type)
        except Exception as exc:  # whatever rclpy raises for bytes it cannot read
            self._throttle.warning(fallback.key, f"{fallback.topic} message dropped: its "
                                   f"{len(raw)} bytes are not {fallback.a_type} ({exc})")
            return None
        return fallback.fields(msg)

    def _report(self, outcome: Outcome) -> None:
        verdict = outcome.verdict
        if outcome.note == IMU_SILENT:  # says it once per switch, as the WARN in diagnostics
            self._node.get_logger().warning(outcome.note)
        elif outcome.note:
            self._throttle.info("input_mode", outcome.note)
        if outcome.warning:  # said once by the pipeline
            self._node.get_logger().warning(outcome.warning)
        if verdict.status is Status.TIME_RESET:
            self._node.get_logger().warning(verdict.reason)
        elif verdict.warning:
            self._throttle.warning(verdict.code, f"joint_states reading {verdict.warning} "
                                   f"[{verdict.code}]: {verdict.reason}")

    def _publish(self, stamp_ns: int) -> None:
        out = pipeline_publication(self._pipeline)  # replay publishes by the same rule
        # The pose and twist are always finite (the estimator keeps no non-finite state),
        # but a propagated covariance can overflow (an absurd geometry such as a 1e-300 m
        # wheel_separation, which the parameter checks accept): then nothing is published
        # and the refusal is logged, throttled.
        if isinstance(out, Refusal):
            self._throttle.warning(out.code, out.reason)
            return
        # Propagated: the pipeline's covariance, every message; else the parameters'.
        self._output.publish(stamp_ns, out,
                             static_covariance=self._pipeline.estimator.uncertainty is None)


@dataclass(frozen=True)
class Fallback(Generic[T]):
    """rclpy's deserialisation of what the byte decoder leaves, and how a failure is named."""

    msg_type: type[Any]
    fields: Callable[[Any], T]  # the message's fields, as the byte decoder gives them
    key: str  # the throttle's key for "not readable"
    topic: str
    a_type: str  # "a JointState": what the bytes are not


def _joint_fields(msg: JointState) -> JointArrays:
    stamp = msg.header.stamp
    return JointArrays(stamp.sec, stamp.nanosec, tuple(msg.name), tuple(msg.position),
                       tuple(msg.velocity))


def _imu_fields(msg: Imu) -> ImuFields:
    w = msg.angular_velocity
    return (msg.header.stamp.sec, msg.header.stamp.nanosec, w.x, w.y, w.z,
            tuple(float(c) for c in msg.angular_velocity_covariance))


JOINT_STATE_FALLBACK = Fallback(msg_type=JointState, fields=_joint_fields, key="undecodable",
                                topic="joint_states", a_type="a JointState")
IMU_FALLBACK = Fallback(msg_type=Imu, fields=_imu_fields, key="imu_undecodable", topic="imu",
                        a_type="an Imu")


def odometry_endpoints(node: Node, values: dict[str, ParamValue]
                       ) -> OdometryEndpoints | OpenLoopEndpoints:
    """The endpoints the parameters ask for: from the encoders, or open loop (read-only)."""
    if values.get("open_loop") is True:
        from diffdrive_odom.ros.open_loop import OpenLoopEndpoints

        return OpenLoopEndpoints(node, values)
    return OdometryEndpoints(node, values)


class OdometryNode(Node):
    """Publishes wheel odometry computed from encoder readings, from its start."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(NODE_NAME, **kwargs)
        self.odometry = odometry_endpoints(self, declare(self, ODOMETRY_PARAMS))


def main(args: list[str] | None = None) -> int:
    """Console script / ``ros2 run diffdrive_odom odometry_node``."""
    return run(OdometryNode, args)


if __name__ == "__main__":
    raise SystemExit(main())
