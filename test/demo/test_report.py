"""The demo's pure parts: settings, the squares' paths, the table, distances, the plot.

No DDS: these run in milliseconds, with values from geometry, not from a run.
"""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

import numpy as np
import pytest
import yaml

from diffdrive_odom.core.evaluation.metrics import Trajectory
from diffdrive_odom.demo import evaluation, report, settings
from diffdrive_odom.demo.report import (
    FIT,
    GYRO,
    NOMINAL,
    TRUE,
    UMBMARK,
    WHEELS,
    DemoResult,
    ImuReading,
    JointSample,
    Recording,
    Row,
    Square,
)
from diffdrive_odom.demo.settings import DemoError, DemoOptions


def test_each_square_starts_and_ends_where_the_axle_starts() -> None:
    ahead = 0.1
    cw = settings.square_path(4.0, True, ahead)
    ccw = settings.square_path(4.0, False, ahead)
    o = settings.START_OFFSET_M
    assert cw[0] == cw[-1] == ccw[0] == ccw[-1] == (ahead, 0.0)  # P with the axle at the origin
    # UMBmark's 4 m corners, the start o into the first leg; CW turns right (y < 0).
    assert cw[1:-1] == [(4 - o, 0), (4 - o, -4), (-o, -4), (-o, 0)]
    assert ccw[1:-1] == [(4 - o, 0), (4 - o, 4), (-o, 4), (-o, 0)]


@pytest.mark.parametrize("change, flag", [
    ({"route": "circle"}, "--route"), ({"side": 0.5}, "--size"),
    ({"speed": -1.0}, "--linear"), ({"max_angular": math.nan}, "--angular")])
def test_bad_options_are_refused_naming_the_option(change: dict[str, object],
                                                   flag: str) -> None:
    opts = DemoOptions(**change)  # type: ignore[arg-type]
    with pytest.raises(DemoError, match=flag):
        settings.check_options(opts)


def test_override_syntax() -> None:
    assert settings.parse_override("slip_stddev:=0.0") == ("slip_stddev", "0.0")
    with pytest.raises(DemoError, match="NAME:=VALUE"):
        settings.parse_override("slip_stddev=0")
    assert settings.yaml_value("0.0505") == 0.0505 and settings.yaml_value("true") is True


def test_settings_come_from_the_shipped_file_with_the_run_s_follower_values() -> None:
    s = settings.load_settings(DemoOptions(speed=0.3, max_angular=1.5,
                                           sim_overrides={"slip_stddev": "0.0"}))
    assert s.follower.path is None  # the demo sends each square itself
    assert s.follower.gains.desired_speed == 0.3
    assert s.follower.gains.max_angular_velocity == 1.5
    assert math.isclose(s.sim.config.geometry.right_radius, 0.0501, rel_tol=1e-12)
    assert math.isclose(s.odometry.geometry.right_radius, 0.05, rel_tol=1e-12)


def test_run_params_go_into_the_nodes_own_sections(tmp_path: Path) -> None:
    out = settings.write_run_params(
        settings.DEFAULT_PARAMS, {"path_follower_node": settings.follower_values(
            DemoOptions())}, tmp_path / "p.yaml")
    doc = yaml.safe_load(out.read_text())
    section = doc["path_follower_node"]["ros__parameters"]
    assert section["follower.path_type"] == "none" and section["use_sim_time"] is True
    assert doc["/**"]["ros__parameters"]["wheel_radius"] == 0.05  # the rest kept


def test_distance_to_a_polyline() -> None:
    pts = [(0.0, 0.0), (1.0, 0.0), (1.0, 1.0)]
    xy = np.array([[0.5, 0.2], [2.0, 0.0], [-3.0, -4.0], [1.0, 0.5], [0.9, 0.05]])
    np.testing.assert_allclose(evaluation.distance_to_polyline(xy, pts),
                               [0.2, 1.0, 5.0, 0.0, 0.05], atol=1e-12)


def _result(plot: str | None = None) -> DemoResult:
    def row(left: float, right: float, sep: float, err: float) -> Row:
        return Row((left, right, sep), err, -err, (0.0, 0.0, 0.0))

    rows = {NOMINAL: row(0.05, 0.05, 0.30, 0.5), FIT: row(0.05, 0.0501, 0.303, 0.001),
            UMBMARK: row(0.04995, 0.05005, 0.3027, 0.002), TRUE: row(0.05, 0.0501, 0.303, 0.0),
            WHEELS: row(0.05, 0.05, 0.30, 0.5), GYRO: row(0.05, 0.05, 0.30, 0.02)}
    sq = (Square(True, ((0.1, 0.0), (1.0, 0.0)), 0, 10), Square(False, ((0.1, 0.0),), 10, 20))
    # The slip events as the one rule gave them (core.estimation.gyro.slips): one of 0.1 rad.
    slips = ((2_000_000_000, 0.1),)
    return DemoResult("umbmark", 4.0, 32.0, 100.0, 25.0, (0.0, 0.0, 0.0), rows, 0.05, 0.2,
                      sq, {"/odom": 3}, None, plot, slips)


