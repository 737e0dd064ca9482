"""``replay -p open_loop:=true`` over a bag of velocity commands only (no joint_states).

The bag is written with rosbags directly (not the package's writer): a 20 Hz sender on
its own jittered clock drives a 1 m square, each command logged at its arrival, with a
ground truth (PoseStamped at 10 Hz) that is the closed form of what a robot executing the
commands does (test/oracle.py arcs). Every published pose must match that closed form
at its stamp, and ``--eval`` must find it there.
"""

from __future__ import annotations

import csv
import json
import math
import random
from pathlib import Path
from typing import Any

import pytest

from diffdrive_odom.core.motion import routes
from diffdrive_odom.tools.cli import main as cli

import oracle
from bagutil import write_params

pytestmark = pytest.mark.filterwarnings("ignore::DeprecationWarning")

T0 = 1_600_000_000_000_000_000
PARAMS = {"wheel_radius": 0.05, "wheel_separation": 0.3, "publish_rate": 30.0}
TIMEOUT_NS = 500_000_000


def commands_of(route: routes.Route, seed: int) -> list[tuple[int, float, float]]:
    """(arrival ns, v, w) of a jittered 20 Hz sender with a transport delay."""
    rng = random.Random(seed)
    out, t = [], 0.013
    while t < route.duration + 0.2:
        v, w = route.command_at(t)
        out.append((T0 + round((t + rng.uniform(0.001, 0.004)) * 1e9), v, w))
        t += 0.05 + rng.gauss(0.0, 0.002)
    return out


def truth_at(commands: list[tuple[int, float, float]], t_ns: int) -> oracle.Pose:
    """Where the commanded robot is at ``t_ns``: each command held to the next or its timeout."""
    arcs = []
    for k, (t, v, w) in enumerate(commands):
        if t >= t_ns:
            break
        stop = commands[k + 1][0] if k + 1 < len(commands) else t_ns
        dt = (min(stop, t + TIMEOUT_NS, t_ns) - t) * 1e-9
        arcs.append((v * dt, w * dt))
    return oracle.integrate(arcs)


def write_command_bag(path: Path, commands: list[tuple[int, float, float]], stamped: bool,
                      end_ns: int) -> None:
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_JAZZY)
    types: Any = store.types
    twist_t = "geometry_msgs/msg/TwistStamped" if stamped else "geometry_msgs/msg/Twist"
    pose_t = "geometry_msgs/msg/PoseStamped"

    def header(ns: int, frame: str) -> Any:
        sec, nsec = divmod(ns, 10**9)
        return types["std_msgs/msg/Header"](
            stamp=types["builtin_interfaces/msg/Time"](sec=sec, nanosec=nsec), frame_id=frame)

    def vector(x: float, z: float) -> Any:
        return types["geometry_msgs/msg/Vector3"](x=x, y=0.0, z=z)

    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as w:
        cmd = w.add_connection("/cmd_vel", twist_t, typestore=store)
        gt = w.add_connection("/ground_truth/pose", pose_t, typestore=store)
        events = [(t, 0, v, wz) for t, v, wz in commands]
        events += [(t, 1, 0.0, 0.0) for t in range(commands[0][0], end_ns + 1, 100_000_000)]
        for t, kind, v, wz in sorted(events):
            if kind == 0:
                twist = types["geometry_msgs/msg/Twist"](linear=vector(v, 0.0),
                                                         angular=vector(0.0, wz))
                # A sender's stamp a little before the arrival: held for the timeout from it.
                msg = types[twist_t](header=header(t, "base_link"), twist=twist) \
                    if stamped else twist
                w.write(cmd, t, store.serialize_cdr(msg, twist_t))
                continue
            x, y, th = truth_at(commands, t)
            pose = types["geometry_msgs/msg/Pose"](
                position=types["geometry_msgs/msg/Point"](x=x, y=y, z=0.0),
                orientation=types["geometry_msgs/msg/Quaternion"](
                    x=0.0, y=0.0, z=math.sin(th / 2), w=math.cos(th / 2)))
            w.write(gt, t, store.serialize_cdr(types[pose_t](header=header(t, "world"),
                                                              pose=pose), pose_t))


@pytest.mark.parametrize("stamped", [False, True])
def test_replay_of_a_commands_only_bag_is_the_commanded_route(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], stamped: bool
) -> None:
    route = routes.square(1.0)
    commands = commands_of(route, seed=7)
    end = commands[-1][0] + 2 * 10**9
    bag = tmp_path / "commands"
    write_command_bag(bag, commands, stamped, end)
    params = write_params(tmp_path / "p.yaml", {**PARAMS, "enable_stamped_cmd_vel": stamped})
    # Without open_loop: no wheel readings in this bag, and replay says which topics it has.
    assert cli(["replay", str(bag), "--params-file", str(params), "--csv",
                str(tmp_path / "no.csv")]) == 2
    assert "/joint_states is not in the bag" in capsys.readouterr().err
    out, figures = tmp_path / "o.csv", tmp_path / "f.json"
    assert cli(["replay", str(bag), "--params-file", str(params), "-p", "open_loop:=true",
                "--csv", str(out), "--eval", "--json", str(figures)]) == 0
    captured = capsys.readouterr()
    assert "open loop: odometry from the commanded velocity on /cmd_vel" in captured.err
    assert f"{len(commands)} commands (taken {len(commands)}) -> " in captured.out
    with open(out) as f:
        rows = list(csv.DictReader(f))
    # The node's timer: publish_rate 30 Hz from the first command to the end of the bag.
    assert len(rows) == pytest.approx((end - commands[0][0]) * 30e-9, abs=1.5)
    worst = 0.0
    for row in rows:
        x, y, th = truth_at(commands, int(row["stamp_ns"]))
        worst = max(worst, abs(float(row["x"]) - x), abs(float(row["y"]) - y),
                    abs(math.remainder(float(row["yaw"]) - th, math.tau)))
    assert worst < 1e-12, worst
    last = rows[-1]
    assert (float(last["linear"]), float(last["angular"])) == (0.0, 0.0)  # timed out
    assert float(last["var_yaw"]) > 0.01  # a command is not a measurement
    got = json.loads(figures.read_text())
    assert got["final_position_error_m"] < 1e-9
    # The ground truth is matched to the odometry by interpolating between its 30 Hz poses,
    # which rounds off where a command changed between two of them.
    assert got["ate_rmse_m"] < 1e-3


