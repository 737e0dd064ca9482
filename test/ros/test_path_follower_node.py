"""path_follower_node in the closed loop over real DDS: sim, cmd_vel, odometry, follower.

The four console scripts run as processes in lockstep with the sim (it steps its clock
and physics only once the loop has answered the last step: as fast as the machine
allows, and the same run however loaded it is); the test's own node is in the loop too,
listens to the sim's ground truth and computes the errors itself from closed forms
(distance of Kumar's point P to a line, a circle, a square), never from what the
follower reports. Kumar, "Kinematics of Wheeled Robots", eq. 23: the path error of P
decays as exp(-k_p t); eq. 26: the speed error decays to zero.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from contextlib import ExitStack, contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from geometry_msgs.msg import PoseStamped, Twist
from nav_msgs.msg import Odometry
from nav_msgs.msg import Path as PathMsg
from std_msgs.msg import Bool

from diffdrive_odom.ros.path_follower_node import PathFollowerNode
from diffdrive_odom.ros.qos import DONE_QOS, qos
from diffdrive_odom.settings.params import yaml_text

from rosutil import (
    assert_refused_in_process,
    assert_refuses_to_start,
    loop_peer,
    node_process,
    spin_until,
)

pytestmark = [pytest.mark.dds, pytest.mark.process]

R, B = 0.05, 0.30
L = 0.1  # look-ahead of P [m]
V = 0.3  # desired speed [m/s]
PEER = "follower_test_peer"  # the test's node, in the loop
LOOP = ["odometry_node", "path_follower_node", "cmd_vel_node", PEER]


def ns(stamp: Any) -> float:
    return int(stamp.sec) + int(stamp.nanosec) * 1e-9


@dataclass
class Truth:
    """Ground truth samples: time [s, simulated], P's position, heading and speed."""

    t: list[float] = field(default_factory=list)
    px: list[float] = field(default_factory=list)
    py: list[float] = field(default_factory=list)
    speed: list[float] = field(default_factory=list)
    done: list[bool] = field(default_factory=list)
    command_t: list[float] = field(default_factory=list)  # truth's time at each cmd_vel

    def add(self, msg: Odometry) -> None:
        p, q = msg.pose.pose.position, msg.pose.pose.orientation
        theta = 2.0 * math.atan2(q.z, q.w)
        self.t.append(ns(msg.header.stamp))
        self.px.append(p.x + L * math.cos(theta))
        self.py.append(p.y + L * math.sin(theta))
        self.speed.append(msg.twist.twist.linear.x)

    def arrays(self) -> tuple[np.ndarray, ...]:
        t = np.array(self.t)
        return t, np.array(self.px), np.array(self.py), np.array(self.speed)

    def command(self, _: Twist) -> None:
        if self.t:
            self.command_t.append(self.t[-1])

    def longest_command_gap(self) -> str:
        """Simulated seconds the loop went without a new command, said by a failing
        assertion (in lockstep one step, 20 ms, whatever the machine's load)."""
        gap = float(np.max(np.diff(self.command_t))) if len(self.command_t) > 1 else math.inf
        return f"longest gap between commands {gap:.3f} s (simulated)"

    def moving_since(self) -> float:
        """Simulated time of the first sample with the robot moving."""
        t, _, _, v = self.arrays()
        return float(t[np.argmax(np.abs(v) > 1e-3)])


def write_params(tmp: Path, follower: dict[str, Any], sim: dict[str, Any] | None = None,
                 odometry: dict[str, Any] | None = None) -> Path:
    sections = {
        "/**": {"wheel_radius": R, "wheel_separation": B, "use_sim_time": True,
                "lockstep": True},
        "sim_node": {"use_sim_time": False, "joint_state_rate": 50.0, "lockstep_nodes": LOOP,
                     **(sim or {})},
        "odometry_node": odometry or {},
        "path_follower_node": {"follower.look_ahead": L, "follower.desired_speed": V,
                               **follower},
    }
    lines = []
    for node, values in sections.items():
        if not values:
            continue
        lines.append(f"{node}:\n  ros__parameters:")
        lines += [f"    {k}: {yaml_text(v)}" for k, v in values.items()]
    path = tmp / "params.yaml"
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


def line_path(y: float) -> PathMsg:
    """The line y = ``y`` along +x, on the path topic."""
    msg = PathMsg()
    msg.header.frame_id = "odom"
    for x in (0.0, 20.0):
        ps = PoseStamped()
        ps.pose.position.x, ps.pose.position.y = x, y
        msg.poses.append(ps)
    return msg


