"""Offline replay: real bags through the node's estimator, outputs read back independently.

References: the robot's own firmware odometry (/firmware/odom), wheel angles integrated
here from first principles (the exact arc), and the step-by-step estimator for the
vectorised path.
"""

from __future__ import annotations

import csv
import dataclasses
import itertools
import json
import math
import os
import tracemalloc
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from rosbags.highlevel import AnyReader

from diffdrive_odom.core.bulk import batch
from diffdrive_odom.core.estimation.config import OdometrySettings
from diffdrive_odom.core.geometry.kinematics import Geometry
from diffdrive_odom.core.uncertainty.propagation import COVARIANCE_FLOOR
from diffdrive_odom.tools.bags import bagio, bagreadings, bagwriter
from diffdrive_odom.tools.cli import main as cli
from diffdrive_odom.tools.cmdline.args import load_settings
from diffdrive_odom.tools.replaying import sinks
from diffdrive_odom.tools.replaying.readings import replay_readings
from diffdrive_odom.tools.replaying.sinks import Published
from diffdrive_odom.wire.conversions import quaternion_to_yaw

import oracle
from bagutil import OPTIODOM_PARAMS, TB3_PARAMS, joint_state_msg, mcap_messages, write_params
from rosutil import DATA

RUNS = ("square_231220200029_run-01", "square_231220200029_run-04")
TB3 = DATA / "turtlebot3_sim" / "turtlebot3.bag"


def _ns(t: Any) -> int:
    return int(t.sec) * 10**9 + int(t.nanosec)


def _settings(tmp_path: Path, values: dict[str, Any]) -> OdometrySettings:
    return load_settings(write_params(tmp_path / "p.yaml", values))


def _published(bag: Path, settings: OdometrySettings) -> list[Published]:
    out: list[Published] = []
    replay_readings(bagreadings.read_joint_states(bag), settings, out.append)
    return out


def _arc_integrate(readings: list[Any], r: float, b: float, left: int, right: int
                   ) -> tuple[float, float, float]:
    """Exact arc per step from the wheel angles (the oracle's, not the package's form)."""
    return oracle.integrate_wheels(
        ((r * (cur.position[left] - prev.position[left]),
          r * (cur.position[right] - prev.position[right]))
         for prev, cur in itertools.pairwise(readings)), b)


@pytest.mark.parametrize("run", RUNS)
def test_optiodom_replay_matches_firmware_and_first_principles(tmp_path: Path, run: str) -> None:
    bag = DATA / "optiodom" / run
    params = write_params(tmp_path / "p.yaml", OPTIODOM_PARAMS)
    out, table = tmp_path / "out", tmp_path / "out.csv"
    assert cli(["replay", str(bag), "--params-file", str(params), "-o", str(out),
                "--csv", str(table)]) == 0
    odoms = [(t, m) for t, _, m in mcap_messages(out, ["/odom"])]
    tfs = [m for _, _, m in mcap_messages(out, ["/tf"])]
    readings = list(bagreadings.read_joint_states(bag))
    assert len(odoms) == len(tfs) == len(readings)  # every reading published, first = origin
    last = odoms[-1][1]
    assert _ns(last.header.stamp) == readings[-1].stamp_ns
    assert last.header.frame_id == "odom" and last.child_frame_id == "base_link"
    # The robot's own dead reckoning of the same encoders, 4 significant digits: ~1 mm.
    with AnyReader([bag], default_typestore=bagio.typestore()) as reader:
        fw: Any = [reader.deserialize(raw, c.msgtype) for c, _, raw in reader.messages()
                   if c.topic == "/firmware/odom"][-1]
    p = last.pose.pose
    assert math.hypot(p.position.x - fw.pose.pose.position.x,
                      p.position.y - fw.pose.pose.position.y) < 1e-3
    heading_gap = quaternion_to_yaw(p.orientation) - quaternion_to_yaw(fw.pose.pose.orientation)
    assert abs(math.remainder(heading_gap, 2 * math.pi)) < 2e-3
    # Exact arcs from the wheel angles (left first in this bag).
    x, y, th = _arc_integrate(readings, 0.042, 0.200, 0, 1)
    assert math.hypot(p.position.x - x, p.position.y - y) < 1e-9
    assert abs(math.remainder(quaternion_to_yaw(p.orientation) - th, 2 * math.pi)) < 1e-9
    # The CSV carries the same poses.
    with open(table, newline="", encoding="utf-8") as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == len(odoms)
    assert int(rows[-1]["stamp_ns"]) == readings[-1].stamp_ns
    assert float(rows[-1]["x"]) == p.position.x and float(rows[-1]["y"]) == p.position.y
    assert rows[0]["status"] == "reference" and rows[1]["status"] == "updated"
    # ... and the diagonal of the bag's propagated pose covariance, which grows as it drives.
    c = list(last.pose.covariance)
    assert [float(rows[-1][k]) for k in ("var_x", "var_y", "var_yaw")] == [c[0], c[7], c[35]]
    assert float(rows[0]["var_yaw"]) == COVARIANCE_FLOOR < c[35]  # at the start: the floor


