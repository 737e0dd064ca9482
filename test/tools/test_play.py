"""Live replay: ``diffdrive-odom play`` feeding the real odometry node over DDS.

The node's every published pose must equal offline replay's pose for the same
reading to 1e-9 m (one estimator, two paths); /clock must carry the bag's time; a
looped play must restart the node cleanly, every pass identical to the first.
"""

from __future__ import annotations

import math
import signal
from pathlib import Path
from typing import Any

import pytest
from nav_msgs.msg import Odometry
from rosgraph_msgs.msg import Clock

from diffdrive_odom.tools.bags import bagio, bagreadings
from diffdrive_odom.tools.cli import main as cli
from diffdrive_odom.tools.cmdline.args import load_settings
from diffdrive_odom.tools.replaying.readings import replay_readings
from diffdrive_odom.tools.replaying.sinks import Published

from bagutil import OPTIODOM_PARAMS, TB3_PARAMS, write_params
from rosutil import DATA, node_process, ros_test_node, spin_for, spin_until

RUN04 = DATA / "optiodom" / "square_231220200029_run-04"
TB3 = DATA / "turtlebot3_sim" / "turtlebot3.bag"


def _ns(t: Any) -> int:
    return int(t.sec) * 10**9 + int(t.nanosec)


def _offline(bag: Path, params: Path, until_ns: int | None = None,
             only: set[int] | None = None) -> dict[int, Published]:
    """Offline replay's poses by stamp; ``only``: just the readings with these stamps.

    Best-effort DDS may drop a reading on a loaded machine; the node then integrates
    one longer step, so the fair comparison feeds replay exactly the readings the node
    got (its output has one pose per reading received, stamped with it).
    """
    settings = load_settings(params)
    readings = bagreadings.read_joint_states(bag)
    if until_ns is not None:
        readings = (r for r in readings if r.log_ns < until_ns)
    if only is not None:
        readings = (r for r in readings if r.stamp_ns in only)
    out: list[Published] = []
    replay_readings(readings, settings, out.append)
    return {p.stamp_ns: p for p in out}


def _check_pass(odoms: list[Odometry], bag: Path, params: Path, everything: set[int],
                until_ns: int | None = None) -> None:
    """The node's poses equal replay's on the same readings; almost none were lost."""
    stamps = [_ns(o.header.stamp) for o in odoms]
    assert stamps == sorted(set(stamps)), "a reading was answered twice or out of order"
    assert set(stamps) <= everything
    assert len(stamps) >= 0.98 * len(everything), (len(stamps), len(everything))
    expected = _offline(bag, params, until_ns, set(stamps))
    assert sorted(expected) == stamps
    for o in odoms:
        _assert_same(o, expected[_ns(o.header.stamp)])


def _assert_same(odom: Odometry, expected: Published) -> None:
    p = odom.pose.pose
    assert math.hypot(p.position.x - expected.pose.x, p.position.y - expected.pose.y) < 1e-9
    yaw = 2 * math.atan2(p.orientation.z, p.orientation.w)
    assert abs(math.remainder(yaw - expected.pose.theta, 2 * math.pi)) < 1e-9


def _wait_for_node(node: Any, ex: Any, proc: Any) -> None:
    """Until the node's /odom reaches this test's subscriber (discovery takes a while)."""
    if not spin_until(ex, lambda: node.count_publishers("/odom") > 0, 20.0):
        alive = proc.poll() is None
        if not alive and proc.stdout:
            print(proc.stdout.read())
        raise AssertionError(f"odometry_node's /odom not discovered (alive: {alive})")
    spin_for(ex, 0.5)


def _spin_until_quiet(ex: Any, odoms: list[Odometry], quiet: float = 0.5) -> None:
    """Spin until no odometry has arrived for ``quiet`` seconds (the node has caught up)."""
    count = -1
    while count != len(odoms):
        count = len(odoms)
        spin_for(ex, quiet)


def _node_args(params: Path) -> list[str]:
    return ["--ros-args", "--params-file", str(params), "-p", "use_sim_time:=true"]


