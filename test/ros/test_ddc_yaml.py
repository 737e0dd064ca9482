"""A diff_drive_controller controllers file carries over to both nodes, unchanged.

test/data/diffbot_controllers.yaml is written as ros2_control_demos' diffbot writes one
(``diffbot_base_controller:`` section, dotted and nested limits, the deprecated
``has_*_limits`` switches, ``min_acceleration``, zero jerks with jerk limits off). Both
nodes run on it with ``-r __node:=diffbot_base_controller``; expected values are the
file's own numbers and the kinematics, not the code under test.
"""

from __future__ import annotations

import math
import time

import pytest
from geometry_msgs.msg import Twist
from nav_msgs.msg import Odometry
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray
from tf2_msgs.msg import TFMessage

from rosutil import (
    DATA,
    node_parameters,
    node_process,
    ros_test_node,
    spin_for,
    spin_until,
    wait_matched,
)

pytestmark = [pytest.mark.dds, pytest.mark.process]

DDC = str(DATA / "diffbot_controllers.yaml")
ARGS = ["--ros-args", "--params-file", DDC, "-r", "__node:=diffbot_base_controller"]
FQN = "/diffbot_base_controller"
# The file's robot.
R, B = 0.04, 0.24
R_LEFT, R_RIGHT, SEP = R * 0.99, R * 1.01, B * 1.02
IGNORED = "diff_drive_controller parameters with no meaning here (ignored): " \
          "position_feedback, use_stamped_vel"


def report_lines(out: str) -> tuple[list[str], list[str]]:
    lines = out.splitlines()
    return ([ln for ln in lines if "no meaning here" in ln],
            [ln for ln in lines if "unknown parameters" in ln])


def test_odometry_node_takes_the_controllers_file() -> None:
    # The file's covariance diagonals are published as diff_drive_controller does with
    # covariance_model static (the propagated default computes them instead).
    args = [*ARGS, "-p", "covariance_model:=static"]
    with node_process("odometry_node", args) as proc, ros_test_node() as (node, ex):
        got = node_parameters(node, ex, FQN, [
            "wheel_radius", "wheel_separation", "left_wheel_radius_multiplier",
            "right_wheel_radius_multiplier", "wheel_separation_multiplier", "publish_rate",
            "odom_frame_id", "base_frame_id", "pose_covariance_diagonal",
            "twist_covariance_diagonal", "enable_odom_tf", "left_wheel_names",
            "right_wheel_names"])
        assert got == {
            "wheel_radius": 0.04, "wheel_separation": 0.24,
            "left_wheel_radius_multiplier": 0.99, "right_wheel_radius_multiplier": 1.01,
            "wheel_separation_multiplier": 1.02, "publish_rate": 25.0,
            "odom_frame_id": "odom", "base_frame_id": "base_footprint",
            "pose_covariance_diagonal": [0.002] * 5 + [0.02],
            "twist_covariance_diagonal": [0.003] * 5 + [0.03],
            "enable_odom_tf": False,
            "left_wheel_names": ["wheel_l_joint"], "right_wheel_names": ["wheel_r_joint"],
        }
        odom: list[Odometry] = []
        tf: list[TFMessage] = []
        odom_sub = node.create_subscription(Odometry, "/odom", odom.append, 50)
        node.create_subscription(TFMessage, "/tf", tf.append, 50)
        pub = node.create_publisher(JointState, "/joint_states", 10)
        assert wait_matched(node, ex, pub, odom_sub)

        def reading(sec: int, left: float, right: float) -> JointState:
            js = JointState(name=["wheel_l_joint", "wheel_r_joint"], position=[left, right])
            js.header.stamp.sec = sec
            return js

        for _ in range(100):  # the reference reading, until the node answers it
            pub.publish(reading(100, 0.0, 0.0))
            if spin_until(ex, lambda: bool(odom), 0.2):
                break
        pub.publish(reading(101, 1.0, 1.0))  # one radian on each wheel, 1 s later
        assert spin_until(ex, lambda: any(o.header.stamp.sec == 101 for o in odom), 10.0)
        spin_for(ex, 0.3)
        assert proc.poll() is None
    last = next(o for o in odom if o.header.stamp.sec == 101)
    # Arcs on the file's radii; one step about the centre of rotation.
    s_left, s_right = R_LEFT, R_RIGHT
    theta = (s_right - s_left) / SEP
    radius = 0.5 * (s_left + s_right) / theta
    p = last.pose.pose.position
    assert math.isclose(p.x, radius * math.sin(theta), abs_tol=1e-12)
    assert math.isclose(p.y, radius * (1.0 - math.cos(theta)), abs_tol=1e-12)
    assert (last.header.frame_id, last.child_frame_id) == ("odom", "base_footprint")
    assert list(last.pose.covariance[::7]) == [0.002] * 5 + [0.02]
    assert not tf, "enable_odom_tf: false in the file"
    out = proc.stdout.read() if proc.stdout else ""
    ignored, unknown = report_lines(out)
    assert len(ignored) == 1 and IGNORED in ignored[0], out
    assert not unknown, out


