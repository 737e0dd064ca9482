"""odometry_node with ``use_imu`` over real DDS: JointState and Imu in, odometry and
/diagnostics out (issue 18; Borenstein and Feng, "Gyrodometry", ICRA 1996).

The robot drives straight (both wheels 0.01 rad per 20 ms reading, r = 0.1 m) while
the gyro says it does not turn; for 20 readings the right wheel spins 0.05 rad per
reading more than it rolls. The wheels alone would turn 20 * 0.05 * 0.1 / 0.4 =
0.25 rad; with the gyro the heading stays 0, the distance comes from the left wheel once
the spin is beyond what the stamps' timing explains (the first spinning reading alone
is not: see test below), and one slip event is reported. Then the IMU stops: WARN,
wheels only, no jump.
"""

from __future__ import annotations

import itertools
import math

import pytest
from sensor_msgs.msg import Imu, JointState

from diagutil import diagnosed
from rosutil import (
    GEOMETRY,
    NAMES,
    ROOT,
    STEP_NS,
    T0_NS,
    Output,
    gyro_rig,
    node_process,
    ns_of,
    send_first,
    spin_for,
    spin_until,
    stamp,
    yaw,
)

pytestmark = [pytest.mark.dds, pytest.mark.process]

SLIP = range(21, 41)  # readings whose right wheel spins 0.05 rad extra


def reading(k: int) -> JointState:
    msg = JointState()
    msg.header.stamp = stamp(T0_NS + k * STEP_NS)
    msg.name = list(NAMES)
    extra = 0.05 * sum(1 for j in SLIP if j <= k)
    msg.position = [0.01 * k, 0.01 * k + extra]
    return msg


def gyro(ns: int) -> Imu:
    msg = Imu()
    msg.header.stamp = stamp(ns)
    msg.header.frame_id = "imu_link"
    return msg  # angular_velocity 0: not turning


def test_gyro_aided_node_names_the_slip_keeps_the_heading_and_falls_back() -> None:
    with diagnosed("odometry_node", [*GEOMETRY, "-p", "use_imu:=true"]) as peer:
        ex = peer.executor
        joints, imu, sink = gyro_rig(peer.node, ex)
        for ns in (T0_NS - 10_000_000, T0_NS):
            imu.publish(gyro(ns))
        send_first(ex, joints, sink, reading(0))
        last = 60
        for k in range(1, last + 1):
            for ns in (T0_NS + k * STEP_NS - 10_000_000, T0_NS + k * STEP_NS):  # 100 Hz
                imu.publish(gyro(ns))
            spin_for(ex, 0.002)
            joints.publish(reading(k))
            spin_for(ex, 0.005)
        want = T0_NS + last * STEP_NS
        assert spin_until(ex, lambda: any(ns_of(o.header.stamp) == want for o in sink.odom),
                          10.0)
        end = next(o for o in sink.odom if ns_of(o.header.stamp) == want)
        assert abs(yaw(end.pose.pose.orientation)) < 1e-9  # wheels alone: 0.25 rad
        # The left wheel's 1 mm a reading, but for the first spinning one: its 5 mm of excess
        # is within SPIN_SIGMAS (3) of the timing (the default jitter, 5 ms, at both ends,
        # no lag measured: sqrt(2) * 5 ms) at the wheels' 0.25 m/s apart (5.3 mm), so it
        # keeps the wheels' mean, half its excess too much (core.estimation.gyro.slipstep).
        assert end.pose.pose.position.x == pytest.approx(last * 0.001 + 0.0025, abs=1e-9)
        # A report may come in the middle of the slip: wait for the one after it.
        slipped = peer.wait_for(lambda s: s.values.get("slip steps") == str(len(SLIP)), 10.0)
        assert slipped.values["slip events"] == "1"
        assert float(slipped.values["last slip [stamp s]"]) == pytest.approx(
            (T0_NS + SLIP[-1] * STEP_NS) * 1e-9)
        assert slipped.values["imu"] == "gyro-aided"
        # The IMU stops; the wheels go on for 1 s of stamps: wheels only, WARN, no jump.
        for k in range(last + 1, last + 51):
            joints.publish(reading(k))
            spin_for(ex, 0.005)
        silent = peer.wait_for(lambda s: "IMU silent" in s.message, 10.0)
        assert silent.level == 1 and silent.values["imu"] == "silent (wheels only)"
        want = T0_NS + (last + 50) * STEP_NS
        assert spin_until(ex, lambda: any(ns_of(o.header.stamp) == want for o in sink.odom),
                          10.0)
        poses = sorted((ns_of(o.header.stamp), o.pose.pose.position.x, o.pose.pose.position.y)
                       for o in sink.odom)
        for (t0, x0, y0), (t1, x1, y1) in itertools.pairwise(poses):
            # At most a reading's travel per reading interval: no jump at the switch (the
            # first spinning reading adds half its spin: it keeps the wheels' mean, above).
            steps = (t1 - t0) / STEP_NS
            first_spin = 0.0025 if t0 < T0_NS + SLIP[0] * STEP_NS <= t1 else 0.0
            assert math.hypot(x1 - x0, y1 - y0) <= 0.001 * steps + first_spin + 1e-9


