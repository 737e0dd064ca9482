"""sim_node in lockstep over real DDS: a heartbeat slower than the sim, the watchdog on
simulated time, the guard that names a node that does not answer, refused set-ups.

The sim and cmd_vel_node run as processes; the test's node is in the loop too
(``rosutil.loop_peer``). Expected values come from the rules as documented: a timer on
simulated time runs at the first step at or after it is due (as an rcl timer that
cannot keep up), and a command is followed until it is ``cmd_vel_timeout`` old.
"""

from __future__ import annotations

import math
import re
import signal
import time
from pathlib import Path
from typing import Any

import pytest
from geometry_msgs.msg import Twist, Vector3
from nav_msgs.msg import Odometry
from sensor_msgs.msg import JointState

from diffdrive_odom.ros.cmd_vel_node import CmdVelNode
from diffdrive_odom.ros.path_follower_node import PathFollowerNode
from diffdrive_odom.ros.qos import qos
from diffdrive_odom.settings.params import yaml_text
from diffdrive_odom.wire.conversions import stamp_to_ns

from rosutil import assert_refused_in_process, loop_peer, node_process, spin_until

pytestmark = [pytest.mark.dds, pytest.mark.process]

R, B = 0.05, 0.30
STEP_NS = 20_000_000  # the sim's 50 Hz
PEER = "lockstep_test_peer"


def write_params(tmp: Path, cmd_vel: dict[str, Any] | None = None) -> Path:
    sections = {
        "/**": {"wheel_radius": R, "wheel_separation": B, "use_sim_time": True,
                "lockstep": True, "wheel_command_format": "joint_state"},
        "sim_node": {"use_sim_time": False, "joint_state_rate": 50.0,
                     "lockstep_nodes": ["cmd_vel_node", PEER]},
        "cmd_vel_node": cmd_vel or {},
    }
    path = tmp / "params.yaml"
    path.write_text("".join(
        f"{node}:\n  ros__parameters:\n" + "".join(
            f"    {k}: {yaml_text(v)}\n" for k, v in values.items())
        for node, values in sections.items() if values), encoding="utf-8")
    return path


def test_a_slower_heartbeat_ticks_on_simulated_time_and_the_watchdog_stops_it_there(
        tmp_path: Path) -> None:
    """cmd_vel_node at 20 Hz beside a 50 Hz sim: a wheel command (a JointState, stamped
    with the node's clock at the tick) at the first step at or after each 50 ms (0, 60,
    100, 160, 200 ms, ...). One Twist, taken with the sim's first readings, is followed
    by every tick until it is 0.5 s old (simulated, 0.5 s exactly: the tick at 500 ms
    still follows it, the one at 560 ms sends zeros)."""
    v = 0.1
    params = write_params(tmp_path, {"wheel_command_rate": 20.0, "cmd_vel_timeout": 0.5})
    with loop_peer(PEER) as (node, executor, loop):
        now: list[int] = []
        ticks: list[tuple[int, list[float]]] = []
        send = loop.publish(node.create_publisher(Twist, "/cmd_vel", 10))
        sent: list[int] = []

        def first_readings(msg: Odometry) -> None:
            if not sent:
                sent.append(stamp_to_ns(msg.header.stamp))
                send(Twist(linear=Vector3(x=v)))

        loop.on_clock.append(now.append)
        loop.subscription(Odometry, "/ground_truth/odom", first_readings, qos(10, True))
        loop.subscription(JointState, "/wheel_commands", lambda m: ticks.append(
            (stamp_to_ns(m.header.stamp), list(m.velocity))), qos(10, True))
        with node_process("sim_node", ["--ros-args", "--params-file", str(params)]), \
                node_process("cmd_vel_node", ["--ros-args", "--params-file", str(params)]):
            assert spin_until(executor, lambda: len(now) > 60, 90.0), (len(now), ticks[:3])
    t0 = now[0]
    assert sent == [t0]  # the sim's first readings: those of its first step
    steps = [t - t0 for t in now]
    assert steps == [k * STEP_NS for k in range(len(steps))]  # one /clock per step, in order
    want = [math.ceil(50_000_000 * j / STEP_NS) * STEP_NS for j in range(len(ticks))]
    assert [t - t0 for t, _ in ticks] == want
    assert want[-1] >= 1_000_000_000 - STEP_NS  # a second of ticks seen
    rate = v / R
    followed = [(t - t0, rates) for t, rates in ticks if rates != [0.0, 0.0]]
    assert followed == [(t, [rate, rate]) for t in want if 0 < t <= 500_000_000]


def test_a_node_that_does_not_answer_is_named_and_the_loop_waits_for_it(
        tmp_path: Path) -> None:
    """cmd_vel_node stopped (SIGSTOP) past the guard's 5 s: the sim names it and what it
    owes, and steps on once it answers again; no step was taken meanwhile."""
    params = write_params(tmp_path)
    with loop_peer(PEER) as (_, executor, loop):
        now: list[int] = []
        loop.on_clock.append(now.append)
        with node_process("sim_node", ["--ros-args", "--params-file", str(params)]) as sim, \
                node_process("cmd_vel_node", ["--ros-args", "--params-file",
                                              str(params)]) as cmd:
            assert spin_until(executor, lambda: len(now) > 10, 90.0)
            cmd.send_signal(signal.SIGSTOP)
            try:
                spin_until(executor, lambda: False, 1.0)
                held = len(now)
                spin_until(executor, lambda: False, 6.0)
                assert len(now) == held  # the sim waited
            finally:
                cmd.send_signal(signal.SIGCONT)
            assert spin_until(executor, lambda: len(now) > held + 10, 30.0)
            sim.send_signal(signal.SIGINT)
            out = sim.communicate(timeout=20)[0]
    named = [ln for ln in out.splitlines() if "lockstep:" in ln and "not answered" in ln]
    assert named, out
    assert re.search(r"/cmd_vel_node has taken \d+ of the \d+ messages sent on /clock",
                     named[0]), named[0]


LOCKSTEP_WITHOUT_SIM_TIME = ["-p", f"wheel_radius:={R}", "-p", f"wheel_separation:={B}",
                             "-p", "lockstep:=true"]


@pytest.mark.parametrize("node_class", [CmdVelNode, PathFollowerNode])
def test_lockstep_without_use_sim_time_stops_the_node_with_one_line(node_class: Any) -> None:
    """A node in lockstep runs on the sim's /clock: without use_sim_time it would stamp
    and time its work on the wall clock, so it refuses to start, naming lockstep."""
    assert_refused_in_process(node_class, "lockstep", LOCKSTEP_WITHOUT_SIM_TIME)


def test_the_loop_is_not_stepped_before_every_node_has_answered(tmp_path: Path) -> None:
    """A node of lockstep_nodes that never starts: no /clock at all, and after the guard's
    5 s the sim names it."""
    params = write_params(tmp_path)
    with loop_peer(PEER) as (_, executor, loop):
        now: list[int] = []
        loop.on_clock.append(now.append)
        with node_process("sim_node", ["--ros-args", "--params-file", str(params)]) as sim:
            deadline = time.monotonic() + 8.0
            while time.monotonic() < deadline:
                spin_until(executor, lambda: False, 0.5)
            sim.send_signal(signal.SIGINT)
            out = sim.communicate(timeout=20)[0]
    assert now == []
    assert "lockstep: the start not answered" in out and (
        "/cmd_vel_node has not answered yet" in out), out
