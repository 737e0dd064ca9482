"""Final-pose NEES run by run on real runs: the covariance before and after the rotation term.

    .venv/bin/python bench/bench_nees.py [--quick]

Data: the 45 OptiOdom training runs and the two bag squares, as ``bench_calibration.py``
loads them (Sousa et al., "OptiOdom: a Generic Approach for Odometry Calibration of
Wheeled Mobile Robots"). Fit side: the June 2020 sessions (ids ddmmyy = ..0620..);
held out: the December 2020 / January 2021 ones. Each run's final-pose error and the
covariance the node would publish there come from the product
(:mod:`diffdrive_odom.core.evaluation.consistency`, the fast lane's propagation); the
motion capture's own error (``REFERENCE_ERROR``, 1 mm and 0.5 deg, 1 sigma) is added.

Two geometries:
- nominal: the node as shipped (defaults), the robot uncalibrated;
- calibrated: each June run integrated with a geometry fitted on the other runs of its
  experiment (leave-one-run-out), each held-out run with one fitted on the June runs of
  its kind (calibrated in June, driven later; the free paths have no June run and are
  skipped); the geometry ratios as calibrate prints them (bootstrap over the fitting
  runs + the session drift).

The rotation noise ``k_rot`` is chosen on the fit side by maximum likelihood of the
final errors (``consistency.fit_noise``), the other parameters at their defaults or
printed values; printed with its likelihood-ratio statistic against 0. Then per kind,
fit side and held out: runs, mean NEES (two-sided 95 % band of the mean for that many
runs), runs above chi-square(3)'s 95 % quantile 7.81 and 99.9 % quantile 16.27, the
worst run; before (k_rot 0, the old defaults) and after (k_rot fitted / the default).
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from diffdrive_odom.core.evaluation import consistency, crossval
from diffdrive_odom.core.evaluation.consistency import Noise, RunTerms
from diffdrive_odom.core.evaluation.recorded_run import Run, values_of
from diffdrive_odom.core.uncertainty.noise import (
    DEFAULT_K,
    DEFAULT_RADIUS_STDDEV_RATIO,
    DEFAULT_ROTATION_K,
    DEFAULT_SEPARATION_STDDEV_RATIO,
)

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "bench"))
import bench_calibration  # noqa: E402
from bench_calibration import NOMINAL, TRAIN, Data  # noqa: E402

# A run with its terms and the geometry ratios it is judged with.
Judged = dict[str, tuple[Data, RunTerms, float, float]]


def fit_side(d: Data) -> bool:
    """A run of the June 2020 sessions (the experiment id is ddmmyyyyhhmm)."""
    return d.exp[2:6] == "0620"


def printed_ratios(runs: Sequence[Run]) -> tuple[float, float]:
    """The ratios calibrate prints for a fit on ``runs``: bootstrap + session drift."""
    geo = bench_calibration.fitter()(runs).geometry
    cov = crossval.bootstrap(runs, NOMINAL)
    assert cov is not None
    return crossval.stddev_ratios(values_of(geo), crossval.with_drift(values_of(geo), cov))


def nominal_terms(data: Sequence[Data]) -> Judged:
    return {d.run.name: (d, consistency.run_terms(d.run, NOMINAL), DEFAULT_RADIUS_STDDEV_RATIO,
                         DEFAULT_SEPARATION_STDDEV_RATIO) for d in data}


def calibrated_terms(data: Sequence[Data]) -> Judged:
    """June: leave-one-run-out in the experiment; the others: leave-one-experiment-out."""
    out: Judged = {}
    for g in dict.fromkeys(d.group for d in data):
        mine = [d for d in data if d.group == g]
        if fit_side(mine[0]):
            runs = [d.run for d in mine]
            sr, sb = printed_ratios(runs)
            for d, h in zip(mine, crossval.held_out(runs, NOMINAL), strict=True):
                assert h.geometry is not None
                out[d.run.name] = (d, consistency.run_terms(d.run, h.geometry), sr, sb)
            continue
        others = [d.run for d in data if d.kind == mine[0].kind and fit_side(d)]
        if len(others) < crossval.MIN_RUNS_FOR_SIGMA:
            print(f"  {g}: {len(others)} runs of its kind elsewhere, too few: skipped")
            continue
        geo = bench_calibration.fitter()(others).geometry
        sr, sb = printed_ratios(others)
        for d in mine:
            out[d.run.name] = (d, consistency.run_terms(d.run, geo), sr, sb)
    return out


def noise_of(k_rot: float, sr: float, sb: float, k: float = DEFAULT_K) -> Noise:
    return Noise(k, k_rot, sr, sb)


def row(label: str, judged: Judged, names: Sequence[str], k_rot: float) -> str:
    v = np.array([consistency.nees(judged[n][1], noise_of(k_rot, *judged[n][2:]))
                  for n in names])
    if len(v) == 0:
        return f"{label:34s}   0 runs"
    lo, hi = consistency.chi2_band(len(v))
    w = int(np.argmax(v))
    ok = "ok" if lo <= v.mean() <= hi else "--"
    over = v > consistency.CHI2_3_95
    return (f"{label:34s} {len(v):3d} {v.mean():6.2f} [{lo:4.2f}, {hi:4.2f}] {ok} "
            f"{int(np.sum(over)):3d} ({100 * np.mean(over):4.1f} %) "
            f"{int(np.sum(v > consistency.CHI2_3_999)):3d}   {names[w]} {v[w]:.2f}")


def table(title: str, judged: Judged, settings: Sequence[tuple[str, float]]) -> None:
    print(f"\n-- {title}")
    print(f"{'runs (kind, side) / setting':34s} {'n':>3s} {'mean':>6s} {'95 % band':>12s}    "
          f"{'>7.81':>11s} {'>16.27':>6s} worst run")
    for side, pick in (("fit side (June 2020)", True), ("held out (Dec 2020 / Jan 2021)", False)):
        names = [n for n, (d, *_) in judged.items() if fit_side(d) == pick]
        kinds = sorted({judged[n][0].kind for n in names})
        for label, k_rot in settings:
            print(f"{side}, {label}:")
            for kind in kinds:
                print(row(f"  {kind}", judged, [n for n in names if judged[n][0].kind == kind],
                          k_rot))
            print(row("  ALL", judged, names, k_rot))


def fit_rotation(label: str, judged: Judged, joint: bool, june_side: bool = True
                 ) -> tuple[float, float]:
    """ML ``k_rot`` on the June runs, each with its own ratios; and its 95 % upper bound.

    ``joint``: the runs of an experiment share their geometry error (one draw per
    session, :func:`consistency.joint_log_likelihood`), else each run is independent.
    ``june_side`` False: the same on the held-out runs (for information, never chosen).
    """
    june = [(t, sr, sb, d.group) for d, t, sr, sb in judged.values()
            if fit_side(d) == june_side]

    def ll(kr: float) -> float:
        if joint:  # one ratio pair per experiment (the same for its runs here)
            groups: dict[str, list[tuple[RunTerms, float, float]]] = {}
            for t, sr, sb, g in june:
                groups.setdefault(g, []).append((t, sr, sb))
            return sum(consistency.joint_log_likelihood(
                [[t for t, _, _ in ts]], noise_of(kr, ts[0][1], ts[0][2])) for ts in
                groups.values())
        return sum(consistency.log_likelihood([t], noise_of(kr, sr, sb))
                   for t, sr, sb, _ in june)

    best = float(max(consistency.GRID, key=ll))
    if best > 0.0:  # refine between the grid's neighbours
        best = float(max(np.geomspace(best / 10 ** 0.25, best * 10 ** 0.25, 41), key=ll))
    lr = 2.0 * (ll(best) - ll(0.0))
    bound = consistency.upper_bound(ll, best)
    want = "wanted" if lr > consistency.LR_5_PERCENT else "not wanted"
    how = "experiment-joint" if joint else "per run"
    side = "June" if june_side else "held-out (for information)"
    print(f"  {side}, {how} likelihood: k_rot = {best:.3g} rad (ratio against 0: {lr:.2f}, "
          f"{want} at 5 %); these runs reject above {bound:.2g} rad (one-sided 95 %)")
    return best, bound


def needed(judged: Judged, names: Sequence[str], limit: float) -> float | None:
    """The smallest k_rot (decades in 1/16 steps) that puts the runs under ``limit``."""
    kr = 1e-7
    while kr < 1.0:
        if all(consistency.nees(judged[n][1], noise_of(kr, *judged[n][2:])) <= limit
               for n in names):
            return kr
        kr *= 10 ** (1 / 16)
    return None


def held_names(judged: Judged) -> list[str]:
    return [n for n, (d, *_) in judged.items() if not fit_side(d)]


def main(argv: Sequence[str]) -> int:
    ap = argparse.ArgumentParser(description=(__doc__ or "").split("\n\n")[0])
    ap.add_argument("--quick", action="store_true",
                    help="the nominal geometry only (no fits): a smoke test, ~1 min")
    args = ap.parse_args(list(argv))
    if not (TRAIN / "to_rosbag2.py").exists():
        print(f"skipped: {TRAIN} not found (the project's shared data; a clone has none)")
        return 0
    data = bench_calibration.load_all(False)
    print(f"{len(data)} runs; fit side (June 2020): {sum(fit_side(d) for d in data)}, held out: "
          f"{sum(not fit_side(d) for d in data)}; reference error added: 1 mm, 0.5 deg "
          "(1 sigma, the motion capture's)")
    print(f"defaults: wheel_noise_k {DEFAULT_K:g} m, radius ratio "
          f"{DEFAULT_RADIUS_STDDEV_RATIO:g}, separation ratio {DEFAULT_SEPARATION_STDDEV_RATIO:g}, "
          f"rotation_noise_k {DEFAULT_ROTATION_K:g} rad")
    nominal = nominal_terms(data)
    judged = {"nominal geometry, the node's defaults": nominal}
    if not args.quick:
        judged["calibrated geometry, printed ratios"] = calibrated_terms(data)
    print("\n== 1. The rotation term by maximum likelihood of the June final poses ==")
    chosen: dict[str, float] = {}
    for title, j in judged.items():
        print(f"{title}:")
        _, bound = fit_rotation(title, j, joint=False)
        _, joint_bound = fit_rotation(title, j, joint=True)
        chosen[title] = min(bound, joint_bound)
        for joint in (False, True):
            fit_rotation(title, j, joint, june_side=False)
        held = held_names(j)
        worst = max(held, key=lambda n: consistency.nees(j[n][1], noise_of(0.0, *j[n][2:])))
        need = needed(j, [worst], consistency.CHI2_3_95)
        print(f"  held out, for comparison: the worst run {worst} needs k_rot "
              + ("> 1 rad" if need is None else f"{need:.2g} rad")
              + " to come under 7.81")
    print("\n== 2. Final-pose NEES per run (3 dof): mean (95 % band of the mean), runs above "
          "7.81 (95 %) and 16.27 (99.9 %), worst ==")
    for title, j in judged.items():
        settings = [("k_rot 0: before" + (", and the default (June's ML)"
                                           if DEFAULT_ROTATION_K == 0.0 else ""), 0.0)]
        if DEFAULT_ROTATION_K != 0.0:
            settings.append((f"after: k_rot {DEFAULT_ROTATION_K:g} (the default)",
                             DEFAULT_ROTATION_K))
        settings.append((f"k_rot {chosen[title]:.2g}, the largest June does not reject",
                         chosen[title]))
        table(title, j, settings)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
