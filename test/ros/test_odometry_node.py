"""The odometry node over real DDS on loopback, checked against closed forms.

Each test starts ``odometry_node`` as its own process (the console script a user
runs) and talks to it from a private-Context peer node.
"""

from __future__ import annotations

import itertools
import math
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from rcl_interfaces.msg import ParameterType, ParameterValue
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState
from std_srvs.srv import Trigger

from diffdrive_odom.core.uncertainty.propagation import COVARIANCE_FLOOR
from diffdrive_odom.ros.odometry_node import OdometryNode
from diffdrive_odom.tools.cli import main as cli

import oracle
from bagutil import mcap_messages, write_params
from rosutil import (
    ROOT,
    STEP_NS,
    T0_NS,
    OdomRigs,
    assert_refused_in_process,
    assert_refuses_to_start,
    call_service,
    drive_straight,
    ns_of,
    send_first,
    set_parameter,
    spin_for,
    spin_until,
    stamp,
    yaw,
)

pytestmark = [pytest.mark.dds, pytest.mark.process]


def test_ticks_wrap_shuffled_names_sign_flip_and_nonzero_start(odom_rig: OdomRigs) -> None:
    """Raw 16-bit counts that wrap, names shuffled, extra joints, right joint reversed."""
    r, b, tpr = 0.05, 0.3, 1000.0
    left_inc, right_inc = 40, -60  # counts per reading; right joint axis reversed
    steps = 100
    args = [
        "-p", f"wheel_radius:={r}", "-p", f"wheel_separation:={b}",
        "-p", f"ticks_per_revolution:={tpr}", "-p", "encoder_counter_bits:=16",
        "-p", "right_wheel_sign:=-1",
        "-p", "left_wheel_names:=['lw']", "-p", "right_wheel_names:=['rw']",
    ]
    _, _, _, ex, pub, sink = odom_rig(*args, geometry=())
    left0, right0 = 65_000, 100  # left wraps up through 65535, right down through 0
    for k in range(steps + 1):
        msg = JointState()
        msg.header.stamp = stamp(T0_NS + k * STEP_NS)
        left = (left0 + k * left_inc) % 65536
        right = (right0 + k * right_inc) % 65536
        names = [("caster", 123.0 * k), ("rw", float(right)), ("lw", float(left))]
        if k % 2:
            names.reverse()
        msg.name = [n for n, _ in names]
        msg.position = [v for _, v in names]
        if k == 0:
            send_first(ex, pub, sink, msg)
        else:
            pub.publish(msg)
            spin_for(ex, 0.005)
    last_ns = T0_NS + steps * STEP_NS
    assert spin_until(
        ex, lambda: any(ns_of(o.header.stamp) == last_ns for o in sink.odom), 10.0
    ), f"no odom for the last reading ({len(sink.odom)} received)"
    # /tf goes out right after odom, on its own topic: wait for it as well.
    spin_until(ex, lambda: any(ns_of(t.header.stamp) == last_ns
                               for m in sink.tf for t in m.transforms), 10.0)

    s_left = r * steps * left_inc * 2 * math.pi / tpr
    s_right = r * steps * (-right_inc) * 2 * math.pi / tpr
    ex_x, ex_y, ex_th = oracle.wheel_arc(s_left, s_right, b)  # constant ratio: one arc
    first = min(sink.odom, key=lambda o: ns_of(o.header.stamp))
    assert ns_of(first.header.stamp) == T0_NS
    assert first.pose.pose.position.x == 0.0 and first.pose.pose.position.y == 0.0
    final = max(sink.odom, key=lambda o: ns_of(o.header.stamp))
    p = final.pose.pose
    assert math.isclose(p.position.x, ex_x, abs_tol=1e-9)
    assert math.isclose(p.position.y, ex_y, abs_tol=1e-9)
    assert math.isclose(math.remainder(yaw(p.orientation) - ex_th, 2 * math.pi), 0.0, abs_tol=1e-9)
    assert final.header.frame_id == "odom" and final.child_frame_id == "base_link"
    # Twist in the child frame: constant over the run, so equal to the arc rates.
    dt = STEP_NS * 1e-9
    assert math.isclose(final.twist.twist.linear.x, 0.5 * (s_left + s_right) / (steps * dt),
                        rel_tol=1e-9)
    assert math.isclose(final.twist.twist.angular.z, ex_th / (steps * dt), rel_tol=1e-9)
    assert final.pose.covariance[0] > 0.0 and final.twist.covariance[35] > 0.0
    # Every stamp published is a stamp we sent (never the node's clock).
    sent = {T0_NS + k * STEP_NS for k in range(steps + 1)}
    assert {ns_of(o.header.stamp) for o in sink.odom} <= sent
    tfs = [t for m in sink.tf for t in m.transforms if ns_of(t.header.stamp) == last_ns]
    assert tfs, "no /tf for the last reading"
    t = tfs[-1]
    assert (t.header.frame_id, t.child_frame_id) == ("odom", "base_link")
    assert math.isclose(t.transform.translation.x, ex_x, abs_tol=1e-9)
    assert math.isclose(t.transform.translation.y, ex_y, abs_tol=1e-9)


