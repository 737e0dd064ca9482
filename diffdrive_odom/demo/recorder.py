"""The demo's own node: records every topic raw into the bag and sends the squares' paths."""

from __future__ import annotations

import time
from collections.abc import Mapping, Sequence
from contextlib import ExitStack
from pathlib import Path
from types import TracebackType

import rclpy
from geometry_msgs.msg import PoseStamped
from nav_msgs.msg import Odometry
from nav_msgs.msg import Path as PathMsg
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.serialization import deserialize_message
from rclpy.signals import SignalHandlerOptions
from rosgraph_msgs.msg import Clock as ClockMsg
from sensor_msgs.msg import Imu, JointState
from std_msgs.msg import Bool, Float64

from diffdrive_odom.core.motion.paths import Point
from diffdrive_odom.ros.messages import message_class
from diffdrive_odom.ros.qos import DONE_QOS, RELIABLE_OUT_QOS, qos
from diffdrive_odom.tools.bags import bagwriter
from diffdrive_odom.tools.replaying.sinks import PoseLog
from diffdrive_odom.wire.conversions import reference_pose, stamp_to_ns

from . import interrupts
from .report import ImuReading, JointSample, Recording, Square
from .settings import BAG_TOPICS, FOLLOWER

RECORD_QOS = qos(1000, reliable=True)
LATEST_QOS = qos(1, reliable=False)  # only the newest /clock matters


