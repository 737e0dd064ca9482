"""The calibration bench still runs: ``--quick`` on the 12 OptiOdom training squares.

Figures are the bench's to report; checked here is that every section prints, that the
product's fit beats the nominal geometry on held-out squares (the real-data claim the
calibration page makes), and that the bench skips with one line where ../shared is missing.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys

import pytest

from rosutil import ROOT

pytestmark = [pytest.mark.process, pytest.mark.slow]

TRAIN = ROOT.parent / "shared" / "data" / "optiodom_train"


def _quick(bench: str) -> str:
    """``bench/BENCH --quick``'s standard output; it must exit 0."""
    proc = subprocess.run([sys.executable, str(ROOT / "bench" / bench), "--quick"],
                          capture_output=True, text=True, timeout=600, cwd=ROOT,
                          env=dict(os.environ))
    assert proc.returncode == 0, proc.stdout + proc.stderr
    return proc.stdout


@pytest.mark.skipif(not (TRAIN / "to_rosbag2.py").exists(),
                    reason="../shared/data/optiodom_train is not here (a user's clone)")
def test_calibration_bench_quick_prints_every_section() -> None:
    out = _quick("bench_calibration.py")
    for head in ("== 1. Objectives", "== 2. The product's fit", "== 3. Bootstrap",
                 "== 4. Final-pose NEES"):
        assert head in out, out
    row = re.search(r"^ALL training runs\s+(\S+)/\S+ \S+\s+\S+\s+\S+ \S+\s+\S+\s+(\S+)/", out,
                    re.M)
    assert row, out
    nominal, loro = (float(v) for v in row.groups())
    assert loro < nominal, out
    assert re.search(r"^calibrated LOEO \(held out\).* runs mean", out, re.M), out
    # the printed sigma's coverage, before (bootstrap alone) and after (+ session drift)
    assert re.search(r"^fit in June, judged Dec/Jan \(held out\)\s+\d+(\s+\d+ % /\s+\d+ %){2}",
                     out, re.M), out


@pytest.mark.skipif(not (TRAIN / "to_rosbag2.py").exists(),
                    reason="../shared/data/optiodom_train is not here (a user's clone)")
def test_verdict_bench_quick_counts_both_rules_on_the_squares() -> None:
    """``bench_verdict.py --quick``: the 3-run subsets of the 12 training squares. The
    calibration page's claim there: the verdict that leaves out the folds that cannot judge, with
    its margin and its leverage test, neither refuses a fit that is better held out nor
    accepts a worse one."""
    out = _quick("bench_verdict.py")
    total = re.search(r"^ALL\s+40\s+(\d+)\s+(\d+)\s+(\d+)\s+([\d.]+)-\s*([\d.]+)"
                      r"((?:\s+\|(?:\s+\d+){5}){4})$", out, re.M)
    assert total, out
    rules = [[int(v) for v in part.split()] for part in total.group(6).split("|")[1:]]
    assert all(sum(r[:3]) == 40 for r in rules), out  # accepted + cannot tell + refused
    old, _, _, new = rules
    # the squares' folds sit below the leverage the verdict allows: none is left out
    assert float(total.group(5)) < 3.0, out
    assert new[3] == 0 and new[4] == 0, out  # no false refusal, no false acceptance
    assert old[3] > 0, out  # the rule before refused fits that were better held out


@pytest.mark.skipif(not (TRAIN / "to_rosbag2.py").exists(),
                    reason="../shared/data/optiodom_train is not here (a user's clone)")
def test_free_paths_bench_quick_puts_the_objectives_side_by_side() -> None:
    """``bench_free_paths.py --quick``: both free-path experiments, the default and an
    end weight of 0.5, each row with its in-sample worst and a held-out verdict; the
    default's held out is better than nominal there (the calibration page's claim)."""
    out = _quick("bench_free_paths.py")
    rows = re.findall(r"^(free/\d+)\s+(default \(whole trajectory\)|\+ end weight 0\.5)\s+"
                      r"([\d.]+)\s.*\s(better|NOT better)\s*$", out, re.M)
    assert len(rows) == 4, out
    assert all(verdict == "better" for _, label, _, verdict in rows
               if label.startswith("default")), out
