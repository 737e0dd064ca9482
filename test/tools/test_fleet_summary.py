"""A fleet's summary: one table, each bag's figures side by side, also as CSV and JSON.

The expected figures are each bag's own: ``eval BAG --json`` (and ``replay BAG --eval
--json``) run alone, one bag at a time; the fleet's table and its ``--summary`` file
must carry exactly those (start-aligned final error, ATE, error per metre, the
distance), a failed bag its reason, and not replay's throughput line.
"""

from __future__ import annotations

import csv
import json
from pathlib import Path
from typing import Any

import pytest

from diffdrive_odom.tools.cli import main as cli

from bagutil import OPTIODOM_PARAMS, write_params
from rosutil import DATA

pytestmark = [pytest.mark.process]

RUNS = [DATA / "optiodom" / r for r in
        ("square_231220200029_run-04", "square_231220200029_run-01")]
# Summary key -> the figure of eval's own JSON it is.
SAME_AS = {"distance_m": "distance_m", "final_error_m": "final_position_error_aligned_m",
           "ate_m": "ate_rmse_aligned_m", "error_per_m": "final_error_per_m"}


def _alone(tmp_path: Path, command: list[str], bag: Path) -> dict[str, Any]:
    out = tmp_path / f"alone_{bag.name}.json"
    assert cli([*command[:1], str(bag), *command[1:], "--json", str(out)]) == 0
    return dict(json.loads(out.read_text(encoding="utf-8")))


def _rows(text: str, bags: list[str]) -> dict[str, list[str]]:
    """The table's rows by bag (the lines after the header that starts with 'bag')."""
    lines = text[text.index("\nbag "):].splitlines()[1:]
    header = lines[0]
    assert "final error [m]" in header and "ATE [m]" in header and "slips" in header
    return {row.split()[0]: row.split()[1:] for row in lines[1:1 + len(bags)]}


@pytest.mark.parametrize("suffix", [".csv", ".json"])
def test_replay_eval_fleet_summary(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                   suffix: str) -> None:
    params = write_params(tmp_path / "p.yaml", OPTIODOM_PARAMS)
    command = ["replay", "--params-file", str(params), "--eval"]
    alone = {str(b): _alone(tmp_path, command, b) for b in RUNS}
    capsys.readouterr()
    missing = str(tmp_path / "no_such_bag")
    bags = [str(RUNS[0]), missing, str(RUNS[1])]
    summary = tmp_path / f"fleet{suffix}"
    status = cli(["replay", *bags, "--params-file", str(params), "--eval",
                  "--summary", str(summary), "--jobs", "2"])
    out, _ = capsys.readouterr()
    assert status == 1
    rows = _rows(out, bags)
    assert rows[missing][0] == "FAILED" and "no_such_bag" in " ".join(rows[missing])
    table = out[out.index("\nbag "):]
    assert "readings/s" not in table  # not the throughput line any more

    if suffix == ".json":
        got = {r["bag"]: r for r in json.loads(summary.read_text(encoding="utf-8"))}
    else:
        with open(summary, newline="", encoding="utf-8") as f:
            got = {r["bag"]: r for r in csv.DictReader(f)}
    assert list(got) == bags
    assert got[missing]["status"] == "failed" and got[missing]["reason"]
    for bag in map(str, RUNS):
        row = got[bag]
        assert row["status"] == "ok"
        for key, theirs in SAME_AS.items():
            assert float(row[key]) == alone[bag][theirs], (bag, key)
        assert row["slips"] in (None, "")  # wheels only: no slip detector ran
        # The printed row: ok, readings, poses, then the figures to their printed digits.
        printed = rows[bag]
        assert printed[0] == "ok"
        assert float(printed[3]) == pytest.approx(alone[bag]["distance_m"], abs=5e-4)
        assert float(printed[4]) == pytest.approx(
            alone[bag]["final_position_error_aligned_m"], abs=5e-5)
        assert float(printed[5]) == pytest.approx(alone[bag]["ate_rmse_aligned_m"], abs=5e-5)
        assert float(printed[6]) == pytest.approx(100 * alone[bag]["final_error_per_m"],
                                                  abs=5e-4)
        assert printed[7] == "-"


def test_eval_fleet_summary_and_one_bag_refused(tmp_path: Path,
                                                capsys: pytest.CaptureFixture[str]) -> None:
    params = write_params(tmp_path / "p.yaml", OPTIODOM_PARAMS)
    assert cli(["replay", *map(str, RUNS), "--params-file", str(params), "-o",
                str(tmp_path / "out"), "--keep-input", "--jobs", "2"]) == 0
    outs = [tmp_path / "out" / b.name for b in RUNS]
    alone = {str(b): _alone(tmp_path, ["eval"], b) for b in outs}
    summary = tmp_path / "fleet.json"
    assert cli(["eval", *map(str, outs), "--summary", str(summary), "--jobs", "1"]) == 0
    got = {r["bag"]: r for r in json.loads(summary.read_text(encoding="utf-8"))}
    for bag in map(str, outs):
        assert {k: got[bag][k] for k in SAME_AS} == {
            k: alone[bag][v] for k, v in SAME_AS.items()}
        assert got[bag]["readings"] is None and got[bag]["slips"] is None
    capsys.readouterr()
    # One bag has no fleet table; a summary that cannot be written costs no work.
    assert cli(["eval", str(outs[0]), "--summary", str(summary)]) == 2
    assert "several bags" in capsys.readouterr().err
    assert cli(["eval", *map(str, outs), "--summary", str(tmp_path / "fleet.txt")]) == 2
    assert ".csv or .json" in capsys.readouterr().err