class Recorder:
    """The demo's own node: records every topic into the bag and sends the paths.

    Messages are taken raw (the CDR bytes DDS delivered) and written to the bag as
    they are, so the bag holds exactly what the nodes sent; the few needed for the
    evaluation are decoded as well. A context manager: ``__enter__`` builds the ROS
    context, node and bag writer on an ExitStack, so a failure half-way undoes what
    was built, and ``__exit__`` closes them all.
    """

    def __init__(self, domain_id: int, bag_path: Path | None,
                 topics: Mapping[str, str] = BAG_TOPICS) -> None:
        self.domain_id, self.bag_path, self.topics = domain_id, bag_path, dict(topics)
        self.context = Context()
        self.writer: bagwriter.BagWriter | None = None
        self.now_ns: int | None = None
        self._log_ns = 0  # the last log time written: each message's is later
        self.odom, self.truth = PoseLog(), PoseLog()
        self.joint_states: list[JointSample] = []
        self.imu: list[ImuReading] = []
        self.counts: dict[str, int] = dict.fromkeys(self.topics, 0)
        self.done_true = self.done_false = 0
        self.cross_track_max = 0.0
        self._stack = ExitStack()

    def __enter__(self) -> Recorder:
        with ExitStack() as stack:
            # No rclpy signal handlers: Ctrl-C stays a KeyboardInterrupt, so the caller
            # stops the child processes.
            rclpy.init(context=self.context, domain_id=self.domain_id,
                       signal_handler_options=SignalHandlerOptions.NO)
            stack.callback(rclpy.try_shutdown, context=self.context)
            self.node = Node("diffdrive_odom_demo", context=self.context)
            stack.callback(self.node.destroy_node)
            self.executor = SingleThreadedExecutor(context=self.context)
            stack.callback(self.executor.shutdown)
            self.executor.add_node(self.node)
            if self.bag_path is not None:
                self.writer = stack.enter_context(bagwriter.BagWriter(self.bag_path))
            for topic, type_name in self.topics.items():
                cls = message_class(type_name)
                if self.writer is not None:
                    self.writer.add_topic(topic, type_name)
                self.node.create_subscription(
                    cls, topic, lambda raw, t=topic: self._on_raw(t, raw), RECORD_QOS,
                    raw=True)
            self.node.create_subscription(ClockMsg, "/clock", self._on_clock, LATEST_QOS)
            self.node.create_subscription(Bool, f"/{FOLLOWER}/done", self._on_done, DONE_QOS)
            self.path_pub = self.node.create_publisher(
                PathMsg, "/path", RELIABLE_OUT_QOS)
            self._stack = stack.pop_all()
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self._stack.close()
        self.writer = None

    def spin_once(self, timeout: float) -> None:
        """Handle what arrived (or wait up to ``timeout`` seconds).

        A Ctrl-C meanwhile is raised once the spin is over (:mod:`.interrupts`).
        """
        with interrupts.deferred():
            self.executor.spin_once(timeout_sec=timeout)

    def _on_clock(self, msg: ClockMsg) -> None:
        self.now_ns = stamp_to_ns(msg.clock)

    def _on_done(self, msg: Bool) -> None:
        if msg.data:
            self.done_true += 1
        else:
            self.done_false += 1

    def _on_raw(self, topic: str, raw: bytes) -> None:
        # The log time is the simulated clock (wall time before its first /clock), one
        # nanosecond after the last at least: a bag is read in log-time order, and
        # messages heard before /clock got the wall time, later than the simulated time
        # of those heard next (the sim starts its clock at the wall time and runs it
        # faster), so its first JointState was read back after three later ones, 60 ms
        # back in stamp. Arrival order is each publisher's order, so it is kept.
        clock = self.now_ns if self.now_ns is not None else time.time_ns()
        log_ns = self._log_ns = max(clock, self._log_ns + 1)
        self.counts[topic] += 1
        if self.writer is not None:
            self.writer.write_cdr(topic, log_ns, bytes(raw))
        if topic == "/joint_states":
            js = deserialize_message(raw, JointState)
            self.joint_states.append(JointSample(
                stamp_to_ns(js.header.stamp), tuple(js.name),
                tuple(js.position), tuple(js.velocity)))
        elif topic == "/imu":
            imu = deserialize_message(raw, Imu)
            w = imu.angular_velocity
            self.imu.append(ImuReading(stamp_to_ns(imu.header.stamp), w.x, w.y, w.z))
        elif topic in ("/odom", "/ground_truth/odom"):
            msg = deserialize_message(raw, Odometry)
            series = self.odom if topic == "/odom" else self.truth
            series.add(*reference_pose(msg))
        elif topic == f"/{FOLLOWER}/cross_track_error":
            e = float(deserialize_message(raw, Float64).data)
            self.cross_track_max = max(self.cross_track_max, abs(e))

    def send_path(self, points: Sequence[Point]) -> None:
        """Publish a path (odom frame) for the follower."""
        msg = PathMsg()
        msg.header.frame_id = "odom"
        for x, y in points:
            pose = PoseStamped()
            pose.header.frame_id = "odom"
            pose.pose.position.x, pose.pose.position.y = float(x), float(y)
            pose.pose.orientation.w = 1.0
            msg.poses.append(pose)
        self.path_pub.publish(msg)

    def _has(self, topic: str, node: str, publisher: bool) -> bool:
        infos = (self.node.get_publishers_info_by_topic(topic) if publisher
                 else self.node.get_subscriptions_info_by_topic(topic))
        return any(i.node_name == node for i in infos)

    def ready(self) -> bool:
        """Every link of the loop is up: clock, encoders, odometry, follower, cmd_vel -> sim."""
        c = self.counts
        return (self.now_ns is not None and self.done_false > 0
                and all(c[t] > 0 for t in ("/joint_states", "/odom", "/ground_truth/odom",
                                           "/tf"))
                and self._has("/path", FOLLOWER, publisher=False)
                and self._has("/odom", FOLLOWER, publisher=False)
                and self._has("/cmd_vel", "cmd_vel_node", publisher=False)
                and self._has("/wheel_commands", "sim_node", publisher=False)
                and self._has("/wheel_commands", "cmd_vel_node", publisher=True))

    def status(self) -> str:
        """Message counts so far, for error messages."""
        counts = ", ".join(f"{t}: {n}" for t, n in self.counts.items())
        clock = "no /clock yet" if self.now_ns is None else "/clock running"
        return f"{clock}; done {self.done_true}x; {counts}"

    def recording(self, squares: Sequence[Square]) -> Recording:
        """What was heard, for :mod:`.report`."""
        return Recording(tuple(self.joint_states), self.odom.trajectory(),
                         self.truth.trajectory(), tuple(squares), self.cross_track_max,
                         tuple(self.imu))
