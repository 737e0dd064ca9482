"""SIGTERM, SIGINT and SIGHUP end every node within a second, even in the middle of a burst.

Under systemd or docker a stop is SIGTERM, then SIGKILL after a grace period: a node
that sits in an unbounded wait after the signal is killed at every stop. Each trial
starts the real console script, feeds it a stream of bursts (messages back to back,
then a short quiet spell, so that a signal lands both while callbacks run and just as
the input stops), sends the signal at a random moment of that cycle and times the
exit. The processes of a batch start together and share one burst generator; each
gets its signal at its own moment. SIGHUP (a closed terminal or ssh session) used to end
a node by its default action, at once and with no teardown.
"""

from __future__ import annotations

import math
import os
import random
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from contextlib import ExitStack

import pytest
import rclpy
from geometry_msgs.msg import Twist
from rclpy.context import Context
from rclpy.node import Node
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray

from diffdrive_odom.ros.lifetime import stop_signals
from diffdrive_odom.ros.runtime import EXECUTOR_KINDS, make_executor

from rosutil import EXIT_WITHIN_S, GEOMETRY, Burst, burst, joint_state, node_process

pytestmark = [pytest.mark.dds, pytest.mark.process, pytest.mark.serial,
              pytest.mark.xdist_group("serial-heavy")]


def twist(k: int) -> Twist:
    msg = Twist()
    msg.linear.x = 0.2 * math.sin(k * 1e-3)
    msg.angular.z = 0.3
    return msg


def wheel_command(k: int) -> Float64MultiArray:
    return Float64MultiArray(data=[1.0, 1.5 + math.sin(k * 1e-3)])


def stop_times(
    executable: str,
    args: Callable[[int], list[str]],
    source: Burst,
    signals: list[signal.Signals],
    rng: random.Random,
) -> list[tuple[str, int | None, float, str]]:
    """Start one process per entry of ``signals`` (``args(i)`` its ROS arguments), all
    at once; once all are subscribed, for each in turn: burst at it, signal it at a
    random moment of the burst cycle, time its exit.

    Returns (signal name, exit code or None if still running, seconds, output).
    """
    n = len(signals)
    results: list[tuple[str, int | None, float, str]] = []
    with ExitStack() as stack:
        procs = [stack.enter_context(node_process(
            executable, ["--ros-args", *args(i), "-r", f"__node:=signal_test_{i}"],
            env={"PYTHONFAULTHANDLER": "1"})) for i in range(n)]
        deadline = time.monotonic() + 60.0
        while (not all(p.get_subscription_count() for p in source.pubs[:n])
               and time.monotonic() < deadline):
            assert all(p.poll() is None for p in procs), "a node died at start"
            time.sleep(0.05)
        assert all(p.get_subscription_count() for p in source.pubs[:n]), "never subscribed"
        sent_at: dict[int, float] = {}
        ended: dict[int, float] = {}
        for i in range(n):
            source.aim(i)
            time.sleep(rng.uniform(0.05, 0.05 + source.cycle_s))
            sent_at[i] = time.monotonic()
            procs[i].send_signal(signals[i])
            until = sent_at[i] + 3 * EXIT_WITHIN_S
            while procs[i].poll() is None and time.monotonic() < until:
                time.sleep(0.002)
            if procs[i].poll() is not None:
                ended[i] = time.monotonic()
        for i, p in enumerate(procs):
            code = p.poll()
            if code is None:
                p.send_signal(signal.SIGABRT)  # faulthandler prints where it is stuck
                try:
                    p.wait(timeout=5)
                except subprocess.TimeoutExpired:
                    p.kill()
                    p.wait()
            out = p.stdout.read() if p.stdout else ""
            took = ended.get(i, math.inf) - sent_at[i]
            results.append((signals[i].name, code, took, out))
    return results


def assert_all_stopped(results: list[tuple[str, int | None, float, str]]) -> None:
    late = [(sig, code, round(took, 3)) for sig, code, took, _ in results
            if code != 0 or took > EXIT_WITHIN_S]
    bad_out = [out for *_, out in results if "Traceback" in out or "[FATAL]" in out]
    first = max(((took, out) for sig, code, took, out in results
                 if code != 0 or took > EXIT_WITHIN_S), default=(0.0, ""))[1]
    assert not late, f"{len(late)} of {len(results)} did not exit 0 within " \
                     f"{EXIT_WITHIN_S} s: {late}; first one's output:\n{first[-3000:]}"
    assert not bad_out, bad_out[0]


def test_spin_loop_ends_on_a_shutdown_that_wakes_no_wait() -> None:
    """The race behind a hang: rclpy's signal thread triggers the signal guard, then shuts
    the context down without waking any executor. A wait that took the trigger while
    the context was still up leaves the next one blocked, with no timeout, until a
    message or timer comes. Here, the second half of that alone: the context is shut
    down as rclpy's signal thread does it (no on_shutdown callbacks, no wake-up) under a
    node with nothing to wake the wait; each executor's spin loop must still end.
    """
    for kind in EXECUTOR_KINDS:
        context = Context()
        rclpy.init(context=context)
        executor, spin = make_executor(kind, context=context)
        node = Node("quiet_node", context=context)
        executor.add_node(node)
        worker = threading.Thread(target=spin, args=(lambda: False,), daemon=True)
        worker.start()
        time.sleep(0.3)  # the loop is in its wait by now
        with context.handle:
            context.handle.shutdown()
        worker.join(timeout=EXIT_WITHIN_S)
        assert not worker.is_alive(), f"{kind}: spin loop still waiting after the shutdown"
        executor.shutdown()
        node.destroy_node()


