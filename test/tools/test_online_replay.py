"""``replay --online-calibration`` on a bag written with rosbags (issue 25 item 2).

The bag holds the issue's route twice (53 m, turns both ways) of a robot whose right
wheel is 0.5 % larger and whose track is 1 % wider than configured, the IMU stamping
5 ms early, each message logged at its receive time (``gyrostreams``). What replay
prints is checked against the true geometry in closed form, not against the package.
"""

from __future__ import annotations

import math
import re
from importlib.resources import files
from pathlib import Path

import numpy as np
import pytest
from gyrostreams import ISSUE_ROUTE, TIMINGS, B, R, Route, stream, truth

from diffdrive_odom.tools.cli import main as cli

from bagutil import TB3_PARAMS, write_params, write_sensor_bag
from rosutil import DATA

TRUE = (R, R * 1.005, B * 1.01)
JITTERED = {t.name: t for t in TIMINGS}["173 Hz jittered"]
MIXED = Route(ISSUE_ROUTE.segments * 2)


def _replay(tmp_path: Path, capsys: pytest.CaptureFixture[str], route: Route,
            *extra: str, **values: object) -> tuple[int, str, str]:
    bag = tmp_path / f"bag{len(list(tmp_path.iterdir()))}"
    write_sensor_bag(bag, stream(route, JITTERED, math.radians(0.3), 3e-4, 1,
                                 truth(route, *TRUE)), JITTERED.imu_hz)
    params = write_params(tmp_path / "p.yaml", {
        "wheel_radius": R, "wheel_separation": B, "wheel_noise_k_left": 0.0,
        "wheel_noise_k_right": 0.0, **values})
    code = cli(["replay", str(bag), "--params-file", str(params), "--online-calibration",
                *extra])
    said = capsys.readouterr()
    return code, said.out, said.err


