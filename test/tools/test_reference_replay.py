"""``replay --online-calibration --reference-topic`` (issue 25 items 4 and 5).

A bag written with rosbags: the issue's route (76 s, 26 m, turns both ways) of a robot
whose mean radius is 0.05 % small and whose track is 1 % wide, its gyro reading 2 %
too much, a PoseStamped reference at 30 Hz on its own clock, 50 ms late, in a frame of
its own (``refstreams``). The block replay prints is checked against the true geometry
in closed form (``r_L/R``, ``r_R/R``, ``b/B``). And the TurtleBot3 (Gazebo) bag, whose
/odom is Gazebo's true pose: the same path reads a real ROS 1 Odometry reference.
"""

from __future__ import annotations

import math
import re
from pathlib import Path

import pytest
from gyrostreams import ISSUE_ROUTE, TIMINGS, B, R, stream, truth
from refstreams import Reference, merge, reference

from diffdrive_odom.tools.cli import main as cli

from bagutil import TB3_PARAMS, write_params, write_sensor_bag
from rosutil import DATA

TRUE = (R * 0.998, R * 1.003, B * 1.01)
SCALE = 1.02


def _blocks(out: str) -> dict[str, tuple[float, float]]:
    return {name: (float(value), float(sigma)) for name, value, sigma in re.findall(
        r"^\s+(\w+_multiplier): ([0-9.]+)  # \+- ([0-9.]+)", out, re.M)}


@pytest.mark.parametrize("mode", ["monitor", "disabled"])
def test_replay_recovers_scale_and_gyro_scale_factor(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], mode: str) -> None:
    """``--online-calibration`` runs the estimate (as monitor) even where the params file
    disables it, with the reference and the noise the file gives."""
    tru = truth(ISSUE_ROUTE, *TRUE)
    timing = {t.name: t for t in TIMINGS}["173 Hz jittered"]
    messages = merge(stream(ISSUE_ROUTE, timing, math.radians(0.3), 3e-4, 1, tru, SCALE),
                     reference(tru, Reference(), ISSUE_ROUTE.seconds))
    write_sensor_bag(tmp_path / "bag", messages, timing.imu_hz)
    params = write_params(tmp_path / "p.yaml", {
        "wheel_radius": R, "wheel_separation": B, "use_imu": True,
        "wheel_noise_k_left": 0.0, "wheel_noise_k_right": 0.0, "online_calibration": mode,
        "online_calibration_reference_type": "pose_stamped",
        "online_calibration_reference_position_stddev": 0.002,
        "online_calibration_reference_heading_stddev": 0.001})
    code = cli(["replay", str(tmp_path / "bag"), "--params-file", str(params),
                "--online-calibration", "--reference-topic", "/reference"])
    out = capsys.readouterr().out
    assert code == 0
    assert "the scale from the reference topic" in out
    assert "paste into the parameter file (the scale from the reference)" in out
    rl, rr, b = TRUE
    want = {"left_wheel_radius_multiplier": rl / R, "right_wheel_radius_multiplier": rr / R,
            "wheel_separation_multiplier": b / B}
    block = _blocks(out)
    assert set(block) == set(want)
    for name, (value, sigma) in block.items():
        assert abs(value - want[name]) < 3 * max(sigma, 1e-5), name
    s, ss = (float(v) for v in re.findall(r"gyro scale ([0-9.]+) \+- ([0-9.]+)", out)[0])
    assert abs(s - SCALE) < 3 * ss


def test_replay_turtlebot3_with_its_odom_as_reference(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    params = write_params(tmp_path / "p.yaml", {**TB3_PARAMS, "use_imu": True})
    bag = DATA / "turtlebot3_sim" / "turtlebot3.bag"
    assert cli(["replay", str(bag), "--params-file", str(params), "--reference-topic",
                "/odom"]) == 2
    assert "--reference-topic needs --online-calibration" in capsys.readouterr().err
    assert cli(["replay", str(bag), "--params-file", str(params), "--online-calibration",
                "--reference-topic", "/nope"]) == 2
    assert "topic /nope is not in the bag" in capsys.readouterr().err
    code = cli(["replay", str(bag), "--params-file", str(params), "--online-calibration",
                "--reference-topic", "/odom"])
    out = capsys.readouterr().out
    assert code == 0
    line = next(x for x in out.splitlines() if "with the reference:" in x)
    assert line.endswith(": determined")
    # Gazebo's gyro is exact in scale (its /imu is the simulated body's rate).
    s, ss = (float(v) for v in re.findall(r"gyro scale ([0-9.]+) \+- ([0-9.]+)", line)[0])
    assert abs(s - 1.0) < max(3 * ss, 0.005)
