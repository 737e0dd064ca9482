"""``replay --online-calibration --reference-topic`` (issue 25 items 4 and 5).

A bag written with rosbags: the issue's route (76 s, 26 m, turns both ways) of a robot
whose mean radius is 0.05 % small and whose track is 1 % wide, its gyro reading 2 %
too much, a PoseStamped reference at 30 Hz on its own clock, 50 ms late, in a frame of
its own (``refstreams``). The block replay prints is checked against the true geometry
in closed form (``r_L/R``, ``r_R/R``, ``b/B``). And the TurtleBot3 (Gazebo) bag, whose
/odom is Gazebo's true pose: the same path reads a real ROS 1 Odometry reference.
"""

from __future__ import annotations

import contextlib
import io
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


MOUNT = (-0.12, 0.20, math.radians(150.0))  # issue 38's marker body: off the axle, turned


def _mounted_replay(folder: Path, how: str) -> str:
    """replay --online-calibration's output on the route with its reference where ``how``
    says: on the axle, or on ``MOUNT`` given as the offset, on /tf_static, or not at all."""
    folder.mkdir()
    tru = truth(ISSUE_ROUTE, *TRUE)
    timing = {t.name: t for t in TIMINGS}["173 Hz jittered"]
    where = Reference() if how == "axle" else Reference(mount=MOUNT)
    messages = merge(stream(ISSUE_ROUTE, timing, math.radians(0.3), 3e-4, 1, tru, SCALE),
                     reference(tru, where, ISSUE_ROUTE.seconds))
    write_sensor_bag(folder / "bag", messages, timing.imu_hz,
                     static=("marker", *MOUNT) if how == "tf_static" else None)
    mount: dict[str, dict[str, object]] = {
        "offset": {"online_calibration_reference_offset": list(MOUNT)},
        "tf_static": {"online_calibration_reference_frame": "marker"}}
    params = write_params(folder / "p.yaml", {
        "wheel_radius": R, "wheel_separation": B, "use_imu": True,
        "wheel_noise_k_left": 0.0, "wheel_noise_k_right": 0.0, "online_calibration": "monitor",
        "online_calibration_reference_type": "pose_stamped",
        "online_calibration_reference_position_stddev": 0.002,
        "online_calibration_reference_heading_stddev": 0.001, **mount.get(how, {})})
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        code = cli(["replay", str(folder / "bag"), "--params-file", str(params),
                    "--online-calibration", "--reference-topic", "/reference"])
    assert code == 0
    return out.getvalue()


@pytest.fixture(scope="module")
def axle(tmp_path_factory: pytest.TempPathFactory) -> dict[str, tuple[float, float]]:
    """The block from the same route and reference noise, the reference on the axle."""
    block = _blocks(_mounted_replay(tmp_path_factory.mktemp("axle") / "run", "axle"))
    rl, rr, b = TRUE
    want = {"left_wheel_radius_multiplier": rl / R, "right_wheel_radius_multiplier": rr / R,
            "wheel_separation_multiplier": b / B}
    assert set(block) == set(want)
    for name, (value, sigma) in block.items():
        assert abs(value - want[name]) < 3 * max(sigma, 1e-5), name
    return block


@pytest.mark.parametrize("how", ["offset", "tf_static", "none"])
def test_replay_takes_a_mounted_reference_s_mount(
        tmp_path: Path, axle: dict[str, tuple[float, float]], how: str) -> None:
    """A reference 0.23 m off the axle and turned 150 deg (issue 38 item 1): replay's
    online calibration moves its poses onto base_link by the mount the params give
    (``online_calibration_reference_offset``) or the bag's /tf_static holds
    (``online_calibration_reference_frame``), and prints the axle's block (the same
    reference noise: within a quarter of its sigma), no pose refused. Not told the
    mount, it refuses poses as outliers (a turn swings the marker sideways) and its
    block moves by more than a sigma."""
    out = _mounted_replay(tmp_path / "run", how)
    block = _blocks(out)
    off = [abs(block[name][0] - value) / sigma for name, (value, sigma) in axle.items()]
    poses = next(x for x in out.splitlines() if x.strip().startswith("reference poses"))
    if how == "none":
        assert "outlier" in poses
        assert max(off) > 1.0
    else:
        assert "outlier" not in poses
        assert max(off) < 0.25, off


def test_replay_says_a_reference_frame_missing_from_tf_static(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """``online_calibration_reference_frame`` with no such transform in the bag: one line
    naming the frame and the parameter to give instead, nothing replayed."""
    tru = truth(ISSUE_ROUTE, *TRUE)
    timing = {t.name: t for t in TIMINGS}["173 Hz jittered"]
    messages = merge(stream(ISSUE_ROUTE, timing, math.radians(0.3), 3e-4, 1, tru, SCALE),
                     reference(tru, Reference(mount=MOUNT), 5.0))
    write_sensor_bag(tmp_path / "bag", messages, timing.imu_hz, static=("camera", *MOUNT))
    params = write_params(tmp_path / "p.yaml", {
        "wheel_radius": R, "wheel_separation": B, "use_imu": True,
        "online_calibration_reference_frame": "marker"})
    code = cli(["replay", str(tmp_path / "bag"), "--params-file", str(params),
                "--online-calibration", "--reference-topic", "/reference"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2
    assert len(err) == 1
    assert "online_calibration_reference_frame marker" in err[0]
    assert "online_calibration_reference_offset" in err[0]


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
