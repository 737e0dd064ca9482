"""Real runs re-logged as a logger that stamps rows when it writes them (issue 37): the table.

    .venv/bin/python bench/bench_relogged.py [--quick]

Every real run (:mod:`realruns`: 47 OptiOdom runs, 7 PHIL runs; ``--quick``: 3) and its
copy made by ``test/relogged.py`` (holds of 0.1-0.3 s released 1 ms after the previous
row, up to three gaps of 1-5 s inside turns, stamps jittered by up to 2 ms; seeded by the
run's name), both replayed through replay's engine with the run's nominal parameters.
Per run: the holds and gaps (their seconds); the final heading of an anchor that
integrates every count (written without the package), of the unmodified run and of the
copy, and their differences (the run against the anchor, the copy against the run);
the ATE after the best SE(2) fit [mm] of both, on all their poses and on the same
rows (outside the copy's holds and gaps, in both: a held row's pose is stale in any
estimate, the counts being held); what replay named on the copy; the steps the
unmodified runs skipped or restarted on (counter faults, with their heading). The goals:
every heading within 0.1 deg, every same-rows ATE at most 1 mm worse; the worst run of
each and every run that missed one are named. Then, for the runs with a gyro (PHIL), the same
comparison gyro-aided (``use_imu``; no goal: the gyro-aided heading moves with the
wheels' stamp jitter alone). ``--accelerations``: per robot, how many of the
copies' gaps each ``max_wheel_acceleration`` integrates and how many it takes as
restarts (the default's trade-off, doc/concepts/gates.md).
"""

from __future__ import annotations

import argparse
import math
from collections import Counter

from realruns import real_runs
from relogged import judge, outside, relog, replay, seed_of

from diffdrive_odom.core.evaluation.metrics import evaluate

HEADING_DEG, ATE_M = 0.1, 0.001
SEEDS = 6  # copies of each run for --accelerations
ACCELERATIONS = (5.0, 10.0, 20.0, 40.0, 80.0)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--quick", action="store_true", help="3 runs")
    parser.add_argument("--accelerations", action="store_true",
                        help="also: the gaps each max_wheel_acceleration integrates, over "
                        f"{SEEDS} copies of each run (a few minutes)")
    args = parser.parse_args()
    print(f"{'run':30s} {'holds':>5s} {'gaps':>9s}  {'final heading [deg]':>25s}  "
          f"{'differences':>19s}  {'ATE [mm]: all poses':>19s}  {'same rows':>18s}  "
          "named on the copy")
    print(f"{'':30s} {'':5s} {'':9s}  {'anchor':>8s} {'run':>8s} {'copy':>8s}  "
          f"{'run-anchor':>10s} {'copy-run':>8s}  "
          f"{'run':>9s} {'copy':>9s}  {'run':>6s} {'copy':>5s} {'diff':>5s}")
    worst_heading = (0.0, "")
    worst_ate = (-math.inf, "")
    count = met = 0
    run_faults: list[tuple[str, str]] = []
    missed: list[str] = []
    for run in real_runs(args.quick):
        j = judge(run.name, run.recording, run.robot, run.params, run.truth)
        plain, copy = j.unmodified, j.relogged
        anchor = j.degrees(plain.heading, j.anchor)
        moved = j.degrees(copy.heading, plain.heading)
        gaps = sum(b - a for a, b in j.copy.gaps) * 1e-9
        ate = "      -         -       -     -     -"
        ok = abs(anchor) <= HEADING_DEG and abs(moved) <= HEADING_DEG
        if j.ate is not None:
            a_all, c_all, a_same, c_same = (1e3 * v for v in j.ate)
            ate = (f"{a_all:9.2f} {c_all:9.2f}  {a_same:6.2f} {c_same:5.2f} "
                   f"{c_same - a_same:+5.2f}")
            ok &= c_same - a_same <= 1e3 * ATE_M
            worst_ate = max(worst_ate, (c_same - a_same, run.name))
        worst_heading = max(worst_heading, (max(abs(anchor), abs(moved)), run.name))
        named = ", ".join(f"{k} {v}" for k, v in sorted(copy.reasons.items())) or "-"
        named += "" if not plain.reasons else "; the run: " + ", ".join(
            f"{k} {v}" for k, v in sorted(plain.reasons.items()))
        finals = " ".join(f"{math.degrees(h):+8.3f}" for h in (j.anchor, plain.heading,
                                                                copy.heading))
        print(f"{run.name:30s} {len(j.copy.holds):5d} {len(j.copy.gaps):2d} ({gaps:4.1f}s)  "
              f"{finals}  {anchor:+10.4f} {moved:+8.4f}  {ate}  {named}")
        if plain.reasons:
            run_faults.append((run.name, ", ".join(
                f"{k} {v}" for k, v in sorted(plain.reasons.items()))
                + f"; heading {anchor:+.4f} deg from the anchor"))
        if not ok:
            missed.append(run.name)
        count += 1
        met += ok
    faults = [f"{name} ({codes})" for name, codes in run_faults] or ["none"]
    print("steps the unmodified runs skipped or restarted on (counter faults): "
          + "; ".join(faults))
    print(f"goals (heading within {HEADING_DEG} deg of the run's and the anchor's, same-rows "
          f"ATE at most {1e3 * ATE_M:g} mm worse): met on {met} of {count} runs; worst heading "
          f"{worst_heading[0]:.4f} deg ({worst_heading[1]}), worst ATE change "
          f"{worst_ate[0]:+.2f} mm ({worst_ate[1]}); missed on: {', '.join(missed) or 'none'}")
    gyro_aided(args.quick)
    if args.accelerations:
        accelerations(args.quick)
    return 0