def test_params_file_namespace_remap_and_reset_service(odom_rig: OdomRigs) -> None:
    """The shipped YAML, a namespace, a remapped input and the reset service."""
    args = ["--params-file", str(ROOT / "config" / "diffdrive_odom.yaml"),
            "-r", "__ns:=/robot1", "-r", "joint_states:=wheel_states"]
    r = 0.042  # config/diffdrive_odom.yaml's example robot
    _, _, node, ex, pub, sink = odom_rig(*args, geometry=(), ns="/robot1",
                                         joints="wheel_states")
    per_step = 0.5 / r / 50  # 0.5 m in 50 steps
    k = drive_straight(pub, ex, sink, 0, 50, per_step)
    last = T0_NS + k * STEP_NS
    assert spin_until(ex, lambda: any(ns_of(o.header.stamp) == last for o in sink.odom), 10.0)
    before = max(sink.odom, key=lambda o: ns_of(o.header.stamp))
    assert math.isclose(before.pose.pose.position.x, 0.5, abs_tol=1e-9)
    assert before.header.frame_id == "robot1/odom"
    assert before.child_frame_id == "robot1/base_link"

    # Asked again until answered: with no reading in between, two resets are one.
    result = call_service(node, ex, Trigger, "/robot1/odometry_node/reset_odometry",
                          Trigger.Request())
    assert result is not None and result.success

    # Drive on from where the wheels are: no jump, 0.25 m more from the origin.
    k2 = drive_straight(pub, ex, sink, k + 1, 24, per_step, prime=False)
    last2 = T0_NS + k2 * STEP_NS
    assert spin_until(ex, lambda: any(ns_of(o.header.stamp) == last2 for o in sink.odom), 10.0)
    after = max(sink.odom, key=lambda o: ns_of(o.header.stamp))
    assert math.isclose(after.pose.pose.position.x, 0.25, abs_tol=1e-9)
    assert after.pose.pose.position.y == 0.0


BAD_PARAMETERS = {
    "wheel_radius": ["-p", "wheel_radius:=-0.1", "-p", "wheel_separation:=0.3"],
    "wheel_separation": ["-p", "wheel_radius:=0.1", "-p", "wheel_separation:=.nan"],
    "right_wheel_names": ["-p", "wheel_radius:=0.1", "-p", "wheel_separation:=0.3",
                          "-p", "right_wheel_names:=['a','b']"],
    "pose_covariance_diagonal": ["-p", "wheel_radius:=0.1", "-p", "wheel_separation:=0.3",
                                 "-p", "pose_covariance_diagonal:=[1.0,2.0]"],
    "enable_odom_tf": ["-p", "wheel_radius:=0.1", "-p", "wheel_separation:=0.3",
                       "-p", "enable_odom_tf:=3"],
    "max_reading_gap": ["-p", "wheel_radius:=0.1", "-p", "wheel_separation:=0.3",
                        "-p", "max_reading_gap:=0.0"],
}


@pytest.mark.parametrize("name", BAD_PARAMETERS)
def test_bad_parameters_stop_the_node_with_their_name(name: str) -> None:
    """Each case in this process (the node's own construction, rcl parsing the -p)."""
    assert_refused_in_process(OdometryNode, name, BAD_PARAMETERS[name])


