"""sim_node over real DDS: encoders (wrap, sign flip) undone by odometry_node, time, formats.

Each test starts the console scripts as processes and talks to them from a
private-Context peer node; expected values come from the kinematics' closed forms
and the encoder's resolution.
"""

from __future__ import annotations

import itertools
import math
import subprocess
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import pytest
from nav_msgs.msg import Odometry
from rcl_interfaces.msg import ParameterType, ParameterValue
from rclpy.node import Node
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray

from diffdrive_odom.ros.sim_node import SimNode

from rosutil import (
    assert_refused_in_process,
    assert_refuses_to_start,
    node_process,
    ns_of,
    ros_test_node,
    set_parameter,
    spin_for,
    spin_until,
)

pytestmark = [pytest.mark.dds, pytest.mark.process]

R, B = 0.05, 0.30  # nominal = true geometry in these tests


def yaw(q: Any) -> float:
    return 2.0 * math.atan2(q.z, q.w)


@dataclass
class Sink:
    joints: list[JointState] = field(default_factory=list)
    truth: list[Odometry] = field(default_factory=list)
    odom: dict[str, list[Odometry]] = field(default_factory=dict)
    clock: list[int] = field(default_factory=list)


def listen(node: Node, odom_topics: tuple[str, ...] = ()) -> Sink:
    sink = Sink()
    node.create_subscription(JointState, "/joint_states", sink.joints.append, 200)
    node.create_subscription(Odometry, "/ground_truth/odom", sink.truth.append, 200)
    for topic in odom_topics:
        sink.odom[topic] = []
        node.create_subscription(Odometry, topic, sink.odom[topic].append, 200)
    node.create_subscription(Clock, "/clock", lambda m: sink.clock.append(ns_of(m.clock)), 200)
    return sink


def output(proc: subprocess.Popen[str]) -> str:
    if proc.poll() is None:
        return "(still running)"
    return proc.stdout.read() if proc.stdout else ""


def rates(v: float, w: float, left_sign: int = 1, right_sign: int = 1) -> list[float]:
    """Inverse kinematics by hand: joint rates of each side, with the joint signs."""
    return [left_sign * (v - w * B / 2) / R, right_sign * (v + w * B / 2) / R]


def drive_until(ex: Any, pub: Any, values: list[float], done: Callable[[], Any],
                timeout: float = 20.0) -> bool:
    """Command ``values`` every 20 ms (at least once) until ``done()`` or ``timeout`` s.

    The command is held until its effect is seen, however long this test or the sim
    stalls meanwhile (a stall over command_timeout only pauses the motion).
    """
    deadline = time.monotonic() + timeout
    while True:
        pub.publish(Float64MultiArray(data=values))
        if spin_until(ex, done, 0.02):
            return True
        if time.monotonic() > deadline:
            return False


def drive(ex: Any, pub: Any, values: list[float], seconds: float) -> None:
    """Command ``values`` every 20 ms for ``seconds``."""
    drive_until(ex, pub, values, lambda: False, seconds)


def standing(m: Odometry) -> bool:
    return bool(m.twist.twist.linear.x == 0.0 and m.twist.twist.angular.z == 0.0)


