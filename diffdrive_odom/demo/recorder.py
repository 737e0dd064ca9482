"""The demo's own node: in the loop, it records every topic raw into the bag and drives.

It takes part in the lockstep (:mod:`diffdrive_odom.ros.lockstep`): the sim waits for its
answers too, so everything a step sends reaches it before the next ``/clock``. At each
``/clock`` what it heard since the last one is the last step's, all of it: it is written
into the bag logged at the last ``/clock``'s simulated time (when all of it was sent), in
a fixed order (by topic, as the loop sends them; each topic in its own order) and one
nanosecond apart, so log times are simulated time and the bag is the same, byte for byte,
on every run. The driver (``on_step``) acts first (sends a square's path) and the loop
has its answer; the writing comes after, while the loop handles the next readings.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from contextlib import ExitStack
from functools import partial
from pathlib import Path
from types import TracebackType

import rclpy
from geometry_msgs.msg import PoseStamped
from nav_msgs.msg import Odometry
from nav_msgs.msg import Path as PathMsg
from rclpy.context import Context
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.serialization import deserialize_message
from rclpy.signals import SignalHandlerOptions
from sensor_msgs.msg import Imu, JointState
from std_msgs.msg import Bool, Float64

from diffdrive_odom.core.motion.paths import Point
from diffdrive_odom.ros.lockstep import Participant, settle
from diffdrive_odom.ros.messages import message_class
from diffdrive_odom.ros.qos import DONE_QOS, RELIABLE_OUT_QOS, qos
from diffdrive_odom.ros.runtime import make_executor
from diffdrive_odom.tools.bags import bagwriter
from diffdrive_odom.tools.replaying.sinks import PoseLog
from diffdrive_odom.wire.conversions import reference_pose, stamp_to_ns

from . import interrupts
from .report import ImuReading, JointSample, Recording, Square
from .settings import BAG_TOPICS, FOLLOWER

NODE_NAME = "diffdrive_odom_demo"
RECORD_QOS = qos(1000, reliable=True)
# The order a step's messages are written in: as the loop sends them (the path at the
# step's /clock; the sim's readings, the odometry, the follower's answer).
RECORD_ORDER = ("/path", "/imu", "/joint_states", "/ground_truth/odom", "/odom", "/tf",
                "/cmd_vel", f"/{FOLLOWER}/cross_track_error")


class Recorder:
    """The demo's own node: records every topic into the bag and sends the paths.

    Messages are taken raw (the CDR bytes DDS delivered) and written to the bag as
    they are, so the bag holds exactly what the nodes sent; the few needed for the
    evaluation are decoded as well. A context manager: ``__enter__`` builds the ROS
    context, node and bag writer on an ExitStack, so a failure half-way undoes what
    was built, and ``__exit__`` closes them all. ``on_step(now_ns)`` is called at each
    ``/clock`` once what came before it is recorded.
    """

    def __init__(self, domain_id: int, bag_path: Path | None,
                 topics: Mapping[str, str] = BAG_TOPICS,
                 on_step: Callable[[int], None] | None = None) -> None:
        self.domain_id, self.bag_path, self.topics = domain_id, bag_path, dict(topics)
        self.on_step = on_step
        self.context = Context()
        self.writer: bagwriter.BagWriter | None = None
        self.now_ns: int | None = None  # the last /clock: the simulated time now
        self._log_ns = 0  # the last log time written: each message's is later
        order = [t for t in RECORD_ORDER if t in self.topics]
        order += [t for t in self.topics if t not in order]
        self._rank = {t: i for i, t in enumerate(order)}
        self._heard: list[tuple[int, int, str, bytes]] = []  # since the last /clock
        self._unwritten: list[tuple[int, list[tuple[int, int, str, bytes]]]] = []  # steps
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
            self.node = Node(NODE_NAME, context=self.context, parameter_overrides=[
                Parameter("use_sim_time", value=True)])
            stack.callback(self.node.destroy_node)
            self.executor, _ = make_executor(context=self.context)
            stack.callback(self.executor.shutdown)
            self.executor.add_node(self.node)
            if self.bag_path is not None:
                self.writer = stack.enter_context(bagwriter.BagWriter(self.bag_path))
            self.loop = Participant(self.node)
            for topic, type_name in self.topics.items():
                cls = message_class(type_name)
                if self.writer is not None:
                    self.writer.add_topic(topic, type_name)
                self.loop.subscription(cls, topic, partial(self._hear, topic), RECORD_QOS,
                                       raw=True)
            self.loop.subscription(Bool, f"/{FOLLOWER}/done", self._on_done, DONE_QOS)
            self._publish_path = self.loop.publish(self.node.create_publisher(
                PathMsg, "/path", RELIABLE_OUT_QOS))
            self.loop.on_clock.append(self._on_clock)
            self._stack = stack.pop_all()
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        if exc_type is None:
            self.write()
        self._stack.close()
        self.writer = None

    def spin_once(self, timeout: float) -> None:
        """Handle what arrived (or wait up to ``timeout`` seconds).

        A Ctrl-C meanwhile is raised once the spin is over (:mod:`.interrupts`).
        """
        with interrupts.deferred():
            self.executor.spin_once(timeout_sec=timeout)
            settle(self.executor)  # answers the loop
            self.write()

    def _on_clock(self, now_ns: int) -> None:
        """A step's /clock: what came since the last one is that step's; the driver acts."""
        if self.now_ns is not None and self._heard:
            self._unwritten.append((self.now_ns, self._heard))
            self._heard = []
        self.now_ns = now_ns
        if self.on_step is not None:
            self.on_step(now_ns)

    def _on_done(self, msg: Bool) -> None:
        if msg.data:
            self.done_true += 1
        else:
            self.done_false += 1

    def _hear(self, topic: str, raw: bytes) -> None:
        self._heard.append((self._rank[topic], len(self._heard), topic, bytes(raw)))

    def write(self) -> None:
        """The steps heard in full, into the bag at their times (and decoded)."""
        unwritten, self._unwritten = self._unwritten, []
        for log_ns, heard in unwritten:
            for _, _, topic, raw in sorted(heard):
                log_ns = self._log_ns = max(log_ns, self._log_ns + 1)
                self.counts[topic] += 1
                if self.writer is not None:
                    self.writer.write_cdr(topic, log_ns, raw)
                self._decode(topic, raw)

    def _decode(self, topic: str, raw: bytes) -> None:
        """Keep what the evaluation reads of a recorded message."""
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
        self._publish_path(msg)

    def status(self) -> str:
        """Message counts so far, for error messages."""
        counts = ", ".join(f"{t}: {n}" for t, n in self.counts.items())
        clock = ("no /clock yet (the sim waits for every node of the loop)"
                 if self.now_ns is None else f"/clock at {self.now_ns * 1e-9:.3f} s")
        return f"{clock}; done {self.done_true}x; {counts}"

    def recording(self, squares: Sequence[Square]) -> Recording:
        """What was recorded (the steps heard in full), for :mod:`.report`."""
        self.write()
        return Recording(tuple(self.joint_states), self.odom.trajectory(),
                         self.truth.trajectory(), tuple(squares), self.cross_track_max,
                         tuple(self.imu))
