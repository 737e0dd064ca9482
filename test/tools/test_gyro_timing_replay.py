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

import pytest
from gyrostreams import ISSUE_ROUTE, TIMINGS, B, R, Timing, stream, truth

from diffdrive_odom.tools.cli import main as cli

from bagutil import write_params, write_sensor_bag

BIAS = math.radians(0.3)


def _write(path: Path, timing: Timing) -> None:
    write_sensor_bag(path, stream(ISSUE_ROUTE, timing, BIAS, 3e-4), timing.imu_hz)


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
    # The summary says how many updates ran and how long the robot stood.
    assert "4 slip events" in out
    updates = int(out.split(" zero-velocity updates over ")[0].rsplit(" ", 1)[-1])
    # Less HOLD_S after the wheels last moved and the step that closes it: 5.33 s.
    assert updates >= 264 and "over 5.3 s standing still" in out
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