@contextmanager
def closed_loop(params: Path, path: PathMsg | None = None
                ) -> Iterator[tuple[Any, Truth]]:
    """The test's node in the loop, listening to the truth, then the four nodes; all
    stopped afterwards. ``path``: sent at the loop's first step (the robot at rest at the
    origin), so the whole motion is recorded."""
    with loop_peer(PEER) as (node, executor, loop), ExitStack() as stack:
        truth = Truth()
        loop.subscription(Odometry, "/ground_truth/odom", truth.add, qos(500, reliable=True))
        loop.subscription(Twist, "/cmd_vel", truth.command, qos(500, reliable=True))
        loop.subscription(Bool, "/path_follower_node/done",
                          lambda m: truth.done.append(bool(m.data)), DONE_QOS)
        if path is not None:
            send = loop.publish(node.create_publisher(PathMsg, "/path", 1))

            def first_step(now_ns: int) -> None:
                loop.on_clock.remove(first_step)
                send(path)

            loop.on_clock.append(first_step)
        procs = [stack.enter_context(node_process(name, ["--ros-args", "--params-file",
                                                         str(params)]))
                 for name in ("sim_node", "cmd_vel_node", "odometry_node",
                              "path_follower_node")]
        assert spin_until(executor, lambda: truth.t, 60.0), "no ground truth"
        assert all(p.poll() is None for p in procs)
        yield executor, truth


def spin_sim(executor: Any, truth: Truth, seconds: float, timeout: float = 60.0) -> None:
    """Spin until ``seconds`` of simulated time have passed since the robot moved."""
    start: list[float] = []

    def enough() -> bool:
        if not start:
            if truth.speed and abs(truth.speed[-1]) > 1e-3:
                start.append(truth.t[-1])
            return False
        return truth.t[-1] - start[0] >= seconds

    assert spin_until(executor, enough, timeout), "the robot did not drive long enough"


def test_path_error_decays_at_the_rate_k_p_predicts(tmp_path: Path) -> None:
    """Robot at the origin heading +x, line y = -0.3 given on the path topic."""
    k_p, offset = 1.0, 0.3
    # omega starts at k_p e1 / l = 3 rad/s: above the default bound, so lift it.
    params = write_params(tmp_path, {"follower.k_p": k_p, "follower.path_type": "none",
                                     "follower.max_angular_velocity": 5.0})
    with closed_loop(params, line_path(-offset)) as (executor, truth):
        spin_sim(executor, truth, 5.0)
    t, _, py, _ = truth.arrays()
    e = py + offset  # gamma(P) of the line: P's signed distance, left positive
    t0 = truth.moving_since()
    assert abs(e[t >= t0][0] - offset) < 0.02
    window = (t >= t0) & (e < 0.8 * offset) & (e > 0.03 * offset)
    assert window.sum() > 20
    slope = np.polyfit(t[window], np.log(e[window]), 1)[0]
    gap = truth.longest_command_gap()
    assert abs(-slope - k_p) < 0.2 * k_p, f"decay rate {-slope:.3f}/s, k_p = {k_p}/s; {gap}"
    assert np.all(np.abs(e[t > t0 + 4.5]) < 0.03 * offset), gap


def test_integral_feedback_removes_the_speed_error_of_a_5_percent_wheel(tmp_path: Path) -> None:
    """Wheels 5 % larger than cmd_vel_node believes; odometry calibrated to the truth."""
    true_r = 1.05 * R
    params = write_params(
        tmp_path,
        {"follower.k_i": 1.0, "follower.path_type": "none"},
        sim={"true_left_wheel_radius": true_r, "true_right_wheel_radius": true_r},
        odometry={"left_wheel_radius_multiplier": 1.05, "right_wheel_radius_multiplier": 1.05})
    with closed_loop(params, line_path(0.0)) as (executor, truth):
        spin_sim(executor, truth, 7.0)
    t, _, _, v = truth.arrays()
    t0 = truth.moving_since()
    early = (t > t0 + 0.1) & (t < t0 + 0.4)
    late = t > t0 + 6.0
    # Open loop the 5 % larger wheel drives 5 % too fast; the integral (k_i = 1/s)
    # has removed that after 6 time constants.
    gap = truth.longest_command_gap()
    assert np.mean(V - v[early]) < -0.03 * V, (np.mean(v[early]), gap)
    assert abs(np.mean(V - v[late])) < 0.005 * V, (np.mean(v[late]), gap)