def test_a_bad_parameter_stops_the_process_with_exit_2_and_one_line() -> None:
    assert_refuses_to_start("odometry_node", "wheel_radius", BAD_PARAMETERS["wheel_radius"])


@pytest.mark.parametrize("executable", ["odometry_node", "cmd_vel_node", "sim_node"])
def test_an_empty_list_of_joints_is_refused_as_what_it_is(executable: str) -> None:
    """``-p left_wheel_names:="[]"``: rcl gives an empty list no type and rclpy hands it
    over as None, which the refusal used to quote (``got None``)."""
    line = assert_refuses_to_start(executable, "left_wheel_names", [
        "-p", "wheel_radius:=0.1", "-p", "wheel_separation:=0.4",
        "-p", "left_wheel_names:=[]"])
    assert "got an empty list" in line and "None" not in line, line


def test_runtime_parameter_refused_with_reason_and_bad_messages_dropped(odom_rig: OdomRigs) -> None:
    r, b = 0.1, 0.4
    args = ["-p", f"wheel_radius:={r}", "-p", f"wheel_separation:={b}"]
    proc, _, node, ex, pub, sink = odom_rig(*args, geometry=())
    bad = set_parameter(node, ex, "/odometry_node", "wheel_radius",
                     ParameterValue(type=ParameterType.PARAMETER_DOUBLE, double_value=-1.0))
    assert not bad.successful and "wheel_radius" in bad.reason
    ok = set_parameter(node, ex, "/odometry_node", "wheel_radius",
                    ParameterValue(type=ParameterType.PARAMETER_DOUBLE, double_value=0.2))
    assert ok.successful

    names = ["left_wheel_joint", "right_wheel_joint"]

    def send(k: int, position: list[float], name: list[str] | None = None) -> None:
        msg = JointState()
        msg.header.stamp = stamp(T0_NS + k * STEP_NS)
        msg.name = name if name is not None else names
        msg.position = position
        pub.publish(msg)
        spin_for(ex, 0.01)

    first = JointState()
    first.header.stamp = stamp(T0_NS)
    first.name, first.position = names, [0.0, 0.0]
    send_first(ex, pub, sink, first)
    send(1, [float("nan"), 1.0])  # NaN: dropped
    send(2, [float("inf"), 1.0])  # inf: dropped
    send(3, [1.0])  # shorter than names: dropped
    send(4, [1.0, 1.0], ["left_wheel_joint"])  # right wheel missing: dropped
    send(5, [1.0, 1.0])  # good: 1 rad on both wheels
    send(5, [9.0, 9.0])  # repeated stamp: dropped
    send(4, [9.0, 9.0])  # slightly older: dropped
    send(6, [1e6, 1e6])  # implausibly fast: skipped, re-anchored
    send(7, [1e6 + 1.0, 1e6 + 1.0])  # good: 1 rad more
    last = T0_NS + 7 * STEP_NS
    assert spin_until(ex, lambda: any(ns_of(o.header.stamp) == last for o in sink.odom), 10.0)
    assert proc.poll() is None, "node died on bad input"
    for o in sink.odom:
        values = [o.pose.pose.position.x, o.pose.pose.position.y, o.pose.pose.orientation.z,
                  o.pose.pose.orientation.w, o.twist.twist.linear.x, o.twist.twist.angular.z]
        assert all(math.isfinite(v) for v in values)
    final = max(sink.odom, key=lambda o: ns_of(o.header.stamp))
    # radius 0.2 after the runtime change: 2 rad of good motion = 0.4 m straight ahead.
    assert math.isclose(final.pose.pose.position.x, 0.4, abs_tol=1e-9)
    assert final.pose.pose.position.y == 0.0