STOPPED_WHILE_STARTING = """
import os, signal, sys, time
from rclpy.node import Node
from diffdrive_odom.ros.runtime import run

def factory():
    node = Node("starting_node")
    os.kill(os.getpid(), signal.SIGINT)  # Ctrl-C while the node is being built
    time.sleep(0.5)  # rclpy's own handler would have shut the context down by now
    node.create_timer(1.0, lambda: None)  # and this raised, as sim_node's did under launch
    return node

sys.exit(run(factory, ["starting_node"]))
"""


def test_a_stop_signal_while_the_node_is_built_ends_it_with_exit_0() -> None:
    """CI's ros2 launch Ctrl-C test once caught sim_node still in its constructor: rclpy's
    signal handler shut the context down under it, its next create_timer raised, exit 1
    with a traceback. Now the signal only asks for the stop, which comes after the
    constructor: exit 0, nothing printed."""
    proc = subprocess.run([sys.executable, "-c", STOPPED_WHILE_STARTING],
                          capture_output=True, text=True, timeout=30)
    assert proc.returncode == 0, proc.stderr
    assert "Traceback" not in proc.stderr, proc.stderr


def signal_mix(terms: int, ints: int, rng: random.Random, hups: int = 0
               ) -> list[signal.Signals]:
    """The signals in a random order; SIGHUP's share as SIGTERM where the nodes inherit it
    ignored (a test run under nohup: they keep it ignored, as asked)."""
    if signal.SIGHUP not in stop_signals():
        terms, hups = terms + hups, 0
    sigs = [signal.SIGTERM] * terms + [signal.SIGINT] * ints + [signal.SIGHUP] * hups
    rng.shuffle(sigs)
    return sigs


@pytest.mark.slow
def test_odometry_node_stops_within_a_second_of_sigterm_or_sigint_during_a_burst() -> None:
    """Half SIGTERM, half SIGINT, ten processes started at a time: 20 trials in make
    test (the race they once caught has its own deterministic test above), more with
    SIGNAL_TRIAL_ROUNDS=10 (the 100 trials the fix was judged on: about 110 s)."""
    rounds = int(os.environ.get("SIGNAL_TRIAL_ROUNDS", "2"))
    rng = random.Random(20261201)
    topics = [f"/signal_test/joint_states_{i}" for i in range(10)]

    def args(i: int) -> list[str]:
        return [*GEOMETRY, "-r", f"joint_states:={topics[i]}",
                "-r", f"odom:=/signal_test/odom_{i}", "-p", "enable_odom_tf:=false"]

    results = []
    with burst(JointState, topics, joint_state) as source:
        for _ in range(rounds):
            results += stop_times("odometry_node", args, source, signal_mix(5, 5, rng), rng)
        assert source.sent > 0
    assert sorted(sig for sig, *_ in results) == ["SIGINT"] * 5 * rounds + ["SIGTERM"] * 5 * rounds
    assert_all_stopped(results)


def test_cmd_vel_node_stops_within_a_second_during_a_burst() -> None:
    rng = random.Random(7)
    topics = [f"/signal_test/cmd_vel_{i}" for i in range(6)]

    def args(i: int) -> list[str]:
        return [*GEOMETRY, "-r", f"cmd_vel:={topics[i]}",
                "-r", f"wheel_commands:=/signal_test/wheels_{i}"]

    with burst(Twist, topics, twist) as source:
        results = stop_times("cmd_vel_node", args, source, signal_mix(2, 2, rng, hups=2), rng)
    assert_all_stopped(results)


def test_sim_node_stops_within_a_second_during_a_burst() -> None:
    rng = random.Random(11)
    topics = [f"/signal_test/wheel_commands_{i}" for i in range(6)]

    def args(i: int) -> list[str]:
        return ["-r", f"wheel_commands:={topics[i]}",
                "-r", f"joint_states:=/signal_test/sim_joints_{i}",
                "-r", f"ground_truth/odom:=/signal_test/truth_{i}"]

    with burst(Float64MultiArray, topics, wheel_command) as source:
        results = stop_times("sim_node", args, source, signal_mix(2, 2, rng, hups=2), rng)
    assert_all_stopped(results)


def test_sim_node_with_a_fast_clock_stops_on_sigint_without_a_fatal() -> None:
    """The Ctrl-C of ``ros2 launch diffdrive_odom base.launch.py use_sim:=true``: rclpy's
    own handler shut the context down from its thread while a timer callback published,
    and 2 of 6 tries printed "[FATAL] ... Exception in 'timers' callback: Failed to
    publish: publisher's context is invalid" and a traceback. A 1 kHz sim publishing its
    /clock makes the timers busy; SIGINT (and SIGTERM) must end it quietly, exit 0."""
    rng = random.Random(40)
    topics = [f"/signal_test/fast_wheel_commands_{i}" for i in range(6)]

    def args(i: int) -> list[str]:
        return ["-p", "publish_clock:=true", "-p", "joint_state_rate:=1000.0",
                "-r", f"wheel_commands:={topics[i]}", "-r", f"/clock:=/signal_test/clock_{i}",
                "-r", f"joint_states:=/signal_test/fast_joints_{i}",
                "-r", f"ground_truth/odom:=/signal_test/fast_truth_{i}"]

    with burst(Float64MultiArray, topics, wheel_command) as source:
        results = stop_times("sim_node", args, source, signal_mix(2, 4, rng), rng)
    assert_all_stopped(results)
