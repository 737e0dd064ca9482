"""Real runs re-logged as a logger writes them (issue 37): replay loses no count.

The copies (:mod:`relogged`: holds of 0.1-0.3 s released 1 ms after the previous row,
gaps of 1-5 s inside turns, jittered stamps) of the OptiOdom runs in test/data (MIT)
and, where ``../shared`` is beside the clone, of the PHIL TurtleBot2 runs (GPL-3.0, read
in place, never copied). The judges need no estimator: the unmodified run replayed, and
an anchor that integrates every count. Goals: on every copy the final heading within
0.1 deg of the unmodified run's and the ATE (best SE(2) fit, on the same rows: outside
the copy's holds and gaps in both) at most 1 mm worse; on every unmodified run the final
heading within 0.1 deg of the anchor's, no step named a counter fault.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import phildata
import pytest
import relogged

from diffdrive_odom.core.evaluation.metrics import Trajectory
from diffdrive_odom.tools.bags import poses
from diffdrive_odom.tools.cli import main as cli

from bagutil import OPTIODOM_PARAMS, write_params, write_sensor_bag
from rosutil import DATA

OPTIODOM = sorted((DATA / "optiodom").glob("square_*"))
HEADING_DEG = 0.1
ATE_M = 0.001


def judged_optiodom(bag: Path) -> relogged.Judged:
    rec = relogged.load(bag, "left_wheel_joint", "right_wheel_joint")
    return relogged.judge(bag.name, rec, relogged.OPTIODOM, OPTIODOM_PARAMS,
                          poses.read_trajectory(bag, "/ground_truth/pose"))


def assert_goals(j: relogged.Judged) -> None:
    copy, plain = j.relogged, j.unmodified
    assert not plain.reasons, plain.examples  # nothing named on the real run
    assert abs(j.degrees(plain.heading, j.anchor)) <= HEADING_DEG, j.name
    assert abs(j.degrees(copy.heading, plain.heading)) <= HEADING_DEG, j.name
    # Every hold integrated (no step skipped), every gap's motion integrated and named.
    assert "too_fast" not in copy.reasons and "gap" not in copy.reasons, copy.examples
    assert copy.gaps_integrated == len(j.copy.gaps) == copy.reasons["gap_integrated"]
    if j.ate is not None:
        _, _, same_plain, same_copy = j.ate
        assert same_copy <= same_plain + ATE_M, (j.name, j.ate)


@pytest.mark.parametrize("bag", OPTIODOM, ids=lambda b: b.name)
def test_relogged_optiodom_runs_keep_their_heading_and_path(bag: Path) -> None:
    j = judged_optiodom(bag)
    assert len(j.copy.holds) >= 20 and len(j.copy.gaps) >= 2  # the logger really wrote
    assert_goals(j)


@pytest.mark.skipif(not phildata.DATA.is_dir(), reason=phildata.MISSING)
@pytest.mark.parametrize("run", phildata.RUNS)
def test_relogged_phil_runs_keep_their_heading_and_path(run: int) -> None:
    """The Kobuki's 16-bit counters (a gap longer than its speeds allow reads ambiguous)."""
    bag = phildata.DATA / f"phil_trial_{run}"
    rec = relogged.load(bag, "wheel_left_joint", "wheel_right_joint")
    truth: Trajectory | None = phildata.load(bag).truth
    params: dict[str, Any] = dict(phildata.NOMINAL)
    assert_goals(relogged.judge(bag.name, rec, relogged.KOBUKI, params, truth))


def test_the_copy_holds_every_count_and_only_what_the_logger_did() -> None:
    """The generator, judged without the package: the anchor's heading is the run's,
    the holds and gaps are where and as long as the module says, stamps stay in order."""
    bag = OPTIODOM[0]
    rec = relogged.load(bag, "left_wheel_joint", "right_wheel_joint")
    copy = relogged.relog(rec, relogged.OPTIODOM, relogged.seed_of(bag.name))
    rows = copy.recording
    assert relogged.anchor_heading(rows, relogged.OPTIODOM) == pytest.approx(
        relogged.anchor_heading(rec, relogged.OPTIODOM), abs=1e-12)
    assert (rows.stamp_ns[1:] > rows.stamp_ns[:-1]).all()
    turns = relogged.turning_stretches(rec, relogged.OPTIODOM)
    for a, b in copy.gaps:
        assert 1e9 <= b - a <= 5e9
        assert any(s <= a and b <= e for s, e in turns)
        assert not ((rows.stamp_ns > a + 3e6) & (rows.stamp_ns < b - 3e6)).any()
    for a, b in copy.holds:
        assert 0.1e9 <= b - a <= 0.3e9
    released = (rows.stamp_ns[1:] - rows.stamp_ns[:-1]) == relogged.RELEASE_NS
    assert released.sum() >= 0.8 * len(copy.holds)  # short holds may hold no row


def test_replay_of_a_relogged_bag_names_the_gaps_and_skips_nothing(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The user's command on the copy written as a bag: the summary names each gap's
    motion integrated, no step is skipped."""
    bag = OPTIODOM[1]
    rec = relogged.load(bag, "left_wheel_joint", "right_wheel_joint")
    copy = relogged.relog(rec, relogged.OPTIODOM, relogged.seed_of(bag.name))
    rows = copy.recording
    path = tmp_path / "relogged"
    write_sensor_bag(path, [("j", int(s), int(s), float(p[0]), float(p[1]))
                            for s, p in zip(rows.stamp_ns, rows.position, strict=True)],
                     imu_hz=100.0, imu=False)
    params = write_params(tmp_path / "p.yaml", OPTIODOM_PARAMS)
    assert cli(["replay", str(path), "--params-file", str(params),
                "--csv", str(tmp_path / "out.csv")]) == 0
    err = capsys.readouterr().err
    assert f"  {len(copy.gaps)} x gap_integrated: " in err, err
    assert "s without a reading (max_reading_gap 1 s): the counts went on" in err, err
    assert "too_fast" not in err and "x gap:" not in err, err
