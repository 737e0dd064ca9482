"""Which objective gives what, per experiment: in-sample worst final error against held out.

    .venv/bin/python bench/bench_free_paths.py [--quick]

Issue 24 item 4: on a free path the whole-trajectory fit (``calibrate``'s default) ends
its runs further off at worst than a fit to the same runs' end poses (OptiOdom's
objective, Sousa et al., "OptiOdom: a Generic Approach for Odometry Calibration of
Wheeled Mobile Robots"), while held out it stays better than nominal. This bench puts
the objectives side by side on the 45 OptiOdom training runs (``bench_calibration``'s
cache): per experiment, the final position error (start aligned) worst over its runs
in-sample, and mean / worst held out (LORO: leave one run out; LOEO: fitted on the other
experiments of the kind), with the nominal geometry's on the same runs. Objectives:

- the default: whole trajectory, start yaw, Cauchy loss;
- the same plus each run's end position error, weighted W (``calibration.fit(end_weight=W)``:
  its square counts W^2 times the run's mean squared residual, in plain squares);
- end poses only, no start yaw (OptiOdom-like; on a free path the reference figure in
  place of the paper's, whose text is not at hand).

``--quick``: the free paths only, the default and W = 0.5.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "bench"))
import bench_calibration as bc  # noqa: E402

OBJECTIVES: tuple[tuple[str, dict[str, Any]], ...] = (
    ("default (whole trajectory)", {}),
    ("+ end weight 0.2", {"end_weight": 0.2}),
    ("+ end weight 0.5", {"end_weight": 0.5}),
    ("+ end weight 1", {"end_weight": 1.0}),
    ("end poses (OptiOdom-like)", {"ends_only": True, "loss": "linear",
                                   "fit_start_yaw": False}),
)


def _fpe(ms: Sequence[Any]) -> list[float]:
    return [m.final_position_error_aligned_m for m in ms]


def _cell(values: list[float]) -> str:
    return f"{np.mean(values):.4f}/{max(values):.4f}" if values else "-"


def main(argv: Sequence[str]) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true",
                    help="free paths only, the default and end weight 0.5")
    args = ap.parse_args(list(argv))
    if not (bc.TRAIN / "to_rosbag2.py").exists():
        print(f"skipped: {bc.TRAIN} not found (the project's shared data; a clone has none)")
        return 0
    data = [d for d in bc.load_all(quick=False) if d.exp != bc.TRAIN_ONLY]
    objectives = OBJECTIVES
    if args.quick:
        data = [d for d in data if d.kind == "free"]
        objectives = (OBJECTIVES[0], OBJECTIVES[2])
    print("final position error, start aligned [m]: in-sample worst; held out mean/worst "
          "(LORO, LOEO) with nominal's on the same runs")
    print(f"{'experiment':24s} {'objective':28s} {'in-sample':>9s} {'nominal':>13s} "
          f"{'LORO':>13s} {'LOEO':>13s}  held out vs nominal  paper (quoted)")
    rows: dict[str, list[str]] = {}
    for label, kw in objectives:
        cv = bc.cross_validate(data, bc.fitter(**kw))
        for g, c in cv.items():
            nominal = _fpe(c["nominal"])
            held = [_fpe(c[k]) for k in ("LORO", "LOEO") if c[k]]
            verdict = ("better" if all(np.mean(h) < np.mean(nominal) for h in held)
                       else "NOT better")
            paper = bc.PAPER.get(g.split("/")[0], "")
            rows.setdefault(g, []).append(
                f"{g:24s} {label:28s} {max(_fpe(c['in-sample'])):9.4f} {_cell(nominal):>13s} "
                f"{_cell(_fpe(c['LORO'])):>13s} {_cell(_fpe(c['LOEO'])):>13s}  "
                f"{verdict:20s} {paper}")
        print(f"  ({label}: done)", flush=True)
    for lines in rows.values():
        print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