def test_replay_prints_the_estimate_and_a_block_to_paste(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    png = tmp_path / "online.png"
    code, out, err = _replay(tmp_path, capsys, MIXED, "--plot", str(png), use_imu=True)
    assert code == 0, err
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"  # the estimate over the run, drawn
    _assert_whole_and_titled(png, f"online calibration of {Path(_last_bag(tmp_path)).name}")
    assert f"online calibration plot: {png}" in out
    assert "online calibration (gyro" in out and "final:" in out
    assert "outside the estimate's 3-sigma region" in out
    block = {name: (float(value), float(sigma)) for name, value, sigma in re.findall(
        r"^\s+(\w+_multiplier): ([0-9.]+)  # \+- ([0-9.]+)", out, re.M)}
    rl, rr, b = TRUE
    want = {"left_wheel_radius_multiplier": 2 * rl / (rl + rr),
            "right_wheel_radius_multiplier": 2 * rr / (rl + rr),
            "wheel_separation_multiplier": 2 * R * b / ((rl + rr) * B)}
    assert set(block) == set(want)
    for name, (value, sigma) in block.items():
        assert abs(value - want[name]) < 3 * max(sigma, 1e-5)  # printed to 5 decimals
    assert "online calibration: the configured geometry is outside" in err  # the warning


def _last_bag(tmp_path: Path) -> Path:
    return max(tmp_path.glob("bag*"), key=lambda p: p.stat().st_mtime)


def _assert_whole_and_titled(png: Path, title: str) -> None:
    """Nothing drawn runs off the image (its four edges are background: the legend in
    four columns ran past both sides), and the PNG's Title says what it shows."""
    from PIL import Image

    with Image.open(png) as im:
        assert im.info.get("Title", "").startswith(title), im.info
        rgb = np.asarray(im.convert("RGB"))
    edges = np.concatenate([rgb[0], rgb[-1], rgb[:, 0], rgb[:, -1]])
    assert (edges == 255).all(), "something drawn touches the image's edge (cut off)"


def test_replay_says_when_not_determined_and_needs_the_gyro(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    straight = Route(((20.0, 0.5, 0.0), (20.0, 0.4, 0.0)))
    code, out, _ = _replay(tmp_path, capsys, straight, use_imu=True)
    assert code == 0
    assert "not yet determined" in out and "nothing to paste" in out
    assert "_multiplier:" not in out
    # use_imu false: --online-calibration turns it on, the bag having its gyro, and says so.
    code, out, err = _replay(tmp_path, capsys, straight)
    assert code == 0, err
    assert "--online-calibration: use_imu on" in err and "gyro is on /imu" in err
    assert "not yet determined" in out
    # A bag without the gyro where it is looked for: one line naming the topic.
    code, out, err = _replay(tmp_path, capsys, straight, "--imu-topic", "/no_imu")
    assert code == 2 and not out
    assert "--online-calibration needs the gyro" in err and "sensor_msgs/Imu on /no_imu" in err
    assert len(err.strip().splitlines()) == 1, err


def test_the_demos_params_file_needs_no_third_file(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The trial's case: the demo's params file sets use_imu: false in its odometry_node
    section, which beats any ``-p use_imu:=true`` (rclpy's order). ``--online-calibration``
    alone gives what a file with use_imu: true in that section gives, line for line."""
    bag = tmp_path / "bag"
    write_sensor_bag(bag, stream(MIXED, JITTERED, math.radians(0.3), 3e-4, 1,
                                 truth(MIXED, *TRUE)), JITTERED.imu_hz)
    demo = files("diffdrive_odom") / "data" / "demo_params.yaml"
    text = demo.read_text(encoding="utf-8")
    assert "odometry_node:\n  ros__parameters:" in text and "    use_imu: false\n" in text
    gyro = tmp_path / "demo_with_gyro.yaml"
    gyro.write_text(text.replace("    use_imu: false\n", "    use_imu: true\n"), encoding="utf-8")
    # The bag's positions are radians (the demo's encoders count ticks): in /**, after it.
    radians = ["-p", "ticks_per_revolution:=0.0", "-p", "encoder_counter_bits:=0"]
    said = {}
    for name, params, extra in (("implied", str(demo), []),
                                ("implied, -p too", str(demo), ["-p", "use_imu:=true"]),
                                ("in the file", str(gyro), [])):
        code = cli(["replay", str(bag), "--params-file", params, *radians, *extra,
                    "--online-calibration"])
        said[name] = capsys.readouterr()
        assert code == 0, said[name].err
    report = {name: s.out.splitlines()[1:] for name, s in said.items()}  # not the timing
    assert "final:" in said["in the file"].out and "_multiplier:" in said["in the file"].out
    assert report["implied"] == report["in the file"]
    assert report["implied, -p too"] == report["in the file"]
    for name in ("implied", "implied, -p too"):
        assert "--online-calibration: use_imu on" in said[name].err
        assert "does not get" not in said[name].err  # the -p is not lost: it is what runs
    assert "use_imu on" not in said["in the file"].err


def test_replay_of_the_turtlebot3_bag_excludes_its_slips_and_warns_not(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Recorded (Gazebo) data whose wheels slip: the estimate is determined, the slipping
    steps are left out, and no warning that the robot changed: Gazebo's geometry is the
    configured one. (Its windows scatter beyond their noise model, the slips' doing:
    before the covariance took their variance factor, the configured geometry crossed
    the 3-sigma line early on and was warned of, falsely. The warning's throttling is
    test_online_geometry's.)"""
    bag = DATA / "turtlebot3_sim" / "turtlebot3.bag"
    params = write_params(tmp_path / "p.yaml", {**TB3_PARAMS, "use_imu": True})
    code = cli(["replay", str(bag), "--params-file", str(params), "--online-calibration"])
    said = capsys.readouterr()
    assert code == 0, said.err
    final = next(line for line in said.out.splitlines() if "final:" in line)
    assert final.endswith(": determined")
    slips = int(re.search(r"excluded: .*slip (\d+)", said.out).group(1))  # type: ignore[union-attr]
    assert slips > 100
    assert said.err.count("online calibration: the configured geometry") == 0
