"""calibrate's objective choice judged on runs it never saw: fit on odd runs, judge on even.

    .venv/bin/python bench/bench_calibration_objective.py

Data: the 45 OptiOdom training runs (``bench_calibration``'s cache of
``../shared/data/optiodom_train``; Sousa et al., "OptiOdom: a Generic Approach for
Odometry Calibration of Wheeled Mobile Robots"). Per experiment: the objective is chosen
on its odd runs (run-01, 03, ...) by ``core.evaluation.objective.choose`` (what
``calibrate`` does: leave-one-run-out over the folds that can judge, the lowest worst
final error), fitted on them, and judged on its even runs: their final position error,
start aligned, worst and mean [m]. Beside it, on the same split: the paper's objective
(the end poses only, no start yaw, plain squares: ``objective.END_POSES``), the whole
trajectory alone (``calibrate``'s default before: ``objective.TRAJECTORY``), and what the
choice by the mean of the folds would have taken. Per kind: the worst and the mean over
the even runs of the kind's experiments (each fitted on its own odd runs). The free path
of one run (free/020120212354) has no even run: it is not judged.

Section 2: the same with each kind's odd runs pooled over its experiments (one fit per
kind), judged on the kind's even runs.
"""

from __future__ import annotations

import sys
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from diffdrive_odom.core.evaluation import calibration, objective
from diffdrive_odom.core.evaluation.recorded_run import Run

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "bench"))
import bench_calibration as bc  # noqa: E402

KINDS = ("circular", "free", "ivanjko", "square")


def odd(run: Run) -> bool:
    """run-01, run-03, ...: the runs fitted on."""
    return int(run.name.rsplit("-", 1)[1]) % 2 == 1


def held_out(fitted_on: Sequence[Run], judged: Sequence[Run],
             goal: objective.Objective) -> list[float]:
    """Final position errors (start aligned) of ``judged`` with ``goal`` fitted on the others."""
    geometry = goal.fit(fitted_on, bc.NOMINAL, figures=False).geometry
    return [calibration.figures_of(r, geometry).final_position_error_aligned_m for r in judged]


def split(fitted_on: Sequence[Run], judged: Sequence[Run]) -> dict[str, tuple[str, list[float]]]:
    """Per column: the objective's name and the judged runs' final errors."""
    choice = objective.choose(fitted_on, bc.NOMINAL)
    by_mean = (min(choice.scores, key=lambda s: s.mean).objective if choice.scores
               else choice.objective)
    cols = {"chosen": choice.objective, "by mean": by_mean, "paper": objective.END_POSES,
            "trajectory": objective.TRAJECTORY}
    return {k: (o.name, held_out(fitted_on, judged, o)) for k, o in cols.items()}


def cell(errors: Sequence[float]) -> str:
    return f"{max(errors):.4f}/{np.mean(errors):.4f}" if errors else "-"


HEAD = (f"{'':26s} {'chosen':>15s} {'paper (ends)':>15s} {'whole traj.':>15s} "
        f"{'by mean':>15s}  chosen objective / by mean")


def row(label: str, cols: dict[str, tuple[str, list[float]]], names: str = "") -> str:
    line = f"{label:26s}" + "".join(f" {cell(cols[k][1]):>15s}"
                                     for k in ("chosen", "paper", "trajectory", "by mean"))
    ok = max(cols["chosen"][1]) <= max(cols["paper"][1]) + 1e-9
    return line + f"  {'<=' if ok else '> '} paper  {names}"


def main() -> int:
    if not (bc.TRAIN / "to_rosbag2.py").exists():
        print(f"skipped: {bc.TRAIN} is not here (a user's clone)")
        return 0
    data = [d for d in bc.load_all(False) if d.exp != bc.TRAIN_ONLY]
    print("== 1. Per experiment: fitted on its odd runs, judged on its even runs; final "
          "position error, start aligned, worst/mean [m] ==")
    print(HEAD)
    per_kind: dict[str, dict[str, list[float]]] = {k: {} for k in KINDS}
    for group in dict.fromkeys(d.group for d in data):
        runs = [d.run for d in data if d.group == group]
        train, judged = [r for r in runs if odd(r)], [r for r in runs if not odd(r)]
        if not judged:
            print(f"{group:26s} no even run: not judged")
            continue
        cols = split(train, judged)
        for k, (_, errors) in cols.items():
            per_kind[group.split("/")[0]].setdefault(k, []).extend(errors)
        print(row(group, cols, f"{cols['chosen'][0]} / {cols['by mean'][0]}"), flush=True)
    print("per kind (worst/mean over the kind's even runs, each experiment fitted on its own "
          "odd runs):")
    print(HEAD)
    for kind in KINDS:
        cols = {k: ("", v) for k, v in per_kind[kind].items()}
        print(row(kind, cols))
    print("\n== 2. Per kind, odd runs pooled over its experiments: one fit, judged on the "
          "kind's even runs ==")
    print(HEAD)
    for kind in KINDS:
        runs = [d.run for d in data if d.kind == kind]
        cols = split([r for r in runs if odd(r)], [r for r in runs if not odd(r)])
        print(row(kind, cols, f"{cols['chosen'][0]} / {cols['by mean'][0]}"), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