def test_a_nan_command_is_refused_and_counted(tmp_path: Path,
                                              capsys: pytest.CaptureFixture[str]) -> None:
    commands = [(T0, 0.5, 0.0), (T0 + 100_000_000, math.nan, 0.0)]
    bag = tmp_path / "nan"
    write_command_bag(bag, commands, False, T0 + 10**9)
    params = write_params(tmp_path / "p.yaml", PARAMS)
    out = tmp_path / "o.csv"
    assert cli(["replay", str(bag), "--params-file", str(params), "-p", "open_loop:=true",
                "--csv", str(out)]) == 0
    err = capsys.readouterr().err
    assert "1 x non_finite" in err
    with open(out) as f:
        rows = list(csv.DictReader(f))
    assert float(rows[-1]["x"]) == pytest.approx(0.5 * 0.5, abs=1e-15)  # held to the timeout


def test_eval_of_a_commands_only_bag_says_how_to_judge_it(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    bag = tmp_path / "commands"
    write_command_bag(bag, [(T0, 0.5, 0.0)], False, T0 + 10**9)
    assert cli(["eval", str(bag)]) == 2
    err = capsys.readouterr().err
    assert "topic /odom is not in the bag" in err
    assert "velocity commands (/cmd_vel)" in err and "-p open_loop:=true --eval" in err


def test_calibrate_and_the_gyro_refuse_open_loop(tmp_path: Path,
                                                 capsys: pytest.CaptureFixture[str]) -> None:
    bag = tmp_path / "commands"
    write_command_bag(bag, [(T0, 0.5, 0.0)], False, T0 + 10**9)
    params = write_params(tmp_path / "p.yaml", PARAMS)
    assert cli(["calibrate", str(bag), "--params-file", str(params),
                "-p", "open_loop:=true"]) == 2
    assert "open_loop is true: calibrate fits the wheel geometry" in capsys.readouterr().err
    assert cli(["replay", str(bag), "--params-file", str(params), "-p", "open_loop:=true",
                "-p", "use_imu:=true", "--csv", str(tmp_path / "o.csv")]) == 2
    err = capsys.readouterr().err
    assert "invalid parameter 'use_imu': cannot be true with open_loop" in err
    assert len(err.strip().splitlines()) == 1


def test_the_turtlebot3_bags_commands_end_within_their_covariance(tmp_path: Path) -> None:
    """A real recording's /cmd_vel (ROS 1 bag, Gazebo): open loop ends metres from Gazebo's
    /odom, and its covariance says so (within 3 sigma on each axis), read with rosbags."""
    from rosbags.highlevel import AnyReader

    from bagutil import TB3_PARAMS
    from rosutil import DATA

    bag = DATA / "turtlebot3_sim" / "turtlebot3.bag"
    poses = []
    with AnyReader([bag]) as reader:
        conns = [c for c in reader.connections if c.topic == "/odom"]
        for conn, _, raw in reader.messages(connections=conns):
            p = reader.deserialize(raw, conn.msgtype).pose.pose
            q = p.orientation
            poses.append((p.position.x, p.position.y,
                          math.atan2(2 * (q.w * q.z + q.x * q.y), 1 - 2 * (q.y**2 + q.z**2))))
    (x0, y0, t0), (x1, y1, _) = poses[0], poses[-1]
    c, s = math.cos(t0), math.sin(t0)  # Gazebo's end in the frame of its start
    gx, gy = c * (x1 - x0) + s * (y1 - y0), -s * (x1 - x0) + c * (y1 - y0)
    params = write_params(tmp_path / "p.yaml", {**TB3_PARAMS, "open_loop": True})
    out = tmp_path / "o.csv"
    assert cli(["replay", str(bag), "--params-file", str(params), "--csv", str(out)]) == 0
    with open(out) as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == pytest.approx(91.3 * 50, rel=0.01)  # 50 Hz at publish_rate 0
    last = rows[-1]
    dx, dy = float(last["x"]) - gx, float(last["y"]) - gy
    assert math.hypot(dx, dy) > 1.0  # a command is not a measurement ...
    assert abs(dx) < 3 * math.sqrt(float(last["var_x"]))  # ... and the covariance says so
    assert abs(dy) < 3 * math.sqrt(float(last["var_y"]))