def test_the_table_shows_every_row_against_the_true_geometry() -> None:
    text = _result().table()
    for label in report.LABELS.values():
        assert label in text
    lines = {line.split("  ")[0]: line for line in text.splitlines()}
    nominal = lines[report.LABELS[NOMINAL]]
    # b 0.30 against the true 0.303: -0.99 %; 0.5 m of 32 m is 1.56 %.
    assert "0.30000 (-0.99%)" in nominal and "0.5000 m ( 1.56 %)" in nominal
    assert f"{math.degrees(-0.5):.3f} deg" in nominal
    assert "+0.00%" in lines[report.LABELS[TRUE]]
    assert "CW then CCW" in text and "5.0 cm" in text and "20.0 cm" in text
    assert "0.0200 m" in lines[report.LABELS[GYRO]]
    # The slip line: one slip, 2 s into the route, 0.1 rad.
    assert "found 1, at 2.0 s (5.7 deg) into the route" in text, text


def test_results_json_round_trips() -> None:
    d = json.loads(json.dumps(_result().as_dict()))
    assert set(d["rows"]) == {NOMINAL, FIT, UMBMARK, TRUE, WHEELS, GYRO}
    assert d["slip_events"][0] == {"stamp_ns": 2_000_000_000, "size_rad": 0.1}
    assert d["rows"][FIT]["right_radius"] == 0.0501
    assert d["squares"][0]["clockwise"] is True and d["squares"][1]["start_ns"] == 10
    assert d["follower"]["max_distance_truth_to_path_m"] == 0.2


def test_the_plot_is_written(tmp_path: Path) -> None:
    t = np.arange(50) * 10**8
    s = np.linspace(0.0, 1.0, 50)
    truth = Trajectory.from_arrays(t, s, 0 * s, 0 * s)
    odom = Trajectory.from_arrays(t, s, 0.1 * s, 0 * s)
    path = tmp_path / "p.png"
    from diffdrive_odom.demo.plot import plot

    plot(path, truth, {NOMINAL: odom, FIT: truth, GYRO: truth}, [[(0.0, 0.0), (1.0, 0.0)]],
         "t", [(2 * 10**9, 0.1)])
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    cfg = settings.load_settings(DemoOptions())  # with the online estimate's panel below
    _, _, aided = evaluation.replay_rows(_straight_with_slip(), cfg.odometry, cfg.gyro_odometry)
    assert aided is not None
    plot(path, truth, {NOMINAL: odom}, [[(0.0, 0.0), (1.0, 0.0)]], "t", (), aided.online,
         (1.0, 1.002, 1.01))
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_settings_run_the_node_wheels_only_and_replay_it_with_the_gyro() -> None:
    s = settings.load_settings(DemoOptions())
    assert s.odometry.gyro is None  # the live node: wheels only
    assert s.gyro_odometry.gyro is not None  # the replay: use_imu with the file's values
    assert s.gyro_odometry.geometry == s.odometry.geometry
    assert s.sim.imu_rate > 0.0 and s.sim.config.slip_events  # the sim's gyro and slips
    assert settings.BAG_TOPICS["/imu"] == "sensor_msgs/msg/Imu"


# A straight run (closed form: the truth is x = V t, heading 0) with the demo's robot:
# 1 s standing, then both wheels at V / r; from SLIP_T for 0.5 s the right encoder
# counts SPIN rad/s more than the wheel rolls. A gyro at 100 Hz reads the true yaw rate
# (0) plus a bias the zero-velocity updates find while standing.
V, R_WHEEL, B_WHEEL, TPR = 0.4, 0.05, 0.30, 4096.0
SLIP_T, SLIP_S, SPIN, BIAS, END = 2.0, 0.5, 1.2, 0.004, 4.0
T0 = 1_000_000_000_000


def _straight_with_slip() -> Recording:
    def moving(t: float) -> float:
        return max(0.0, t - 1.0)

    def extra(t: float) -> float:
        return SPIN * min(max(0.0, t - SLIP_T), SLIP_S)

    readings, truth_t, truth_x = [], [], []
    for k in range(int(END * 50) + 1):
        t = k / 50
        left = moving(t) * V / R_WHEEL
        right = left + extra(t)
        stamp = T0 + round(t * 1e9)
        readings.append(JointSample(stamp, ("left_wheel_joint", "right_wheel_joint"),
                                    (left * TPR / (2 * math.pi), right * TPR / (2 * math.pi)),
                                    ()))
        truth_t.append(stamp)
        truth_x.append(V * moving(t))
    # The IMU on its own clock: 97 Hz, 3.7 ms after the wheels' first reading (the robot
    # does not turn: each sample is the bias).
    imu = tuple(ImuReading(T0 + 3_700_000 + round(k * 1e9 / 97), 0.0, 0.0, BIAS)
                for k in range(int(END * 97) + 1))
    truth = Trajectory.from_arrays(truth_t, truth_x, [0.0] * len(truth_x), [0.0] * len(truth_x))
    return Recording(tuple(readings), truth, truth, (), 0.0, imu)


