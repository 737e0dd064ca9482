"""calibrate's objective choice judged on runs it never saw: fit on odd runs, judge on even.

    .venv/bin/python bench/bench_calibration_objective.py

Data: the 45 OptiOdom training runs (``bench_calibration``'s cache of
``../shared/data/optiodom_train``; Sousa et al., "OptiOdom: a Generic Approach for
Odometry Calibration of Wheeled Mobile Robots"). Per experiment: the objective is chosen
on its odd runs (run-01, 03, ...) by ``core.evaluation.objective.choose`` (what
``calibrate`` does: leave-one-run-out over the folds that can judge, the lowest worst
by the one judge, the mount's lever arm fitted where the runs determine it), fitted on
them, and judged on its even runs by the one judge (``core.evaluation.judge``: the
whole trajectory and its end, the reference on the axle as it is on these runs), worst
and mean [m]. Beside it, on the same split: the paper's objective (the end poses only,
plain squares, the reference held on the axle: ``calibration.fit(ends_only=True,
mount=ON_AXLE)``), the whole trajectory alone (``objective.TRAJECTORY``), and what the
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
from diffdrive_odom.core.evaluation.judge import judgment
from diffdrive_odom.core.evaluation.recorded_run import Run
from diffdrive_odom.core.geometry.kinematics import Geometry

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "bench"))
import bench_calibration as bc  # noqa: E402

KINDS = ("circular", "free", "ivanjko", "square")


def odd(run: Run) -> bool:
    """run-01, run-03, ...: the runs fitted on."""
    return int(run.name.rsplit("-", 1)[1]) % 2 == 1


def held_out(geometry: Geometry, judged: Sequence[Run]) -> list[float]:
    """The one judge's figure of ``judged`` with ``geometry`` (fitted on other runs)."""
    return [judgment(r, geometry).error for r in judged]


def split(fitted_on: Sequence[Run], judged: Sequence[Run]) -> dict[str, tuple[str, list[float]]]:
    """Per column: the objective's name and the judged runs' errors."""
    choice = objective.choose(fitted_on, bc.NOMINAL, mount=bc.lever_rule)
    by_mean = (min(choice.scores, key=lambda s: s.mean).objective if choice.scores
               else choice.objective)
    spec = bc.lever_rule(fitted_on)
    cols = {k: (o.name, o.fit(fitted_on, bc.NOMINAL, figures=False, mount=spec).geometry)
            for k, o in (("chosen", choice.objective), ("by mean", by_mean),
                         ("trajectory", objective.TRAJECTORY))}
    cols["paper"] = ("end poses, on the axle", calibration.fit(
        fitted_on, bc.NOMINAL, ends_only=True, loss="linear", mount=calibration.ON_AXLE,
        figures=False).geometry)
    return {k: (name, held_out(g, judged)) for k, (name, g) in cols.items()}


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
    print("== 1. Per experiment: fitted on its odd runs, judged on its even runs; the one "
          "judge's whole-trajectory error, worst/mean [m] ==")
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