@pytest.mark.slow  # 9 s of the sim's time on the wall clock
def test_sim_node_gyro_and_scripted_slip_through_the_gyro_aided_node() -> None:
    """sim_node (gyro at 100 Hz, the right wheel spinning 10 rad/s extra from 2 s to
    2.5 s of its time) and odometry_node with use_imu, driven straight: the wheels
    alone would turn 10 * 0.5 * 0.033 / 0.16 = 1.03 rad; the gyro-aided odometry stays
    with sim_node's ground truth."""
    from nav_msgs.msg import Odometry
    from std_msgs.msg import Float64MultiArray

    from rosutil import node_process, ros_test_node

    sim_args = ["--ros-args", "-p", "imu_rate:=100.0", "-p", "slip_events:=right 6.0 0.5 10"]
    odom_args = ["--ros-args", "-p", "wheel_radius:=0.033", "-p", "wheel_separation:=0.16",
                 "-p", "use_imu:=true"]
    with node_process("sim_node", sim_args) as sim, \
            node_process("odometry_node", odom_args) as odom, \
            ros_test_node() as (node, ex):
        truth: list[Odometry] = []
        est: list[Odometry] = []
        joints: dict[int, JointState] = {}
        node.create_subscription(Odometry, "ground_truth/odom", truth.append, 50)
        node.create_subscription(JointState, "joint_states",
                                 lambda m: joints.__setitem__(ns_of(m.header.stamp), m), 50)
        node.create_subscription(Odometry, "odom", est.append, 50)
        cmd = node.create_publisher(Float64MultiArray, "wheel_commands", 10)
        assert spin_until(ex, lambda: bool(truth) and bool(est), 20.0), "no output"
        first = ns_of(truth[0].header.stamp)
        while ns_of(truth[-1].header.stamp) - first < 9_000_000_000:
            cmd.publish(Float64MultiArray(data=[5.0, 5.0]))
            spin_for(ex, 0.05)
            assert sim.poll() is None and odom.poll() is None
        cmd.publish(Float64MultiArray(data=[0.0, 0.0]))
        spin_for(ex, 0.3)
    by_stamp = {ns_of(t.header.stamp): t for t in truth}
    # Under load a message of the test's own subscriptions can be lost: pair only the
    # odometry whose reading and truth the test received.
    pairs = [(o, by_stamp[ns_of(o.header.stamp)]) for o in est
             if ns_of(o.header.stamp) in by_stamp and ns_of(o.header.stamp) in joints]
    assert pairs
    o, t = pairs[-1]
    # The odometry starts where the sim was at its first reading: compare motion since.
    o0, t0 = pairs[0]
    # The slip happened in between: the wheels alone would have turned about 1 rad.
    j0, j1 = joints[ns_of(o0.header.stamp)], joints[ns_of(o.header.stamp)]
    wheel_turn = ((j1.position[1] - j0.position[1]) - (j1.position[0] - j0.position[0])) \
        * 0.033 / 0.16
    assert wheel_turn == pytest.approx(10 * 0.5 * 0.033 / 0.16, rel=1e-6)
    d_yaw_est = yaw(o.pose.pose.orientation) - yaw(o0.pose.pose.orientation)
    d_yaw_true = yaw(t.pose.pose.orientation) - yaw(t0.pose.pose.orientation)
    assert abs(math.remainder(d_yaw_est - d_yaw_true, 2 * math.pi)) < 0.05  # wheels: 1.03
    dist_est = math.hypot(o.pose.pose.position.x - o0.pose.pose.position.x,
                          o.pose.pose.position.y - o0.pose.pose.position.y)
    dist_true = math.hypot(t.pose.pose.position.x - t0.pose.pose.position.x,
                           t.pose.pose.position.y - t0.pose.pose.position.y)
    assert dist_true > 0.2 and abs(dist_est - dist_true) < 0.02


@pytest.mark.parametrize(("args", "warned"), [
    ([], False),  # ros2 run with no file: the default monitor, no gyro
    (["--params-file", str(ROOT / "config" / "diffdrive_odom.yaml")], False),  # launch's file
    (["-p", "online_calibration:=apply"], True),
    (["-p", "online_calibration:=apply", "-p", "use_imu:=true"], False),
], ids=["defaults", "shipped_file", "apply_without_imu", "apply_with_imu"])
def test_online_calibration_is_mentioned_at_start_only_when_it_cannot_do_what_was_set(
        args: list[str], warned: bool) -> None:
    """Every start without an IMU used to log 'online_calibration is monitor or apply
    but use_imu is false': the default (monitor: while the gyro is on) contradicted the
    default (no gyro). Now only apply without the gyro is said, once, as a warning."""
    with node_process("odometry_node", ["--ros-args", *GEOMETRY, *args]) as proc:
        out = Output(proc)
        assert out.wait_for("wheel odometry:"), out.text()  # the start's last line
        said = out.matching("online_calibration")
    assert len(said) == warned, out.text()
    if warned:
        assert "WARN" in said[0] and "apply but use_imu is false" in said[0], said
