"""The demo's resources are released when a constructor fails (real rclpy, real processes)."""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from diffdrive_odom.demo.children import Children
from diffdrive_odom.demo.recorder import Recorder
from diffdrive_odom.demo.settings import DemoError

pytestmark = [pytest.mark.dds, pytest.mark.process]

DOMAIN = int(os.environ.get("ROS_DOMAIN_ID", "0"))


def test_a_recorder_that_fails_half_way_shuts_its_context_and_bag(tmp_path: Path) -> None:
    bag = tmp_path / "bag"
    rec = Recorder(DOMAIN, bag, topics={"/odom": "nav_msgs/msg/Odometry",
                                        "/x": "no_such_msgs/msg/Nope"})
    with pytest.raises(ModuleNotFoundError):
        rec.__enter__()
    assert not rec.context.ok()  # rclpy.init was undone
    assert (bag / "metadata.yaml").exists()  # the writer was closed (rosbag2 writes it then)


def test_a_recorder_used_as_a_context_manager_shuts_down(tmp_path: Path) -> None:
    with Recorder(DOMAIN, None) as rec:
        assert rec.context.ok()
        rec.spin_once(0.01)
    assert not rec.context.ok()


def test_a_child_that_cannot_start_leaves_no_child_behind(tmp_path: Path) -> None:
    env = dict(os.environ, ROS_DOMAIN_ID=str(DOMAIN))
    with pytest.raises(DemoError, match="no_such_node"), Children(env, tmp_path) as children:
        first = children.start("sim_node", [])
        children.start("no_such_node", [])
    assert first.proc.poll() is not None  # stopped by the with block
    with pytest.raises(ProcessLookupError):
        os.kill(first.proc.pid, 0)


class Feed:
    """A publisher of the recorder's topics in its own context, and the recorder's spin."""

    def __init__(self, rec: Recorder) -> None:
        from rclpy.node import Node
        from rosgraph_msgs.msg import Clock

        from diffdrive_odom.demo.settings import BAG_TOPICS
        from diffdrive_odom.ros.messages import message_class

        self.rec = rec
        self.node = Node("feed", context=rec.context)
        self.pubs = {t: self.node.create_publisher(message_class(ty), t, 10)
                     for t, ty in BAG_TOPICS.items()}
        self.clock_pub = self.node.create_publisher(Clock, "/clock", 10)
        rec.executor.add_node(self.node)
        self.until(lambda: all(p.get_subscription_count() for p in self.pubs.values())
                   and self.clock_pub.get_subscription_count() > 0)

    def until(self, done: Callable[[], bool]) -> None:
        deadline = time.monotonic() + 20.0
        while not done() and time.monotonic() < deadline:
            self.rec.spin_once(0.05)
        assert done()

    def clock(self, ns: int) -> None:
        from rosgraph_msgs.msg import Clock

        from diffdrive_odom.wire.conversions import ns_to_stamp

        tick = Clock()
        ns_to_stamp(ns, tick.clock)
        self.clock_pub.publish(tick)
        self.until(lambda: self.rec.now_ns == ns)

    def send(self, topic: str, msg: Any) -> None:
        took = self.rec.loop.tally.took
        n = took[topic]
        self.pubs[topic].publish(msg)
        self.until(lambda: took[topic] == n + 1)


def test_the_recorder_records_the_gyro_into_the_bag_and_the_recording(tmp_path: Path) -> None:
    """An Imu on /imu (the sim's gyro, a sample of the step that ends at this /clock) is
    written raw and kept for the gyro-aided replay, once the next /clock says its step is
    over."""
    from sensor_msgs.msg import Imu

    from diffdrive_odom.tools.bags import bagio

    bag = tmp_path / "bag"
    with Recorder(DOMAIN, bag) as rec:
        feed = Feed(rec)
        feed.clock(12_000_000_000)
        msg = Imu()
        msg.header.stamp.sec, msg.header.stamp.nanosec = 11, 999_999_500
        msg.angular_velocity.x, msg.angular_velocity.z = 0.25, -0.125
        feed.send("/imu", msg)
        assert not rec.imu  # not before its step is over
        feed.clock(12_020_000_000)
        recording = rec.recording([])
    assert recording.imu == ((11_999_999_500, 0.25, 0.0, -0.125),)
    with bagio.open_bag(bag) as reader:
        assert bagio.count_messages(reader, "/imu") == rec.counts["/imu"] == 1