def test_wrapping_counter_and_flipped_joint_are_undone_by_the_odometry_parameters() -> None:
    tpr, bits, start = 1000.0, 12, 4090.0
    encoder = ["-p", f"ticks_per_revolution:={tpr}", "-p", f"encoder_counter_bits:={bits}",
               "-p", f"wheel_radius:={R}", "-p", f"wheel_separation:={B}",
               "-p", "right_wheel_sign:=-1"]
    sim_args = ["--ros-args", *encoder, "-p", f"encoder_initial_count:={start}",
                "-p", "command_timeout:=0.3"]
    odom_args = ["--ros-args", *encoder, "-p", "enable_odom_tf:=false"]
    # The same node told the joint is NOT flipped: the control that shows the parameter works.
    wrong_args = ["--ros-args", "-r", "__node:=odometry_wrong", "-r", "odom:=odom_wrong",
                  "-p", f"ticks_per_revolution:={tpr}", "-p", f"encoder_counter_bits:={bits}",
                  "-p", f"wheel_radius:={R}", "-p", f"wheel_separation:={B}",
                  "-p", "enable_odom_tf:=false"]
    with node_process("sim_node", sim_args) as sim, \
            node_process("odometry_node", odom_args) as odo, \
            node_process("odometry_node", wrong_args) as wrong, \
            ros_test_node() as (node, ex):
        sink = listen(node, ("/odom", "/odom_wrong"))
        pub = node.create_publisher(Float64MultiArray, "/wheel_commands", 10)
        # The joints heard from the start: the counters' wrap below is checked on them.
        assert spin_until(ex, lambda: pub.get_subscription_count() > 0 and len(sink.joints) > 0
                          and len(sink.truth) > 0 and len(sink.odom["/odom"]) > 0
                          and len(sink.odom["/odom_wrong"]) > 0,
                          25.0), output(sim) + output(odo) + output(wrong)
        # An arc: 0.2 m/s, 0.5 rad/s, until the ground truth has turned 0.7 rad (1.4 s of
        # motion; a stall over the sim's command_timeout pauses it on the same arc), then
        # stopped by a zero command. The sim moves on only while commands come in and
        # 0.3 s after (command_timeout, however long this test stalls): the motion stays
        # far from 2.36 s, where the wrong odometry's heading (-1.33 rad/s) would wrap.
        assert drive_until(ex, pub, rates(0.2, 0.5, 1, -1),
                           lambda: yaw(sink.truth[-1].pose.pose.orientation) >= 0.7), (
            output(sim))
        stop_sent = node.get_clock().now().nanoseconds  # the sim stamps on the same clock
        assert drive_until(ex, pub, [0.0, 0.0], lambda: ns_of(sink.truth[-1].header.stamp)
                           > stop_sent and standing(sink.truth[-1])), output(sim)
        stop_ns = ns_of(sink.truth[-1].header.stamp)
        # Both odometries have read the joint states up to the stop.
        assert spin_until(ex, lambda: all(
            odom and ns_of(odom[-1].header.stamp) >= stop_ns for odom in sink.odom.values()),
            10.0), output(odo) + output(wrong)
        truth = {ns_of(m.header.stamp): m for m in sink.truth}
        common = [m for m in sink.odom["/odom"] if ns_of(m.header.stamp) in truth]
        assert common, "no odometry stamped like the ground truth"
        last = common[-1]
        gt = truth[ns_of(last.header.stamp)]
        distance = 0.0
        for a, b in itertools.pairwise(sink.truth):
            pa, pb = a.pose.pose.position, b.pose.pose.position
            distance += math.hypot(pb.x - pa.x, pb.y - pa.y)
        assert distance > 0.25  # it really drove (about 0.3 m)
        assert abs(yaw(gt.pose.pose.orientation)) > 0.6  # and turned left (about 0.7 rad)

        # Encoder resolution: one tick per wheel, so heading within (2 tick arcs) / b at
        # every instant, position within 2 tick arcs + distance * that heading bound.
        tick_arc = 2 * math.pi * R / tpr
        heading_bound = 2 * tick_arc / B
        position_bound = 2 * tick_arc + distance * heading_bound
        p, q = last.pose.pose.position, gt.pose.pose.position
        assert math.hypot(p.x - q.x, p.y - q.y) <= position_bound
        assert abs(yaw(last.pose.pose.orientation) - yaw(gt.pose.pose.orientation)) <= (
            heading_bound)

        # The counters really wrapped: left counts up past 4095, right counts down past 0.
        lefts = [m.position[0] for m in sink.joints]
        rights = [m.position[1] for m in sink.joints]
        # Left starts at 4090 and counts up: below 4090 only by wrapping past 4095 (not
        # 'below 100': a sim step stretched by load once went from 4090 straight to 116).
        assert lefts[0] == 4090 and min(lefts) < 4090 and max(lefts) <= 4095
        assert rights[0] == 4090 and min(rights) < 4000 and max(rights) <= 4095
        assert all(0 <= c < 2**bits and c == int(c) for c in lefts + rights)

        # Without right_wheel_sign the odometry sees the right wheel roll backwards: it
        # believes the robot reversed and turned right (v = -0.075 m/s, w = -1.33 rad/s)
        # while it drove forwards turning left.
        bad = sink.odom["/odom_wrong"][-1]
        assert yaw(bad.pose.pose.orientation) < -1.0 < 0.6 < yaw(gt.pose.pose.orientation)


@pytest.mark.serial
def test_clock_stamps_formats_and_timeout() -> None:
    rtf = 3.0
    args = ["--ros-args", "-p", f"wheel_radius:={R}", "-p", f"wheel_separation:={B}",
            "-p", "publish_clock:=true", "-p", f"real_time_factor:={rtf}",
            "-p", "wheel_command_format:=joint_state", "-p", "command_timeout:=0.5",
            "-p", "world_frame_id:=map"]
    with node_process("sim_node", args) as sim, ros_test_node() as (node, ex):
        sink = listen(node)
        pub = node.create_publisher(JointState, "/wheel_commands", 10)
        assert spin_until(ex, lambda: pub.get_subscription_count() > 0 and sink.clock,
                          20.0), output(sim)
        wall0, clock0 = time.monotonic(), sink.clock[-1]
        spin_for(ex, 2.0)
        wall, simulated = time.monotonic() - wall0, (sink.clock[-1] - clock0) * 1e-9
        # Faster than real time (a loaded machine may not reach the full factor).
        assert simulated > 1.3 * wall
        assert simulated < rtf * wall * 1.2
        # joint_states are stamped with the simulated time: on the /clock's grid of
        # exactly 20 ms steps, and in step with it.
        stamps = [ns_of(m.header.stamp) for m in sink.joints if ns_of(m.header.stamp) >= clock0]
        assert len(stamps) > 50
        assert all((s - clock0) % 20_000_000 == 0 for s in stamps)
        assert {b - a for a, b in itertools.pairwise(stamps)} == {20_000_000}
        assert abs(stamps[-1] - sink.clock[-1]) <= 10 * 20_000_000
        assert sink.truth[-1].header.frame_id == "map"
        assert sink.truth[-1].child_frame_id == "base_link"

        # JointState commands by name (order swapped): straight at 0.1 m/s.
        cmd = JointState(name=["right_wheel_joint", "left_wheel_joint"], velocity=[2.0, 2.0])
        start = sink.truth[-1].pose.pose.position.x
        deadline = time.monotonic() + 1.0
        while time.monotonic() < deadline:
            pub.publish(cmd)
            spin_for(ex, 0.02)
        moving = sink.truth[-1]
        assert abs(moving.twist.twist.linear.x - 0.1) < 1e-9
        assert abs(moving.twist.twist.angular.z) < 1e-12
        assert moving.pose.pose.position.x > start
        # Silence: after the timeout (simulated) the base stops and stays.
        spin_for(ex, 1.0)
        stopped = sink.truth[-1]
        assert stopped.twist.twist.linear.x == 0.0
        spin_for(ex, 0.5)
        assert sink.truth[-1].pose.pose.position.x == stopped.pose.pose.position.x
        assert sink.joints[-1].position[0] == sink.joints[-2].position[0]