@pytest.mark.parametrize("run", RUNS)
def test_vectorised_path_equals_the_step_by_step_estimator(tmp_path: Path, run: str) -> None:
    bag = DATA / "optiodom" / run
    settings = _settings(tmp_path, OPTIODOM_PARAMS)
    steps = batch.wheel_steps(bagreadings.read_joint_states(bag), settings)
    x, y, th = batch.integrate_steps(steps, settings.geometry)
    stepwise = [p for p in _published(bag, settings) if p.status.value == "updated"]
    readings = 1385 if run.endswith("04") else 1388  # metadata.yaml
    assert len(stepwise) == len(steps) == readings - 1  # every step after the reference
    sx = np.array([p.pose.x for p in stepwise])
    sy = np.array([p.pose.y for p in stepwise])
    sth = np.array([p.pose.theta for p in stepwise])
    assert np.array_equal(steps.stamp_ns, [p.stamp_ns for p in stepwise])
    assert np.max(np.hypot(x - sx, y - sy)) < 1e-9
    assert np.max(np.abs(np.remainder(th - sth + np.pi, 2 * np.pi) - np.pi)) < 1e-9
    end = batch.final_pose(steps, settings.geometry)
    assert math.hypot(end.x - sx[-1], end.y - sy[-1]) < 1e-9
    # The geometry-free steps serve any geometry (calibration's fitting loop): the same
    # steps with other multipliers equal a fresh estimator run with those multipliers.
    g2 = Geometry(0.042, 0.2, left_wheel_radius_multiplier=1.01,
                         wheel_separation_multiplier=0.99)
    s2 = dataclasses.replace(settings, geometry=g2)
    final2 = replay_readings(bagreadings.read_joint_states(bag), s2).final_pose
    end2 = batch.final_pose(steps, g2)
    assert math.hypot(end2.x - final2.x, end2.y - final2.y) < 1e-9


def test_turtlebot3_ros1_bag_replays_without_a_jump_at_start(tmp_path: Path) -> None:
    settings = _settings(tmp_path, TB3_PARAMS)
    poses = _published(TB3, settings)
    readings = list(bagreadings.read_joint_states(TB3))
    first = poses[0]
    # The first reading (wheels at -4.23 / 9.01 rad, sim time 112.54 s) is the origin.
    assert first.stamp_ns == readings[0].stamp_ns and 112e9 < first.stamp_ns < 113e9
    assert (first.pose.x, first.pose.y, first.pose.theta) == (0.0, 0.0, 0.0)
    # No step anywhere faster than 1 m/s (a Waffle drives at most 0.26 m/s, its slipping
    # simulated wheels spin up to about 0.5 m/s). Integrating the first reading as
    # motion would move >= 0.033 m * 4.23 rad = 0.14 m in one 33 ms step (4 m/s).
    for a, b in itertools.pairwise(poses):
        dt = (b.stamp_ns - a.stamp_ns) * 1e-9
        assert math.hypot(b.pose.x - a.pose.x, b.pose.y - a.pose.y) <= 1.0 * dt
    # Right wheel listed first: the same as integrating columns (1 = left, 0 = right).
    x, y, th = _arc_integrate(readings, 0.033, 0.287, 1, 0)
    end = poses[-1].pose
    assert math.hypot(end.x - x, end.y - y) < 1e-9
    assert abs(math.remainder(end.theta - th, 2 * math.pi)) < 1e-9
    assert math.hypot(x, y) > 1.0  # it did drive somewhere


