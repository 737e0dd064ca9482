"""Where the reference is mounted must not change calibrate (issue 38 items 3 and 4).

    .venv/bin/python bench/bench_mount.py [--quick] [--mounts N]

Data: ``../shared/data/optiodom_train`` (45 runs of one real robot, 8 experiments; Sousa
et al., "OptiOdom: a Generic Approach for Odometry Calibration of Wheeled Mobile
Robots"), bench_calibration's cache of its bags; their motion capture tracks the axle
centre facing forward. A mount moves it, written here with plain trigonometry (the
point ``p + R(theta) (x, y)``, the heading ``theta + yaw``), the lever arm drawn up to
0.3 m each way and the yaw anywhere (seeded: the same mounts every run). Everything
else is ``calibrate``'s own decision with its defaults
(``core.evaluation.assessment.assess``).

1. The invariance sweep: every experiment on the axle and on ``--mounts`` mounts:
   each multiplier's change in units of the axle's printed sigma (goal: within half),
   the same objective and verdict, and the mount found against the one given (the axle's
   own found mount composed with it).
2. Never "better" for worse: every leave-one-experiment-out split of a kind (calibrate
   on the kind's other experiments, the experiment left out judged by the one judge,
   ``core.evaluation.judge``, with the mount calibrate found), on the axle and mounted:
   the count of splits where calibrate's verdict says better while the held-out mean
   error is above nominal's.

``--quick``: the squares, one mount.
"""

from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Sequence
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "bench"))
import bench_calibration as bc  # noqa: E402

from diffdrive_odom.core.evaluation import assessment  # noqa: E402
from diffdrive_odom.core.evaluation.judge import judgment  # noqa: E402
from diffdrive_odom.core.evaluation.metrics import Trajectory  # noqa: E402
from diffdrive_odom.core.evaluation.recorded_run import Run  # noqa: E402

SEED = 38
LEVER_M = 0.3
Mounting = tuple[float, float, float]  # x, y [m], yaw [rad]


def mounted(run: Run, m: Mounting) -> Run:
    """``run`` with its reference where a reference on mount ``m`` would have been."""
    ref = run.reference
    assert ref is not None
    x, y, yaw = m
    c, s = np.cos(ref.yaw), np.sin(ref.yaw)
    moved = Trajectory(ref.stamp_ns, ref.x + c * x - s * y, ref.y + s * x + c * y,
                       ref.yaw + yaw)
    return Run(run.name, run.steps, moved)


def compose(a: Mounting, b: Mounting) -> Mounting:
    """Mount ``b`` on top of mount ``a`` (``A B``)."""
    c, s = math.cos(a[2]), math.sin(a[2])
    return a[0] + c * b[0] - s * b[1], a[1] + s * b[0] + c * b[1], a[2] + b[2]


def draws(n: int, seed: int = SEED) -> list[Mounting]:
    rng = np.random.default_rng(seed)
    return [(float(rng.uniform(-LEVER_M, LEVER_M)), float(rng.uniform(-LEVER_M, LEVER_M)),
             float(rng.uniform(-math.pi, math.pi))) for _ in range(n)]


def verdict(a: assessment.Assessment) -> str:
    v = a.verdict
    if a.implausible:
        return "implausible"
    if v is None:
        return "no check"
    return "refused" if a.refused else "cannot tell" if v.cannot_tell else "better"