def test_best_effort_publisher_and_sim_time_loop_reset(odom_rig: OdomRigs) -> None:
    """A best-effort driver connects; a bag-like stamp jump back restarts at the origin."""
    r, b = 0.1, 0.4
    args = ["-p", f"wheel_radius:={r}", "-p", f"wheel_separation:={b}",
            "-p", "use_sim_time:=true", "-p", "time_jump_threshold:=0.2"]
    qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.BEST_EFFORT)
    proc, out, _, ex, pub, sink = odom_rig(*args, geometry=(), qos=qos)
    k = drive_straight(pub, ex, sink, 0, 20, 0.5)  # 10 rad -> 1 m
    last = T0_NS + k * STEP_NS
    assert spin_until(ex, lambda: any(ns_of(o.header.stamp) == last for o in sink.odom), 10.0)
    assert math.isclose(
        max(sink.odom, key=lambda o: ns_of(o.header.stamp)).pose.pose.position.x, 1.0,
        abs_tol=1e-9)
    sink.odom.clear()
    # The "bag" starts again: same stamps and wheel angles as at its beginning.
    time.sleep(0.05)
    drive_straight(pub, ex, sink, 0, 10, 0.5)  # 0.5 m in the new run
    last = T0_NS + 10 * STEP_NS
    assert spin_until(ex, lambda: any(ns_of(o.header.stamp) == last for o in sink.odom), 10.0)
    final = [o for o in sink.odom if ns_of(o.header.stamp) == last][-1]
    assert math.isclose(final.pose.pose.position.x, 0.5, abs_tol=1e-9)
    assert proc.poll() is None
    assert out.wait_for("jumped back"), out.text()


def test_publish_rate_throttles_by_stamp_and_tf_can_be_disabled(odom_rig: OdomRigs) -> None:
    """10 Hz out of 50 Hz readings: every fifth stamp, decided by the stamps themselves."""
    pose_diag = [0.002, 0.003, 1e6, 1e6, 1e6, 0.04]
    args = ["-p", "wheel_radius:=0.1", "-p", "wheel_separation:=0.4",
            "-p", "publish_rate:=10.0", "-p", "enable_odom_tf:=false",
            "-p", "covariance_model:=static", "-p", f"pose_covariance_diagonal:={pose_diag}"]
    _, _, _, ex, pub, sink = odom_rig(*args, geometry=())
    k = drive_straight(pub, ex, sink, 0, 50, 0.1)  # 1 s of readings at 50 Hz
    last = T0_NS + k * STEP_NS
    assert spin_until(ex, lambda: any(ns_of(o.header.stamp) == last for o in sink.odom), 10.0)
    spin_for(ex, 0.3)
    stamps = sorted({ns_of(o.header.stamp) for o in sink.odom})
    assert stamps == [T0_NS + i * 100_000_000 for i in range(11)]
    final = max(sink.odom, key=lambda o: ns_of(o.header.stamp))
    assert math.isclose(final.pose.pose.position.x, 0.1 * 0.1 * 50, abs_tol=1e-9)
    assert not any(t.child_frame_id == "base_link" for m in sink.tf for t in m.transforms)
    # covariance_model static: the configured diagonals, as diff_drive_controller does.
    expected_pose = [0.0] * 36
    for i, d in enumerate(pose_diag):
        expected_pose[7 * i] = d
    default_twist = [0.001, 1e-6, 1e6, 1e6, 1e6, 0.01]  # twist_covariance_diagonal default
    expected_twist = [0.0] * 36
    for i, d in enumerate(default_twist):
        expected_twist[7 * i] = d
    assert all(list(o.pose.covariance) == expected_pose for o in sink.odom)
    assert all(list(o.twist.covariance) == expected_twist for o in sink.odom)


def _joint_bag(path: Path, stamps_ns: list[int], positions: list[list[float]]) -> None:
    """The readings sent to the node, as a JointState MCAP (rosbags' own message classes)."""
    from diffdrive_odom.tools.bags import bagio, bagwriter

    with bagwriter.BagWriter(path) as writer:
        writer.add_topic("/joint_states", bagio.JOINT_STATE)
        types: Any = writer.typestore.types
        for ns, position in zip(stamps_ns, positions, strict=True):
            msg = types[bagio.JOINT_STATE](
                header=types["std_msgs/msg/Header"](
                    stamp=types["builtin_interfaces/msg/Time"](sec=ns // 10**9,
                                                               nanosec=ns % 10**9),
                    frame_id=""),
                name=["left_wheel_joint", "right_wheel_joint"],
                position=np.array(position, dtype=np.float64),
                velocity=np.zeros(0), effort=np.zeros(0))
            writer.write("/joint_states", ns, msg)