def test_keep_input_copies_ros1_topics_as_cdr_and_refuses_a_topic_clash(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    params = write_params(tmp_path / "p.yaml", TB3_PARAMS)
    # The bag's /odom is Gazebo's ground truth: the output topic must not clash with it.
    before = set(tmp_path.iterdir())
    assert cli(["replay", str(TB3), "--params-file", str(params), "-o",
                str(tmp_path / "clash"), "--keep-input", "--csv", str(tmp_path / "c.csv")]) == 2
    assert "--odom-topic" in capsys.readouterr().err
    assert set(tmp_path.iterdir()) == before  # a failed replay leaves nothing behind
    out = tmp_path / "out"
    assert cli(["replay", str(TB3), "--params-file", str(params), "-o", str(out),
                "--keep-input", "--odom-topic", "/wheel/odom", "--storage", "sqlite3"]) == 0
    with bagio.open_bag(TB3) as src:
        counts_in = {c.topic: c.msgcount for c in src.connections}
    with bagio.open_bag(out) as dst:
        counts_out = {c.topic: c.msgcount for c in dst.connections}
        gazebo: Any = next(dst.deserialize(raw, c.msgtype) for c, _, raw in dst.messages()
                           if c.topic == "/odom")
        assert not hasattr(gazebo.header, "seq")  # ROS 2 header
    readings = counts_in["/joint_states"]
    assert counts_out == {**counts_in, "/wheel/odom": readings, "/tf": readings}
    assert gazebo.child_frame_id == "base_footprint"


def test_same_parameter_validation_as_the_node(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    bad = write_params(tmp_path / "bad.yaml", {"wheel_radius": -0.1, "wheel_separation": 0.2})
    assert cli(["replay", str(TB3), "--params-file", str(bad)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "wheel_radius" in err[0]
    assert cli(["replay", str(TB3), "--params-file", str(tmp_path / "none.yaml")]) == 2
    # The node's section only: another node's parameters are ignored, "/**" applies.
    doc = tmp_path / "multi.yaml"
    doc.write_text(
        "/**:\n  ros__parameters:\n    wheel_separation: 0.287\n"
        "cmd_vel_node:\n  ros__parameters:\n    wheel_radius: 9.0\n"
        "odometry_node:\n  ros__parameters:\n    wheel_radius: 0.033\n"
        "    odom_frame_id: odom\n    tf_frame_prefix: robot1\n", encoding="utf-8")
    s = load_settings(doc)
    assert s.geometry.wheel_radius == 0.033 and s.geometry.wheel_separation == 0.287
    assert s.odom_frame_id == "robot1/odom" and s.base_frame_id == "robot1/base_link"
    # -r __ns:=/robot2: the namespaced section wins and the prefix is the namespace.
    ns_doc = tmp_path / "ns.yaml"
    ns_doc.write_text(
        "/**:\n  ros__parameters:\n    wheel_radius: 0.05\n    wheel_separation: 0.3\n"
        "/robot2/odometry_node:\n  ros__parameters:\n    wheel_radius: 0.07\n",
        encoding="utf-8")
    s2 = load_settings(ns_doc, namespace="/robot2")
    assert s2.geometry.wheel_radius == 0.07 and s2.odom_frame_id == "robot2/odom"
    assert load_settings(ns_doc).geometry.wheel_radius == 0.05


def test_publish_rate_and_frames_follow_the_params(tmp_path: Path) -> None:
    bag = DATA / "optiodom" / RUNS[1]
    params = write_params(tmp_path / "p.yaml", {**OPTIODOM_PARAMS, "publish_rate": 5.0,
                                                "enable_odom_tf": False,
                                                "base_frame_id": "base_footprint"})
    out = tmp_path / "out"
    assert cli(["replay", str(bag), "--params-file", str(params), "-o", str(out)]) == 0
    odoms = [m for _, _, m in mcap_messages(out)]
    assert all(m.child_frame_id == "base_footprint" for m in odoms)  # and no /tf at all
    stamps = [_ns(m.header.stamp) for m in odoms]
    assert oracle.mean_rate(stamps) == pytest.approx(5.0, rel=0.01)  # 20 Hz data, 5 Hz out
    assert len(stamps) == pytest.approx(69.2 * 5, abs=2)


def _write_run(path: Path, stamps: list[int], wheels: list[tuple[float, float]],
               storage: str = "mcap") -> None:
    """JointState bag; logged 1 ms apart in list order, whatever the stamps."""
    with bagwriter.BagWriter(path, storage) as w:
        w.add_topic("/joint_states", bagio.JOINT_STATE)
        t = w.typestore.types
        for k, (ns, (left, right)) in enumerate(zip(stamps, wheels, strict=True)):
            w.write("/joint_states", 10**9 + k * 10**6, joint_state_msg(t, ns, left, right))


def test_replay_refuses_what_the_node_refuses(
        tmp_path: Path, capfd: pytest.CaptureFixture[str]) -> None:
    """A pose whose covariance is not finite is not written, as the node does not publish
    it (both ask core.estimation.publication): a 3e-301 m axle (0.3 m times a separation
    multiplier of 1e-300, which the parameter checks accept) driven straight. Only the
    reference reading's pose goes out; the rest are counted."""
    values = {"wheel_radius": 0.05, "wheel_separation": 0.3, "wheel_separation_multiplier": 1e-300}
    settings = _settings(tmp_path, values)
    n = 20
    bag = tmp_path / "tiny_axle"
    _write_run(bag, [10**9 + k * 20_000_000 for k in range(n)], [(0.1 * k, 0.1 * k)
                                                                 for k in range(n)])
    poses: list[Published] = []
    stats = replay_readings(bagreadings.read_joint_states(bag), settings, poses.append)
    assert stats.pipeline.published == n
    assert stats.refused == {"non-finite covariance suppressed": n - 1}
    assert stats.published == len(poses) == 1
    assert all(map(math.isfinite, [*poses[0].pose_covariance, *poses[0].twist_covariance]))
    assert math.isclose(stats.final_pose.x, 0.05 * 0.1 * (n - 1), abs_tol=1e-12)
    out, table = tmp_path / "out", tmp_path / "out.csv"
    params = write_params(tmp_path / "q.yaml", values)
    capfd.readouterr()
    assert cli(["replay", str(bag), "--params-file", str(params), "-o", str(out),
                "--csv", str(table)]) == 0
    captured = capfd.readouterr()
    assert f"[replay] non-finite covariance suppressed: {n - 1} pose(s) not written" \
        in captured.err
    assert f"{n} readings" in captured.out and "-> 1 poses" in captured.out
    odoms = [m for _, _, m in mcap_messages(out, ["/odom"])]
    assert len(odoms) == 1
    assert all(map(math.isfinite, [*odoms[0].pose.covariance, *odoms[0].twist.covariance]))
    assert len(table.read_text().splitlines()) == 2  # the header and the one pose


@pytest.mark.process
def test_a_looped_bag_restarts_both_paths_at_the_origin(tmp_path: Path) -> None:
    """Stamps jumping back (a bag recorded from a looped play) restart the pose."""
    r, b = 0.05, 0.25
    settings = _settings(tmp_path, {"wheel_radius": r, "wheel_separation": b})
    n = 100  # 2 s per run: the jump back is over time_jump_threshold (1 s)
    # A circle arc: left 0.1 rad, right 0.2 rad per 20 ms step; then the same again.
    stamps = [10**9 + k * 20_000_000 for k in range(n)] * 2
    wheels = [(0.1 * k, 0.2 * k) for k in range(n)] * 2
    bag = tmp_path / "looped"
    _write_run(bag, stamps, wheels)
    # The reordering must not merge the two runs.
    readings = list(bagreadings.read_joint_states(bag))
    assert [r.stamp_ns for r in readings] == stamps
    poses: list[Published] = []
    stats = replay_readings(readings, settings, poses.append)
    assert stats.statuses["time_reset"] == 1
    steps = batch.wheel_steps(readings, settings)
    assert steps.segments == 2 and len(steps) == 2 * (n - 1)
    # Closed form: constant ds, dtheta per step -> arc of radius ds/dtheta.
    ds, dth = r * 0.15, r * 0.1 / b
    k = n - 1
    x_end, y_end, _ = oracle.arc(k * ds, k * dth)
    end = stats.final_pose
    assert math.hypot(end.x - x_end, end.y - y_end) < 1e-12
    vec = batch.final_pose(steps, settings.geometry)
    assert math.hypot(vec.x - x_end, vec.y - y_end) < 1e-12
    restart = next(i for i, p in enumerate(poses) if p.status.value == "time_reset")
    assert (poses[restart].pose.x, poses[restart].pose.y) == (0.0, 0.0)
    first_run = [(p.pose.x, p.pose.y) for p in poses[:restart]]
    second_run = [(p.pose.x, p.pose.y) for p in poses[restart:]]
    assert first_run == second_run


@pytest.mark.process
def test_streaming_memory_does_not_grow_with_the_bag(tmp_path: Path) -> None:
    settings = _settings(tmp_path, {"wheel_radius": 0.05, "wheel_separation": 0.25})
    peaks = []
    # sqlite3 both ways: its pages are small, so any growth would show. (MCAP holds one
    # chunk, a few MB whatever the length: bench/bench_replay.py measures it.)
    for n in (2_000, 8_000):
        bag = tmp_path / f"long{n}"
        _write_run(bag, [10**9 + k * 10**7 for k in range(n)],
                   [(0.01 * k, 0.011 * k) for k in range(n)], "sqlite3")
        out = tmp_path / f"out{n}"
        tracemalloc.start()
        with bagwriter.BagWriter(out, "sqlite3") as w:
            w.add_topic("/odom", bagio.ODOMETRY)
            w.add_topic("/tf", bagio.TF_MESSAGE)
            stats = replay_readings(bagreadings.read_joint_states(bag), settings,
                                           sinks.OutputSink(settings, w, None))
        peaks.append(tracemalloc.get_traced_memory()[1])
        tracemalloc.stop()
        assert stats.published == n
    # Four times the bag, the same peak.
    assert peaks[1] < 1.2 * peaks[0] + 100_000, peaks


def test_replay_eval_in_one_go_equals_eval_on_the_output(tmp_path: Path) -> None:
    bag = DATA / "optiodom" / RUNS[1]
    params = write_params(tmp_path / "p.yaml", OPTIODOM_PARAMS)
    one, two = tmp_path / "one.json", tmp_path / "two.json"
    out = tmp_path / "out"
    assert cli(["replay", str(bag), "--params-file", str(params), "-o", str(out),
                "--eval", "--json", str(one), "--plot", str(tmp_path / "p.png")]) == 0
    assert cli(["eval", str(out), "--odom", "/odom", "--reference-bag", str(bag),
                "--json", str(two)]) == 0
    a, b = json.loads(one.read_text()), json.loads(two.read_text())
    assert a.keys() == b.keys()
    for key in a:
        assert a[key] == pytest.approx(b[key], abs=1e-12), key
    assert a["final_position_error_m"] == pytest.approx(0.1075, abs=5e-4)
    assert (tmp_path / "p.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_progress_line_on_request(tmp_path: Path, capfd: pytest.CaptureFixture[str]) -> None:
    params = write_params(tmp_path / "p.yaml", TB3_PARAMS)
    assert cli(["replay", str(TB3), "--params-file", str(params), "--progress",
                "--csv", str(tmp_path / "o.csv")]) == 0
    captured = capfd.readouterr()
    assert "2.74k/2.74k readings (100 %)" in captured.err  # total from the bag index
    assert "2741 readings" in captured.out


def _write_joint_bag(path: Path, readings: list[tuple[int, list[str], list[float]]]) -> None:
    """A JointState MCAP written with rosbags directly (not the package's writer).

    Logged at the stamp, as a recorder on a synced clock logs on receipt: replay takes
    the log time as the receive time, which tells a driver's pause from its clock jumping.
    """
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_JAZZY)
    types: Any = store.types
    msgtype = "sensor_msgs/msg/JointState"
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as w:
        conn = w.add_connection("/joint_states", msgtype, typestore=store)
        for ns, names, position in readings:
            sec, nsec = divmod(ns, 10**9)
            msg = types[msgtype](
                header=types["std_msgs/msg/Header"](
                    stamp=types["builtin_interfaces/msg/Time"](sec=sec, nanosec=nsec),
                    frame_id=""),
                name=names, position=np.array(position, dtype=np.float64),
                velocity=np.zeros(0), effort=np.zeros(0))
            w.write(conn, ns, store.serialize_cdr(msg, msgtype))


def test_a_driver_restart_after_a_pause_keeps_the_pose_in_replay(tmp_path: Path) -> None:
    """Counters 0 -> 20 rad, 4 s without readings, counters from 0 to 5 rad: 25 rad ahead."""
    r = 0.05
    settings = _settings(tmp_path, {"wheel_radius": r, "wheel_separation": 0.25})
    names = ["left_wheel_joint", "right_wheel_joint"]
    t0, step = 10**9, 20_000_000
    run = [(t0 + k * step, names, [0.4 * k, 0.4 * k]) for k in range(51)]
    restart = t0 + 50 * step + 4 * 10**9
    run += [(restart + k * step, names, [0.2 * k, 0.2 * k]) for k in range(26)]
    bag = tmp_path / "restart"
    _write_joint_bag(bag, run)
    stats = replay_readings(bagreadings.read_joint_states(bag), settings)
    assert stats.pipeline.gap_reanchors == 1 and stats.reasons["gap"] == 1
    assert math.isclose(stats.final_pose.x, r * 25.0, abs_tol=1e-12)
    assert stats.final_pose.y == 0.0
    steps = batch.wheel_steps(bagreadings.read_joint_states(bag), settings)
    assert steps.segments == 1 and len(steps) == 50 + 25
    assert math.isclose(batch.final_pose(steps, settings.geometry).x, r * 25.0, abs_tol=1e-12)
    out = tmp_path / "out"
    params = write_params(tmp_path / "q.yaml", {"wheel_radius": r, "wheel_separation": 0.25})
    assert cli(["replay", str(bag), "--params-file", str(params), "-o", str(out)]) == 0
    last = [m for _, _, m in mcap_messages(out, ["/odom"])][-1]
    assert math.isclose(last.pose.pose.position.x, r * 25.0, abs_tol=1e-12)


def test_wrong_joint_names_exit_2_naming_both_lists_and_write_nothing(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    wrong = ["wheel_left", "wheel_right"]
    bag = tmp_path / "wrong"
    _write_joint_bag(bag, [(10**9 + k * 10**7, wrong, [0.1 * k, 0.1 * k]) for k in range(20)])
    params = write_params(tmp_path / "p.yaml", {"wheel_radius": 0.05, "wheel_separation": 0.25})
    out, table = tmp_path / "out", tmp_path / "out.csv"
    assert cli(["replay", str(bag), "--params-file", str(params), "-o", str(out),
                "--csv", str(table)]) == 2
    captured = capsys.readouterr()
    err = [ln for ln in captured.err.splitlines() if ln.strip()]
    assert len(err) == 1, captured.err
    assert "no usable reading" in err[0] and "20 x missing_joint" in err[0]
    for name in ("left_wheel_joint", "right_wheel_joint", "wheel_left", "wheel_right"):
        assert name in err[0], err[0]
    assert not out.exists() and not table.exists()


def test_a_replay_with_nothing_to_do_says_so_before_working(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    params = write_params(tmp_path / "p.yaml", TB3_PARAMS)
    assert cli(["replay", str(TB3), "--params-file", str(params)]) == 2
    captured = capsys.readouterr()
    assert "nothing to do" in captured.err and captured.out == ""  # no replay ran


def test_unusable_outputs_and_inputs_are_one_line_before_any_work(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    params = write_params(tmp_path / "p.yaml", TB3_PARAMS)
    base = ["replay", str(TB3), "--params-file", str(params)]
    (tmp_path / "a_dir").mkdir()
    not_a_bag = tmp_path / "notes.txt"
    not_a_bag.write_text("not a bag\n")
    cases = {
        "--csv": [*base, "--csv", str(tmp_path / "no" / "such" / "dir.csv")],
        "-o": [*base, "-o", str(tmp_path / "a_dir")],
        "--plot": [*base, "--csv", str(tmp_path / "o.csv"), "--eval", "/odom",
                   "--plot", str(tmp_path / "a_dir")],
        "not a readable bag": ["replay", str(not_a_bag), "--params-file", str(params),
                               "--csv", str(tmp_path / "o.csv")],
        "--params-file": [*base[:2], "--params-file", str(tmp_path / "nope.yaml"), "--csv",
                          str(tmp_path / "o.csv")],
    }
    for name, argv in cases.items():
        assert cli(argv) == 2, name
        captured = capsys.readouterr()
        lines = captured.err.strip().splitlines()
        assert len(lines) == 1 and name in lines[0], (name, captured.err)
        assert captured.out == "", name
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a_dir", "notes.txt", "p.yaml"]


def test_replay_eval_finds_a_ground_truth_topic_by_its_name(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A bag whose ground truth is on /ground_truth/odom, as sim_node and the demo write."""
    src = DATA / "optiodom" / RUNS[1]
    bag = tmp_path / "sim_like"
    with bagio.open_bag(src) as reader, bagwriter.BagWriter(bag) as writer:
        for conn in reader.connections:
            name = "/ground_truth/odom" if conn.topic == "/ground_truth/pose" else conn.topic
            writer.add_topic(name, conn.msgtype)
        for conn, log_ns, raw in reader.messages():
            name = "/ground_truth/odom" if conn.topic == "/ground_truth/pose" else conn.topic
            writer.write_cdr(name, log_ns, bytes(raw))
    params = write_params(tmp_path / "p.yaml", OPTIODOM_PARAMS)
    figures = tmp_path / "m.json"
    assert cli(["replay", str(bag), "--params-file", str(params), "--eval",
                "--json", str(figures)]) == 0
    assert "using /ground_truth/odom" in capsys.readouterr().err
    # run-04, nominal geometry: 0.1075 m from motion capture (the figure doc/tools/eval.md quotes)
    assert json.loads(figures.read_text())["final_position_error_m"] == pytest.approx(
        0.1075, abs=5e-4)


@pytest.mark.process
def test_a_killed_runs_hidden_partial_output_is_removed_by_the_next_and_named(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A run killed outright (SIGKILL) cannot remove its staging directory, which is
    hidden (``.NAME.partial-PID``): the next run for the same output removes it and says
    where it was; one whose process still runs is left alone."""
    import signal
    import subprocess
    import sys

    out = tmp_path / "odom.csv"
    writer = subprocess.Popen([sys.executable, "-c", (
        "import sys, time\n"
        "from diffdrive_odom.tools.cmdline.outputs import staged\n"
        f"with staged({str(out)!r}) as p:\n"
        "    p.write_text('half written')\n"
        "    print('staged', flush=True)\n"
        "    time.sleep(120)\n")], stdout=subprocess.PIPE, text=True)
    alive = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(120)"])
    try:
        assert writer.stdout is not None and writer.stdout.readline() == "staged\n"
        os.kill(writer.pid, signal.SIGKILL)
        writer.wait(10)
        stale = tmp_path / f".odom.csv.partial-{writer.pid}"
        assert (stale / "odom.csv").read_text() == "half written"  # left behind, hidden
        running = tmp_path / f".odom.csv.partial-{alive.pid}"
        running.mkdir()
        params = write_params(tmp_path / "p.yaml", OPTIODOM_PARAMS)
        bag = DATA / "optiodom" / "square_231220200029_run-04"
        assert cli(["replay", str(bag), "--params-file", str(params), "--csv", str(out)]) == 0
        err = capsys.readouterr().err
        assert not stale.exists() and running.is_dir() and out.is_file()
        assert f"removed {stale}: the partial output of an earlier run for {out}" in err, err
        assert str(running) not in err
    finally:
        for proc in (writer, alive):
            if proc.poll() is None:
                proc.kill()
                proc.wait(10)