def test_the_gyro_aided_replay_keeps_the_heading_through_a_wheel_slip() -> None:
    s = settings.load_settings(DemoOptions())
    rec = _straight_with_slip()
    rows, paths, aided = evaluation.replay_rows(rec, s.odometry, s.gyro_odometry)
    assert aided is not None
    slips = aided.slips
    # Wheels only: the extra right arc r SPIN SLIP_S over b turns the odometry by 0.1 rad
    # that the robot never turned (to the encoder tick).
    turned = R_WHEEL * SPIN * SLIP_S / B_WHEEL
    tick = 2 * math.pi / TPR * R_WHEEL / B_WHEEL
    assert abs(rows[WHEELS].heading_rad - turned) < 2 * tick, rows[WHEELS]
    # ... and lands off to the left by about the heading times the distance after it.
    after = V * (END - SLIP_T - SLIP_S)
    assert rows[WHEELS].position_m > 0.8 * turned * after
    # The gyro's heading: the bias found standing still; the distance: the other wheel.
    assert abs(rows[GYRO].heading_rad) < 0.003, rows[GYRO]
    assert rows[GYRO].position_m < 0.005, rows[GYRO]
    assert set(paths) == {WHEELS, GYRO}
    # One slip, where it began, of the heading the wheels got wrong.
    (start, size), = slips
    assert abs((start - T0) * 1e-9 - SLIP_T) <= 0.04
    assert abs(size - turned) < 0.1 * turned


def test_without_imu_samples_only_the_wheels_replay() -> None:
    s = settings.load_settings(DemoOptions())
    rec = _straight_with_slip()
    rows, _, aided = evaluation.replay_rows(
        Recording(rec.joint_states, rec.truth, rec.truth, (), 0.0), s.odometry, s.gyro_odometry)
    assert set(rows) == {WHEELS} and aided is None


def test_readings_heard_before_the_ground_truth_are_left_out() -> None:
    """The recorder may match /joint_states before /ground_truth/odom: that is no failure."""
    s = settings.load_settings(DemoOptions())
    rec = _straight_with_slip()
    late = Trajectory.from_arrays(rec.truth.stamp_ns[25:], rec.truth.x[25:], rec.truth.y[25:],
                                  rec.truth.yaw[25:])  # from 0.5 s on
    cut = Recording(rec.joint_states, late, late, (), 0.0, rec.imu)
    rows = evaluation.calibrate_rows(cut, s.odometry, s.sim.config.geometry, 1.0).rows
    assert set(rows) == {NOMINAL, FIT, TRUE}
    replayed, paths, _ = evaluation.replay_rows(cut, s.odometry, s.gyro_odometry)
    assert paths[WHEELS].stamp_ns[0] == late.stamp_ns[0]
    assert replayed[GYRO].position_m < 0.005


def test_the_calibration_leaves_out_the_slip_the_gyro_finds_and_says_so() -> None:
    """The straight run's one slip (0.5 s at 50 Hz: 25 steps): with the gyro the
    calibration leaves it out, and the true geometry's row, bridged over it, ends on the
    truth (the robot went straight: x = V t), where with every wheel step it ends off by
    the slip's heading times the distance after it."""
    s = settings.load_settings(DemoOptions())
    rec = _straight_with_slip()
    plain = evaluation.calibrate_rows(rec, s.odometry, s.odometry.geometry, 1.0)
    assert plain.left_out is None and plain.rows[TRUE].left_out_position_m is None
    cal = evaluation.calibrate_rows(rec, s.odometry, s.odometry.geometry, 1.0, s.gyro_odometry)
    assert cal.left_out is not None
    events, steps, total = cal.left_out
    assert events == 1 and 24 <= steps <= 27 and total == int(END * 50)
    true = cal.rows[TRUE]
    turned = R_WHEEL * SPIN * SLIP_S / B_WHEEL
    assert true.position_m > 0.8 * turned * V * (END - SLIP_T - SLIP_S)
    assert true.left_out_position_m is not None and true.left_out_position_m < 0.002
    text = dataclasses.replace(_result(), left_out=cal.left_out).table()
    flat = " ".join(text.split())
    assert f"Calibration left out the {steps} of {total} wheel steps of the 1 slip event" in flat


def test_the_table_prints_the_online_estimate_against_the_truth() -> None:
    s = settings.load_settings(DemoOptions())
    rec = _straight_with_slip()
    _, _, aided = evaluation.replay_rows(rec, s.odometry, s.gyro_odometry)
    assert aided is not None and aided.online  # monitor on in the gyro-aided replay
    e = aided.online[-1][1]
    true = evaluation.true_multipliers(s.odometry.geometry, s.sim.config.geometry)
    text = dataclasses.replace(_result(), online=e, true_multipliers=true).table()
    flat = " ".join(text.split())
    assert "Online estimate (the gyro-aided replay" in flat and "not yet determined" in flat
    # The demo's sim: right wheel +0.2 %, track +1 %; mean radius held: r_R/m = 1.002/1.001.
    assert true == pytest.approx((2 / 2.002, 2 * 1.002 / 2.002, 1.01 * 2 / 2.002), rel=1e-12)
