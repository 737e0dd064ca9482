"""The demo's resources are released when a constructor fails (real rclpy, real processes)."""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from pathlib import Path

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


def test_the_recorder_records_the_gyro_into_the_bag_and_the_recording(tmp_path: Path) -> None:
    """An Imu on /imu (the sim's gyro) is written raw and kept for the gyro-aided replay."""
    from rclpy.node import Node
    from sensor_msgs.msg import Imu

    from diffdrive_odom.tools.bags import bagio

    bag = tmp_path / "bag"
    with Recorder(DOMAIN, bag) as rec:
        pub_node = Node("imu_source", context=rec.context)
        pub = pub_node.create_publisher(Imu, "/imu", 10)
        rec.executor.add_node(pub_node)
        msg = Imu()
        msg.header.stamp.sec, msg.header.stamp.nanosec = 12, 500
        msg.angular_velocity.x, msg.angular_velocity.z = 0.25, -0.125
        deadline = time.monotonic() + 20.0
        while not rec.imu and time.monotonic() < deadline:
            pub.publish(msg)  # again until the recorder's subscription is matched
            rec.spin_once(0.05)
        recording = rec.recording([])
    assert recording.imu[0] == (12_000_000_500, 0.25, 0.0, -0.125)
    with bagio.open_bag(bag) as reader:
        assert bagio.count_messages(reader, "/imu") == rec.counts["/imu"] >= 1


def test_joint_states_read_back_in_stamp_order_when_the_sim_clock_starts_behind(
        tmp_path: Path) -> None:
    """The sim's clock starts at the wall time and runs faster than it; the recorder heard
    the sim's first JointState before any /clock and logged it at the wall time, later
    than the simulated time of the next ones: read back in log order (as play, eval and
    the MCAP index do), it came after them, 60 ms back in stamp (the trial's bag; a live
    node fed by play drops it as stale_stamp). Here the simulated clock is 2 s behind
    the wall when the recorder first hears it."""
    from rclpy.node import Node
    from rosgraph_msgs.msg import Clock
    from sensor_msgs.msg import JointState

    from diffdrive_odom.tools.bags import bagio
    from diffdrive_odom.wire.conversions import ns_to_stamp, stamp_to_ns

    step, start = 20_000_000, time.time_ns() - 2_000_000_000
    bag = tmp_path / "bag"
    with Recorder(DOMAIN, bag) as rec:
        sim = Node("sim_like", context=rec.context)
        joints = sim.create_publisher(JointState, "/joint_states", 10)
        clock = sim.create_publisher(Clock, "/clock", 10)
        rec.executor.add_node(sim)

        def spin_until(done: Callable[[], bool]) -> None:
            deadline = time.monotonic() + 20.0
            while not done() and time.monotonic() < deadline:
                rec.spin_once(0.05)
            assert done()

        def send(k: int) -> None:
            msg = JointState(name=["left_wheel_joint", "right_wheel_joint"],
                             position=[0.01 * k, 0.01 * k])
            ns_to_stamp(start + k * step, msg.header.stamp)
            joints.publish(msg)
            spin_until(lambda: rec.counts["/joint_states"] == k + 1)

        spin_until(lambda: joints.get_subscription_count() > 0
                   and clock.get_subscription_count() > 0)
        send(0)  # heard before any /clock: logged at the wall time
        assert rec.now_ns is None
        for k in range(1, 6):
            tick = Clock()
            ns_to_stamp(start + k * step, tick.clock)
            clock.publish(tick)
            at = start + k * step
            spin_until(lambda: rec.now_ns == at)  # noqa: B023 (used at once, in the loop)
            send(k)
    with bagio.open_bag(bag) as reader:
        conns = [c for c in reader.connections if c.topic == "/joint_states"]
        stamps = [stamp_to_ns(reader.deserialize(raw, c.msgtype).header.stamp)
                  for c, _, raw in reader.messages(connections=conns)]
    assert stamps == [start + k * step for k in range(6)]