def test_counts_per_second_and_bad_commands() -> None:
    tpr = 2048.0
    args = ["--ros-args", "-p", f"wheel_radius:={R}", "-p", f"wheel_separation:={B}",
            "-p", "wheel_command_format:=ticks_per_second",
            "-p", f"ticks_per_revolution:={tpr}", "-p", "joint_state_units:=radians"]
    with node_process("sim_node", args) as sim, ros_test_node() as (node, ex):
        sink = listen(node)
        pub = node.create_publisher(Float64MultiArray, "/wheel_commands", 10)
        assert spin_until(ex, lambda: pub.get_subscription_count() > 0 and sink.truth,
                          20.0), output(sim)
        # Wrong length and NaN: dropped, the robot does not move, the node lives on.
        drive(ex, pub, [100.0, 100.0, 100.0], 0.3)
        drive(ex, pub, [math.nan, 100.0], 0.3)
        assert sink.truth[-1].pose.pose.position.x == 0.0
        assert sim.poll() is None
        # Turning on the spot at 1 rad/s: right wheel +w b/2 / r rad/s, in counts/s.
        per_rad = tpr / (2 * math.pi)
        right = 1.0 * B / 2 / R
        # Commanded until the truth moves and the right wheel has turned forwards (at
        # least a tick) on joint_states: every step on the command is exactly the turn.
        assert drive_until(ex, pub, [-right * per_rad, right * per_rad], lambda: any(
            not standing(m) for m in sink.truth) and sink.joints[-1].position[1] > 0), (
            output(sim))
        moving = [m for m in sink.truth if not standing(m)]
        assert all(abs(m.twist.twist.angular.z - 1.0) < 1e-9 for m in moving)
        assert all(abs(m.twist.twist.linear.x) < 1e-9 for m in moving)
        # Radians on joint_states, quantized to whole ticks.
        tick = 2 * math.pi / tpr
        pos = sink.joints[-1].position[1]
        assert pos > 0 and abs(pos / tick - round(pos / tick)) < 1e-6
    assert "dropped" in output(sim)


def test_runtime_parameters_refused_with_reason_or_applied() -> None:
    with node_process("sim_node", ["--ros-args"]) as sim, ros_test_node() as (node, ex):
        double = ParameterType.PARAMETER_DOUBLE
        bad = set_parameter(node, ex, "/sim_node", "slip_stddev",
                            ParameterValue(type=double, double_value=-1.0))
        assert not bad.successful and "slip_stddev" in bad.reason
        fixed = set_parameter(node, ex, "/sim_node", "joint_state_rate",
                           ParameterValue(type=double, double_value=10.0))
        assert not fixed.successful  # read-only: the rate is the simulation's step
        ok = set_parameter(node, ex, "/sim_node", "true_right_wheel_radius",
                        ParameterValue(type=double, double_value=0.034))
        assert ok.successful
        assert sim.poll() is None


BAD_PARAMETERS = {
    "joint_state_rate": "joint_state_rate:=0.0",
    "joint_state_units": "joint_state_units:=furlongs",
    "true_right_wheel_radius": "true_right_wheel_radius:=-0.1",
    "encoder_counter_bits": "encoder_counter_bits:=16",
}


@pytest.mark.parametrize("name", BAD_PARAMETERS)
def test_bad_parameters_refuse_to_start_with_one_line(name: str) -> None:
    """Each case in this process (the node's own construction, rcl parsing the -p)."""
    assert_refused_in_process(SimNode, name, ["-p", BAD_PARAMETERS[name]])


def test_a_bad_parameter_stops_the_process_with_exit_2_and_one_line() -> None:
    assert_refuses_to_start("sim_node", "joint_state_rate",
                            ["-p", BAD_PARAMETERS["joint_state_rate"]])