def test_a_message_stamped_after_the_recorders_clock_waits_for_that_clock(
        tmp_path: Path) -> None:
    """The sim sends a step's /clock before its readings, but two writers' messages may
    arrive in either order: a reading stamped after the last /clock taken is held (not
    taken, not answered) until the /clock of its time comes, then taken as that step's."""
    from sensor_msgs.msg import Imu

    with Recorder(DOMAIN, tmp_path / "bag") as rec:
        feed = Feed(rec)
        feed.clock(12_000_000_000)
        msg = Imu()
        msg.header.stamp.sec, msg.header.stamp.nanosec = 12, 20_000_000
        took = rec.loop.tally.took
        feed.pubs["/imu"].publish(msg)
        deadline = time.monotonic() + 2.0
        while time.monotonic() < deadline:
            rec.spin_once(0.05)
        assert took["/imu"] == 0
        feed.clock(12_020_000_000)
        feed.until(lambda: took["/imu"] == 1)
        feed.clock(12_040_000_000)
        recording = rec.recording([])
    assert [s[0] for s in recording.imu] == [12_020_000_000]


def step_messages(k: int) -> dict[str, Any]:
    """What a step of the loop sends the recorder, stamped at its time."""
    from nav_msgs.msg import Odometry
    from sensor_msgs.msg import Imu, JointState

    from diffdrive_odom.wire.conversions import ns_to_stamp

    at = START + k * STEP
    joints = JointState(name=["left_wheel_joint", "right_wheel_joint"],
                        position=[0.01 * k, 0.01 * k])
    imu, odom, truth = Imu(), Odometry(), Odometry()
    for msg in (joints, imu, odom, truth):
        ns_to_stamp(at, msg.header.stamp)
    odom.pose.pose.position.x = truth.pose.pose.position.x = 0.001 * k
    return {"/joint_states": joints, "/imu": imu, "/odom": odom, "/ground_truth/odom": truth}


START, STEP = 1_000_000_000, 20_000_000


def test_a_step_is_written_at_its_time_in_one_order_whatever_order_it_arrives_in(
        tmp_path: Path) -> None:
    """Within a step the recorder hears its topics in whatever order the processes run
    (the sim's readings, the odometry's answer); it writes them at the step's simulated
    time, in the loop's order, one nanosecond apart: the same bag from either order,
    byte for byte. It used to log each at the last /clock it had heard: a JointState
    heard before the first /clock was logged at the wall time and read back after three
    later ones, and a replay once found the IMU stamps 7.2 s ahead of their log times."""
    from diffdrive_odom.tools.bags import bagio

    orders = (["/joint_states", "/imu", "/odom", "/ground_truth/odom"],
              ["/odom", "/ground_truth/odom", "/imu", "/joint_states"])
    bags = []
    for i, order in enumerate(orders):
        bag = tmp_path / f"run{i}" / "bag"
        bag.parent.mkdir()
        with Recorder(DOMAIN, bag) as rec:
            feed = Feed(rec)
            for k in range(3):
                feed.clock(START + k * STEP)
                msgs = step_messages(k)
                for topic in order if k % 2 == 0 else reversed(order):
                    feed.send(topic, msgs[topic])
            feed.clock(START + 3 * STEP)
        bags.append(bag)
    files = [{p.name: p.read_bytes() for p in bag.iterdir()} for bag in bags]
    assert files[0] == files[1]
    with bagio.open_bag(bags[0]) as reader:
        logged = [(c.topic, log) for c, log, _ in reader.messages()]
    want = [(topic, START + k * STEP + i) for k in range(3)
            for i, topic in enumerate(["/imu", "/joint_states", "/ground_truth/odom", "/odom"])]
    assert logged == want