def test_circle_is_followed_with_a_bounded_cross_track_error(tmp_path: Path) -> None:
    params = write_params(tmp_path, {"follower.k_p": 2.0, "follower.path_type": "circle",
                                     "follower.circle": [0.0, 1.0, 1.0]})
    with closed_loop(params) as (executor, truth):
        spin_sim(executor, truth, 2.0 * math.pi / V + 1.0)
    t, px, py, _ = truth.arrays()
    e = np.hypot(px, py - 1.0) - 1.0
    moving = t >= truth.moving_since()
    gap = truth.longest_command_gap()
    assert np.max(np.abs(e[moving])) < 0.01, (np.max(np.abs(e[moving])), gap)


def square_distance(x: np.ndarray, y: np.ndarray, side: float) -> np.ndarray:
    """Distance to the boundary of the square [0, side]^2 (closed form)."""
    dx = np.maximum(np.maximum(-x, x - side), 0.0)
    dy = np.maximum(np.maximum(-y, y - side), 0.0)
    outside = np.hypot(dx, dy)
    inside = np.minimum(np.minimum(x, side - x), np.minimum(y, side - y))
    return np.asarray(np.where((dx > 0) | (dy > 0), outside, inside), dtype=float)


def test_square_is_followed_with_the_error_peaking_at_the_corners(tmp_path: Path) -> None:
    """In lockstep: a loop process descheduled no longer leaves the wheels on a stale
    command meanwhile. Free-running at 4x real time a 250 ms stall of cmd_vel_node as P
    entered the third fillet (SIGSTOP) put P 0.139 m off at (1.85, 2.14), the flake's
    signature (0.11-0.22 m off there, about 1 run in 7 on a loaded machine), and the test
    had to run in real time; in lockstep the same stall changes nothing
    (test_lockstep.py), and the largest error is the fillet's own."""
    side, corner = 2.0, 0.25
    params = write_params(tmp_path, {"follower.k_p": 2.0, "follower.path_type": "route",
                                     "follower.route": "square", "follower.route_size": side,
                                     "follower.corner_radius": corner})
    with closed_loop(params) as (executor, truth):
        assert spin_until(executor, lambda: truth.done[-1:] == [True], 120.0), "not done"
        end = truth.t[-1]
        assert spin_until(executor, lambda: truth.t[-1] > end + 1.0, 10.0)
    t, px, py, v = truth.arrays()
    e = square_distance(px, py, side)
    corners = np.array([(0, 0), (side, 0), (side, side), (0, side)], dtype=float)
    to_corner = np.min(np.hypot(px[:, None] - corners[:, 0], py[:, None] - corners[:, 1]),
                       axis=1)
    # A fillet of radius rho cut into a right angle lies at most rho (1 - 1/sqrt 2)
    # from the sides (its midpoint); P on the fillet peaks there.
    fillet_gap = corner * (1.0 - 1.0 / math.sqrt(2.0))
    gap = truth.longest_command_gap()
    assert np.max(e) < fillet_gap + 0.01, (np.max(e), gap)
    assert to_corner[np.argmax(e)] < corner, gap
    assert np.max(e[to_corner > 2.0 * corner]) < 0.02, (np.max(e[to_corner > 2.0 * corner]), gap)
    assert np.all(np.abs(v[t > t[-1] - 0.5]) < 1e-3), "not stopped after done"
    assert math.hypot(px[-1] - 0.0, py[-1] - 0.0) < 0.1  # back at the start


_BASE = ["-p", f"wheel_radius:={R}", "-p", f"wheel_separation:={B}"]
BAD_PARAMETERS = {
    "follower.look_ahead": [*_BASE, "-p", "follower.look_ahead:=0.0"],
    "follower.k_p": [*_BASE, "-p", "follower.k_p:=-1.0"],
    "follower.path_type": [*_BASE, "-p", "follower.path_type:=spiral"],
    "follower.points": [*_BASE, "-p", "follower.path_type:=line",
                        "-p", "follower.points:=[0.0, 0.0, 1.0]"],
}


@pytest.mark.parametrize("name", BAD_PARAMETERS)
def test_bad_parameters_stop_the_node_with_one_line(name: str) -> None:
    """Each case in this process (the node's own construction, rcl parsing the -p)."""
    assert_refused_in_process(PathFollowerNode, name, BAD_PARAMETERS[name])


def test_a_bad_parameter_stops_the_process_with_exit_2_and_one_line() -> None:
    assert_refuses_to_start("path_follower_node", "follower.look_ahead",
                            BAD_PARAMETERS["follower.look_ahead"])
