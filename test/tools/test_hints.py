"""The hints the tools print point to commands that work where they are printed.

``make demo`` runs the venv's script without putting the venv on PATH, so the demo's
closing hint names the script by its path; ``eval`` of a replay's output (odometry
only) points to ``--reference-bag``.
"""

from __future__ import annotations

import sys
from pathlib import Path

import pytest
from gyrostreams import TIMINGS, B, R, Route, stream, truth

from diffdrive_odom.demo.report import TRUE, DemoResult, Row, Square
from diffdrive_odom.tools.cli import PROGRAM, invocation
from diffdrive_odom.tools.cli import main as cli

from bagutil import OPTIODOM_PARAMS, write_params, write_sensor_bag
from rosutil import DATA

RUN04 = DATA / "optiodom" / "square_231220200029_run-04"
SCRIPT = Path(sys.executable).parent / PROGRAM


def test_the_hint_names_the_script_by_its_path_when_it_is_not_on_path(
        monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    """On main the demo said ``try: diffdrive-odom eval ...``, which `make demo`'s shell
    does not find."""
    if not SCRIPT.exists():
        pytest.skip(f"no {PROGRAM} beside {sys.executable} (not a pip/venv install)")
    monkeypatch.setenv("PATH", str(tmp_path))  # the venv is not on PATH
    monkeypatch.chdir(tmp_path)
    assert invocation() == str(SCRIPT)
    monkeypatch.chdir(SCRIPT.parent.parent.parent)  # the venv's parent, as after make demo
    assert invocation() == str(Path(SCRIPT.parent.parent.name) / "bin" / PROGRAM)
    monkeypatch.setenv("PATH", str(SCRIPT.parent))  # activated venv: the bare name works
    assert invocation() == PROGRAM


def test_the_demo_table_closes_with_that_command() -> None:
    true = Row((0.05, 0.0501, 0.303), 0.0, 0.0, (0.0, 0.0, 0.0))
    squares = (Square(True, ((0.5, 0.0), (1.0, 0.0)), 0, 10),)
    result = DemoResult("square", 1.0, 4.0, 10.0, 3.0, (0.0, 0.0, 0.0), {TRUE: true}, 0.01,
                        0.1, squares, {}, "demo_output/bag", None)
    last = result.table(".venv/bin/diffdrive-odom").splitlines()[-1]
    assert last == ("bag:  demo_output/bag  (try: .venv/bin/diffdrive-odom eval "
                    "demo_output/bag)")


def test_eval_of_a_replay_output_points_to_reference_bag(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A replay's output holds only /odom and /tf: the reference is in the bag it replayed."""
    params = write_params(tmp_path / "p.yaml", OPTIODOM_PARAMS)
    out = tmp_path / "replayed"
    assert cli(["replay", str(RUN04), "--params-file", str(params), "-o", str(out)]) == 0
    capsys.readouterr()
    assert cli(["eval", str(out)]) == 2
    err = capsys.readouterr().err
    assert "give the bag it replayed as --reference-bag BAG" in err, err
    assert cli(["eval", str(out), "--reference-bag", str(RUN04)]) == 0


def test_another_ground_truth_topic_is_named_with_each_commands_own_flag(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A bag whose only ground truth is /mocap/pose: replay --eval takes it and points to
    ``--eval TOPIC`` (replay has no --ground-truth); eval points to its --ground-truth."""
    route = Route(((5.0, 0.4, 0.0), (5.0, 0.3, 0.3)))
    bag = tmp_path / "bag"
    write_sensor_bag(bag, stream(route, TIMINGS[0], 0.0, 0.0, 1, truth(route, R, R, B)),
                     TIMINGS[0].imu_hz, truth=truth(route, R, R, B), truth_topic="/mocap/pose")
    params = write_params(tmp_path / "p.yaml", {"wheel_radius": R, "wheel_separation": B})
    out = tmp_path / "replayed"
    assert cli(["replay", str(bag), "--params-file", str(params), "--eval", "-o", str(out)]) == 0
    err = capsys.readouterr().err
    assert "using /mocap/pose, its only ground-truth topic (--eval TOPIC to choose another)" \
        in err, err
    assert "--ground-truth" not in err
    assert cli(["eval", str(out), "--reference-bag", str(bag)]) == 0
    err = capsys.readouterr().err
    assert "using /mocap/pose, its only ground-truth topic (--ground-truth TOPIC to choose " \
        "another)" in err, err