def sweep(groups: dict[str, list[Run]], mounts: Sequence[Mounting]) -> int:
    print("== 1. Invariance: each experiment on the axle and mounted; multiplier change in "
          "the axle's printed sigma (left, right, separation), objective, verdict, mount "
          "found - given ==")
    failures = 0
    for g, runs in groups.items():
        axle = assessment.assess(runs, bc.NOMINAL)
        sig = None if axle.printed is None else np.sqrt(np.diag(axle.printed))
        found0 = axle.mount.mount
        base = (found0.x, found0.y, found0.yaw)
        print(f"{g}: axle {axle.choice.objective.name}, {verdict(axle)}, multipliers "
              + " ".join(f"{v:.6f}" for v in axle.fit.values / bc.NOMINAL_VALUES)
              + f", mount {found0.text(axle.mount.sigma)}"
              + (f" (lever held: {axle.mount.lever_held[:60]}...)" if axle.mount.lever_held
                 else ""), flush=True)
        for m in mounts:
            a = assessment.assess([mounted(r, m) for r in runs], bc.NOMINAL)
            d = a.fit.values - axle.fit.values
            z = (np.abs(d) / sig) if sig is not None else None
            expect = compose(base, m)
            got = a.mount.mount
            off = (got.x - expect[0], got.y - expect[1],
                   math.remainder(got.yaw - expect[2], math.tau))
            same = (a.choice.objective == axle.choice.objective and verdict(a) == verdict(axle))
            ok = same and ((z is None and bool(np.all(np.abs(d) <= 1e-4 * axle.fit.values)))
                           or (z is not None and bool(np.all(z <= 0.5))))
            failures += not ok
            change = (" ".join(f"{v:.3f}" for v in z) + " sigma" if z is not None else
                      " ".join(f"{v:.1e}" for v in np.abs(d) / axle.fit.values)
                      + " relative (no sigma: fewer than 3 runs)")
            print(f"  mount ({m[0]:+.3f}, {m[1]:+.3f}, {math.degrees(m[2]):+7.2f} deg): "
                  f"change {change}; {a.choice.objective.name}, {verdict(a)}; found - given "
                  f"({1000 * off[0]:+.2f}, {1000 * off[1]:+.2f}) mm, "
                  f"{math.degrees(off[2]):+.3f} deg{'' if ok else '  <- NOT INVARIANT'}",
                  flush=True)
    print(f"experiment x mount pairs not invariant: {failures}")
    return failures


def never_better_for_worse(groups: dict[str, list[Run]], mount: Mounting) -> int:
    print("\n== 2. Never better for worse: leave one experiment of a kind out, calibrate on "
          "the others, judge it (mean whole-trajectory error [m], the mount calibrate found) ==")
    print(f"{'left out':26s} {'where':8s} {'verdict':12s} {'nominal':>8s} {'calibrated':>10s}")
    count = splits = 0
    for g, runs in groups.items():
        kind = g.split("/")[0]
        training = [r for o, rs in groups.items() if o != g and o.split("/")[0] == kind
                    for r in rs]
        if not training:
            continue
        for where, m in (("axle", None), ("mounted", mount)):
            train = training if m is None else [mounted(r, m) for r in training]
            judged = runs if m is None else [mounted(r, m) for r in runs]
            a = assessment.assess(train, bc.NOMINAL)
            found = a.fit.mount
            nominal = float(np.mean([judgment(r, bc.NOMINAL, found).error for r in judged]))
            cal = float(np.mean([judgment(r, a.fit.geometry, found).error for r in judged]))
            said = verdict(a)
            wrong = said == "better" and cal > nominal
            splits += 1
            count += wrong
            print(f"{g:26s} {where:8s} {said:12s} {nominal:8.4f} {cal:10.4f}"
                  + ("  <- better printed, worse held out" if wrong else ""), flush=True)
    print(f"'better' printed where the held-out error exceeds nominal's: {count} of {splits} "
          "splits")
    return count


def main(argv: Sequence[str]) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="the squares, one mount")
    ap.add_argument("--mounts", type=int, default=3, help="mounts per experiment (default 3)")
    args = ap.parse_args(list(argv))
    if not (bc.TRAIN / "to_rosbag2.py").exists():
        print(f"skipped: {bc.TRAIN} not found (the project's shared data; a clone has none)")
        return 0
    groups: dict[str, list[Run]] = {}
    for d in bc.load_all(args.quick):
        if d.exp != bc.TRAIN_ONLY:
            groups.setdefault(d.group, []).append(d.run)
    mounts = draws(1 if args.quick else args.mounts)
    sweep(groups, mounts)
    never_better_for_worse(groups, draws(1, SEED + 1)[0])
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