def test_propagated_covariance_grows_along_a_drive_and_replay_writes_the_same(
    tmp_path: Path, odom_rig: OdomRigs,
) -> None:
    """Straight line, both wheels with noise k: var(x) = k s / 2 and var(yaw) = 2 k s / b^2.

    The closed form is derived in test_uncertainty (Chong and Kleeman's wheel-travel
    model linearised about a straight path); here it is what comes over DDS, and
    ``diffdrive-odom replay`` of the same readings writes the same matrices.
    """
    r, b, k = 0.05, 0.3, 2e-5
    # The wheel-noise part alone (the geometry term has its own closed forms in
    # test_uncertainty): with the geometry's standard deviations at 0. The rotation term
    # is on and adds nothing on a straight line (test_rotation_noise has its closed forms).
    params = write_params(tmp_path / "p.yaml", {
        "wheel_radius": r, "wheel_separation": b,
        "wheel_noise_k_left": k, "wheel_noise_k_right": k, "rotation_noise_k": 1e-3,
        "wheel_radius_stddev_ratio": 0.0, "wheel_separation_stddev_ratio": 0.0})
    per_step, steps = 0.4, 40  # 2 cm per reading, 0.8 m
    _, _, _, ex, pub, sink = odom_rig("--params-file", str(params), geometry=())
    last = T0_NS + drive_straight(pub, ex, sink, 0, steps, per_step) * STEP_NS
    assert spin_until(ex, lambda: any(ns_of(o.header.stamp) == last for o in sink.odom), 10.0)
    live = {ns_of(o.header.stamp): o for o in sink.odom}
    assert len(live) == steps + 1
    var_x = []
    for ns in sorted(live):
        o = live[ns]
        s = o.pose.pose.position.x  # distance driven
        c = list(o.pose.covariance)
        # The model's value on the floor that keeps the message matrix positive definite.
        assert math.isclose(c[0] - COVARIANCE_FLOOR, k * s / 2, rel_tol=1e-9, abs_tol=1e-18)
        assert math.isclose(c[35] - COVARIANCE_FLOOR, 2 * k * s / b**2, rel_tol=1e-9,
                            abs_tol=1e-18)
        assert [c[14], c[21], c[28]] == [1e6, 1e6, 1e6]  # z, roll, pitch: unobserved
        var_x.append(c[0])
    assert var_x[0] == COVARIANCE_FLOOR and all(v > u for u, v in itertools.pairwise(var_x))
    final = live[last]
    dt, h = STEP_NS * 1e-9, r * per_step
    assert math.isclose(final.twist.covariance[0] - COVARIANCE_FLOOR, 2 * k * h / 4 / dt**2,
                        rel_tol=1e-9)
    assert math.isclose(final.twist.covariance[35] - COVARIANCE_FLOOR,
                        2 * k * h / b**2 / dt**2, rel_tol=1e-9)

    bag, out = tmp_path / "in", tmp_path / "out"
    _joint_bag(bag, [T0_NS + i * STEP_NS for i in range(steps + 1)],
               [[i * per_step, i * per_step] for i in range(steps + 1)])
    assert cli(["replay", str(bag), "--params-file", str(params), "-o", str(out)]) == 0
    replayed = {ns_of(m.header.stamp): m for _, _, m in mcap_messages(out, ["/odom"])}
    assert sorted(replayed) == sorted(live)
    # replay integrates this plain drive in its fast lane, whose covariance is the closed
    # (cumulative-sum) form of the node's recursion: equal to rounding, 1e-9 of the largest
    # entry (test_fastlane proves the bound on every reason code).
    for ns, m in replayed.items():
        for got, want in ((m.pose.covariance, live[ns].pose.covariance),
                          (m.twist.covariance, live[ns].twist.covariance)):
            scale = max(abs(want[i]) for i in (0, 1, 5, 6, 7, 11, 30, 31, 35))  # x, y, yaw
            assert all(abs(a - b) <= 1e-9 * scale for a, b in zip(got, want, strict=True))
