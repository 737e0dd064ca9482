"""``replay -p use_imu:=true`` on a bag of the issue's run, the IMU on its own clock.

The bag is written with rosbags (MCAP), each message logged at its receive time
(``gyrostreams``: the IMU's stamps 5 ms early, the issue's live case that gave no
zero-velocity update at all), so replay meets what a recording of a real robot holds.
The truth comes from ``gyrostreams``, not from the package.
"""

from __future__ import annotations

import csv
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from gyrostreams import ISSUE_ROUTE, NAMES, TIMINGS, B, R, Timing, stream, truth
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore

from diffdrive_odom.tools.cli import main as cli

from bagutil import write_params

STORE = get_typestore(Stores.ROS2_JAZZY)
JS, IMU = "sensor_msgs/msg/JointState", "sensor_msgs/msg/Imu"
BIAS = math.radians(0.3)


def _stamp(ns: int) -> Any:
    sec, nsec = divmod(ns, 10**9)
    return STORE.types["builtin_interfaces/msg/Time"](sec=sec, nanosec=nsec)


def _header(ns: int, frame: str) -> Any:
    return STORE.types["std_msgs/msg/Header"](stamp=_stamp(ns), frame_id=frame)


def _write(path: Path, timing: Timing) -> None:
    t = STORE.types
    zero3 = t["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0)
    cov = np.zeros(9)
    cov[8] = 3e-4 ** 2 * timing.imu_hz  # honest: the density times the rate
    writer = Writer(path, version=9, storage_plugin=StoragePlugin.MCAP)
    with writer:
        joints = writer.add_connection("/joint_states", JS, typestore=STORE)
        imu = writer.add_connection("/imu", IMU, typestore=STORE)
        for kind, rx, stamp, a, b in stream(ISSUE_ROUTE, timing, BIAS, 3e-4):
            if kind == "j":
                msg = t[JS](header=_header(stamp, ""), name=list(NAMES),
                            position=np.array([a, b]), velocity=np.zeros(0),
                            effort=np.zeros(0))
                writer.write(joints, rx, bytes(STORE.serialize_cdr(msg, JS)))
            else:
                msg = t[IMU](
                    header=_header(stamp, "base_link"),
                    orientation=t["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
                    orientation_covariance=np.array([-1.0, *[0.0] * 8]),
                    angular_velocity=t["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=a),
                    angular_velocity_covariance=cov, linear_acceleration=zero3,
                    linear_acceleration_covariance=np.zeros(9))
                writer.write(imu, rx, bytes(STORE.serialize_cdr(msg, IMU)))


def _replay(tmp_path: Path, bag: Path, capsys: pytest.CaptureFixture[str],
            **values: object) -> tuple[float, str, str]:
    """The final heading error [rad] against the truth, replay's stdout and stderr."""
    params = write_params(tmp_path / "p.yaml", {"wheel_radius": R, "wheel_separation": B,
                                                **values})
    out = tmp_path / "o.csv"
    assert cli(["replay", str(bag), "--params-file", str(params), "--csv", str(out)]) == 0
    with open(out) as f:
        yaw = float(list(csv.DictReader(f))[-1]["yaw"])
    th = truth(ISSUE_ROUTE).at(ISSUE_ROUTE.seconds)[2]
    said = capsys.readouterr()
    return abs(math.remainder(yaw - th, 2 * math.pi)), said.out, said.err


def test_replay_of_a_bag_with_the_imu_stamping_early(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    bag = tmp_path / "early"
    _write(bag, TIMINGS[2])  # stamped 5 ms early
    wheels, _, _ = _replay(tmp_path, bag, capsys)
    gyro, out, err = _replay(tmp_path, bag, capsys, use_imu=True)
    assert gyro < math.radians(3.3) and gyro * 10 < wheels
    # The summary says how many updates ran and how long the robot stood (5.6 s).
    assert "4 slip events" in out
    updates = int(out.split(" zero-velocity updates over ")[0].rsplit(" ", 1)[-1])
    assert updates >= 270 and "over 5.6 s standing still" in out
    assert "warning" not in err.lower() or "imu" not in err


def test_replay_names_an_imu_on_its_own_clock_and_receive_time_fixes_it(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    bag = tmp_path / "device"
    _write(bag, Timing("device clock", imu_offset=-1000.0))
    _, out, err = _replay(tmp_path, bag, capsys, use_imu=True)
    assert err.count("imu header stamps are 1000.00") == 1 and "imu_stamp_source" in err
    assert "no zero-velocity update" in err and " 0 zero-velocity updates" in out
    gyro, out, err = _replay(tmp_path, bag, capsys, use_imu=True,
                             imu_stamp_source="receive_time")
    assert gyro < math.radians(3.3) and "imu header stamps" not in err
    assert "4 slip events" in out