@pytest.mark.dds
@pytest.mark.process
def test_play_with_clock_drives_the_node_to_offline_replays_poses(tmp_path: Path) -> None:
    params = write_params(tmp_path / "p.yaml", OPTIODOM_PARAMS)
    expected = _offline(RUN04, params)
    logged = [r.log_ns for r in bagreadings.read_joint_states(RUN04)]
    bag_start, bag_end = min(logged), max(logged)
    odoms: list[Odometry] = []
    clocks: list[int] = []
    with node_process("odometry_node", _node_args(params)) as node_proc, \
            ros_test_node() as (node, ex):
        node.create_subscription(Odometry, "/odom", odoms.append, 2000)
        node.create_subscription(Clock, "/clock", lambda m: clocks.append(_ns(m.clock)), 100)
        _wait_for_node(node, ex, node_proc)
        play = ["play", str(RUN04), "--topics", "/joint_states", "--rate", "8", "--clock",
                "20", "--wait-for", "/joint_states"]
        with node_process("diffdrive-odom", play) as player:
            assert spin_until(ex, lambda: player.poll() is not None, 25.0)
            assert player.returncode == 0
            _spin_until_quiet(ex, odoms)
        assert node_proc.poll() is None
    # The readings came back as the poses offline replay computes (usually all of them).
    _check_pass(odoms, RUN04, params, set(expected))
    # /clock carried the bag's time, forwards, up to the last message played.
    assert len(clocks) > 20
    assert all(bag_start <= c <= bag_end for c in clocks)
    assert clocks == sorted(clocks)
    assert clocks[-1] == bag_end


@pytest.mark.dds
@pytest.mark.process
def test_looped_play_restarts_the_node_cleanly_and_ctrl_c_exits_0(tmp_path: Path) -> None:
    params = write_params(tmp_path / "p.yaml", OPTIODOM_PARAMS)
    with bagio.open_bag(RUN04) as reader:
        until = reader.start_time + 4 * 10**9
    expected = _offline(RUN04, params, until)  # the first 4 s of the bag
    first_ns, last_ns = min(expected), max(expected)
    odoms: list[Odometry] = []
    with node_process("odometry_node", _node_args(params)) as node_proc, \
            ros_test_node() as (node, ex):
        node.create_subscription(Odometry, "/odom", odoms.append, 2000)
        _wait_for_node(node, ex, node_proc)
        play = ["play", str(RUN04), "--topics", "/joint_states", "--rate", "4", "--loop",
                "--duration", "4", "--clock", "--wait-for", "/joint_states"]
        with node_process("diffdrive-odom", play) as player:
            # Three ends of a pass = at least two restarts.
            assert spin_until(
                ex, lambda: sum(_ns(o.header.stamp) == last_ns for o in odoms) >= 3, 20.0)
            player.send_signal(signal.SIGINT)
            code = player.wait(timeout=10)
            assert code == 0, player.stdout.read() if player.stdout else ""  # its traceback
        assert node_proc.poll() is None
        node_proc.send_signal(signal.SIGINT)
        node_proc.wait(timeout=10)
        log = node_proc.stdout.read() if node_proc.stdout else ""
    passes: list[list[Odometry]] = [[]]
    for o in odoms:
        if passes[-1] and _ns(o.header.stamp) < _ns(passes[-1][-1].header.stamp):
            passes.append([])
        passes[-1].append(o)
    assert len(passes) >= 3
    for run in passes[:3]:  # each pass starts over at the origin and repeats the first
        _check_pass(run, RUN04, params, set(expected), until)
        first = run[0].pose.pose.position
        assert _ns(run[0].header.stamp) == first_ns and (first.x, first.y) == (0.0, 0.0)
    assert log.count("jumped back") >= 2, log


@pytest.mark.dds
@pytest.mark.process
def test_play_converts_a_ros1_bag_for_the_node(tmp_path: Path) -> None:
    """TurtleBot3 (ROS 1, right wheel first, wheels not at zero): no jump at the start."""
    params = write_params(tmp_path / "p.yaml", TB3_PARAMS)
    with bagio.open_bag(TB3) as reader:
        until = reader.start_time + 3 * 10**9
    expected = _offline(TB3, params, until)
    odoms: list[Odometry] = []
    with node_process("odometry_node", _node_args(params)) as node_proc, \
            ros_test_node() as (node, ex):
        node.create_subscription(Odometry, "/odom", odoms.append, 2000)
        _wait_for_node(node, ex, node_proc)
        play = ["play", str(TB3), "--topics", "/joint_states", "--duration", "3", "--rate",
                "3", "--clock", "--wait-for", "/joint_states"]
        with node_process("diffdrive-odom", play) as player:
            assert spin_until(ex, lambda: player.poll() is not None, 20.0)
            assert player.returncode == 0
            _spin_until_quiet(ex, odoms)
    _check_pass(odoms, TB3, params, set(expected), until)
    first = odoms[0]
    assert 112 * 10**9 < _ns(first.header.stamp) < 113 * 10**9  # simulated time
    assert (first.pose.pose.position.x, first.pose.pose.position.y) == (0.0, 0.0)


def test_play_refuses_bad_arguments(tmp_path: Path) -> None:
    assert cli(["play", str(RUN04), "--rate", "0"]) == 2
    assert cli(["play", str(tmp_path / "missing")]) == 2
    assert cli(["play", str(RUN04), "--topics", "/nope"]) == 2
    assert cli(["play", str(RUN04), "--remap", "nonsense"]) == 2