def test_cmd_vel_node_takes_the_controllers_file_with_ddc_meanings() -> None:
    """has_jerk_limits: false makes the 0.0 jerks no limit (the node used to exit on
    them); has_acceleration_limits: false drops angular.z.max_acceleration: 0.3."""
    wheels: list[tuple[float, list[float]]] = []
    with node_process("cmd_vel_node", ARGS) as proc, ros_test_node() as (node, ex):
        node.create_subscription(
            Float64MultiArray, "/wheel_commands",
            lambda m: wheels.append((time.monotonic(), list(m.data))), 50)
        pub = node.create_publisher(Twist, "/cmd_vel", 10)
        assert spin_until(ex, lambda: pub.get_subscription_count() > 0 and bool(wheels), 20.0), (
            "cmd_vel_node never connected: " + (proc.stdout.read() if proc.poll() is not None
                                                and proc.stdout else "(running)"))

        def drive(v: float, w: float, seconds: float) -> float:
            start = time.monotonic()
            msg = Twist()
            msg.linear.x, msg.angular.z = v, w
            while time.monotonic() - start < seconds:
                pub.publish(msg)
                spin_for(ex, 0.05)
            return start

        turn_start = drive(0.0, 5.0, 1.0)
        turn = [d for t, d in wheels if t >= turn_start and any(x != 0.0 for x in d)]
        drive(0.0, 0.0, 1.5)  # stops at once: no angular acceleration limit either way
        line_start = drive(5.0, 0.0, 2.5)
        line = [d for t, d in wheels if t >= line_start and any(x != 0.0 for x in d)]
        assert proc.poll() is None
    # Angular: capped at max_velocity 2.0 from the very first command (no ramp at 0.3).
    w = 2.0
    assert turn, "no wheel command while turning"
    assert math.isclose(turn[0][0], -w * SEP / 2 / R_LEFT, rel_tol=1e-9), turn[0]
    assert math.isclose(turn[0][1], w * SEP / 2 / R_RIGHT, rel_tol=1e-9), turn[0]
    # Linear: ramps at max_acceleration 0.5 m/s^2 (0.8 s to 0.4 m/s), then max_velocity.
    v_max = 0.4
    assert line and line[0][0] * R_LEFT < 0.1 * v_max, line[0]
    assert math.isclose(line[-1][0], v_max / R_LEFT, rel_tol=1e-9), line[-1]
    assert math.isclose(line[-1][1], v_max / R_RIGHT, rel_tol=1e-9), line[-1]
    out = proc.stdout.read() if proc.stdout else ""
    ignored, unknown = report_lines(out)
    assert len(ignored) == 1 and IGNORED in ignored[0], out
    assert not unknown, out
