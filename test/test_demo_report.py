"""The demo's pure parts: settings, the squares' paths, the table, distances, the plot.

No DDS: these run in milliseconds, with values from geometry, not from a run.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
import yaml

from diffdrive_odom.core.metrics import Trajectory
from diffdrive_odom.demo import report, settings
from diffdrive_odom.demo.report import FIT, NOMINAL, TRUE, UMBMARK, DemoResult, Row, Square
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
    ({"real_time_factor": 0.0}, "--real-time-factor"), ({"speed": -1.0}, "--linear"),
    ({"max_angular": math.nan}, "--angular")])
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
    np.testing.assert_allclose(report.distance_to_polyline(xy, pts),
                               [0.2, 1.0, 5.0, 0.0, 0.05], atol=1e-12)


def _result(plot: str | None = None) -> DemoResult:
    def row(left: float, right: float, sep: float, err: float) -> Row:
        return Row((left, right, sep), err, -err, (0.0, 0.0, 0.0))

    rows = {NOMINAL: row(0.05, 0.05, 0.30, 0.5), FIT: row(0.05, 0.0501, 0.303, 0.001),
            UMBMARK: row(0.04995, 0.05005, 0.3027, 0.002), TRUE: row(0.05, 0.0501, 0.303, 0.0)}
    sq = (Square(True, ((0.1, 0.0), (1.0, 0.0)), 0, 10), Square(False, ((0.1, 0.0),), 10, 20))
    return DemoResult("umbmark", 4.0, 32.0, 100.0, 25.0, (0.0, 0.0, 0.0), rows, 0.05, 0.2,
                      sq, {"/odom": 3}, None, plot)


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


def test_results_json_round_trips() -> None:
    d = json.loads(json.dumps(_result().as_dict()))
    assert set(d["rows"]) == {NOMINAL, FIT, UMBMARK, TRUE}
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

    plot(path, truth, {NOMINAL: odom, FIT: truth}, [[(0.0, 0.0), (1.0, 0.0)]], "t")
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
