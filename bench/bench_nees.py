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
import math
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
    geo = bench_calibration.fitter()(runs)
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
        geo = bench_calibration.fitter()(others)
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


def fit_rotation(label: str, judged: Judged) -> float:
    june = [(t, sr, sb) for d, t, sr, sb in judged.values() if fit_side(d)]
    # Each run its own ratios: the likelihood is summed with each run's fixed part.
    grid = consistency.GRID

    def ll(kr: float) -> float:
        return sum(consistency.log_likelihood([t], noise_of(kr, sr, sb)) for t, sr, sb in june)

    best = max(grid, key=ll)
    lr = 2.0 * (ll(best) - ll(0.0))
    # refine between the grid's neighbours
    if best > 0.0:
        xs = np.linspace(best / 10 ** 0.25, best * 10 ** 0.25, 41)
        best = float(max(xs, key=ll))
        lr = 2.0 * (ll(best) - ll(0.0))
    want = "wanted" if lr > consistency.LR_5_PERCENT else "not wanted"
    print(f"maximum likelihood on the June runs, {label}: k_rot = {best:.3g} rad "
          f"(likelihood ratio against 0: {lr:.2f}; {want} at 5 %, threshold "
          f"{consistency.LR_5_PERCENT})")
    return float(best)


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
    print("\n== Fitting the rotation term on the June runs ==")
    k_nom = fit_rotation("nominal geometry, default ratios", nominal)
    judged = {"nominal geometry, the node's defaults": nominal}
    fitted = {"nominal geometry, the node's defaults": k_nom}
    if not args.quick:
        cal = calibrated_terms(data)
        fitted["calibrated geometry, printed ratios"] = fit_rotation(
            "calibrated geometry (leave-one-run-out), printed ratios", cal)
        judged["calibrated geometry, printed ratios"] = cal
    print("\n== Final-pose NEES per run (3 dof): mean, runs above 7.81 (95 %) and 16.27 "
          "(99.9 %), worst ==")
    for title, j in judged.items():
        settings = [("before (k_rot 0)", 0.0), (f"k_rot {DEFAULT_ROTATION_K:g} (the default)",
                                                DEFAULT_ROTATION_K)]
        if not math.isclose(fitted[title], DEFAULT_ROTATION_K):
            settings.append((f"k_rot {fitted[title]:.3g} (ML on June, this geometry)",
                             fitted[title]))
        if DEFAULT_ROTATION_K == 0.0:
            settings = [s for s in settings if s[0] != "k_rot 0 (the default)"]
        table(title, j, settings)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