def gyro_aided(quick: bool) -> None:
    """The runs with a gyro (PHIL), ``use_imu``: the copy's final heading and its ATE
    (same rows) against the run's; the logger's copy does not touch the IMU's samples,
    which keep their own stamps (the gyro-aided heading follows the wheels' stamps: their
    jitter alone moves it)."""
    rows = []
    for run in real_runs(quick):
        if not run.imu:
            continue
        params = {**run.params, "use_imu": True}
        copy = relog(run.recording, run.robot, seed_of(run.name))
        a = replay(run.recording, params, run.imu)
        b = replay(copy.recording, params, run.imu)
        moved = math.degrees(math.remainder(b.heading - a.heading, 2 * math.pi))
        ate = "-"
        if run.truth is not None:
            windows = copy.holds + copy.gaps
            fa, fb = (evaluate(outside(r.trajectory, windows), run.truth).ate_rmse_best_fit_m
                      for r in (a, b))
            ate = f"{1e3 * fa:.2f} -> {1e3 * fb:.2f} mm"
        rows.append(f"  {run.name:14s} heading copy-run {moved:+.3f} deg; same-rows ATE {ate}")
    if rows:
        print("\ngyro-aided (use_imu), the run against its copy:")
        print("\n".join(rows))


def accelerations(quick: bool) -> None:
    """Per robot and ``max_wheel_acceleration``: the copies' gaps integrated, and those
    taken as restarts (motion lost) with the reason's kind, over SEEDS copies a run."""
    counts: dict[tuple[str, float], Counter[str]] = {}
    for run in real_runs(quick):
        robot = "PHIL (16-bit)" if run.robot.counter_bits else "OptiOdom"
        for seed in range(SEEDS):
            rows = relog(run.recording, run.robot, seed_of(run.name) + seed).recording
            for a in ACCELERATIONS:
                r = replay(rows, {**run.params, "max_wheel_acceleration": a})
                c = counts.setdefault((robot, a), Counter())
                c["integrated"] += r.reasons["gap_integrated"]
                if r.reasons["gap"]:
                    c["ambiguous" if "ambiguous" in r.examples["gap"] else "beyond"] += (
                        r.reasons["gap"])
    print(f"\nmax_wheel_acceleration [rad/s^2]: the copies' gaps ({SEEDS} copies a run), "
          "integrated / taken as restarts (beyond what the speeds allow, or a wrapping "
          "counter's ambiguous)")
    for (robot, a), c in sorted(counts.items()):
        print(f"  {robot:14s} {a:5g}: integrated {c['integrated']:4d}, beyond "
              f"{c['beyond']:3d}, ambiguous {c['ambiguous']:3d}")


if __name__ == "__main__":
    raise SystemExit(main())
