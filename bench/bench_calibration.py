"""Calibration and covariance judged on OptiOdom runs they were not fitted to.

    .venv/bin/python bench/bench_calibration.py [--quick]

Data: ``../shared/data/optiodom_train`` (45 runs of one real robot, 8 experiments, June
2020, December 2020 and January 2021; Sousa et al., "OptiOdom: a Generic Approach for
Odometry Calibration of Wheeled Mobile Robots", J Intell Robot Syst 105:39, 2022),
converted once with its own ``to_rosbag2.py`` into a cache folder
(``$XDG_CACHE_HOME/diffdrive_odom`` or ``/tmp/diffdrive_odom``, never the repository),
plus the two squares of ``../shared/data/optiodom``. Skips, saying so, where the data
are missing. Everything goes through the product: bags read by ``tools.bags.bagreadings``, steps
by the node's pipeline, fits by ``core.evaluation.calibration``, held-out fits and bootstrap by
``core.evaluation.crossval``, covariance by the node's own ``ReadingPipeline``.

Prints:
1. objectives compared on held-out runs (why the whole-trajectory Cauchy fit);
2. per experiment and overall: nominal, in-sample, leave-one-run-out (LORO) and
   leave-one-experiment-out within a kind (LOEO) final position error (start aligned,
   mean / worst), ATE and relative error per metre, beside the paper's figures where
   known (quoted from the project README and issue 16, not from the paper's text);
3. the printed sigma (bootstrap over runs + a drift between sessions chosen on the June
   2020 experiments) and its coverage: how often another experiment's fit of the same
   robot lies within the printed 1 (2) sigma, on pairs that did not choose the drift,
   before (bootstrap alone) and after;
4. final-pose NEES on real runs: the defaults chosen on the June sessions and judged on
   the others, and calibrated values held out. The NEES compares odometry with the
   motion capture, so the reference's own error (the tracked point is not exactly the
   axle centre, the markers' yaw: ``REFERENCE_ERROR``, 1 mm and 0.5 deg, 1 sigma) is
   added to the covariance; it is named, and the figures without it are printed too.
"""

from __future__ import annotations

import argparse
import math
import os
import subprocess
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np

from diffdrive_odom.core.bulk import batch
from diffdrive_odom.core.bulk.readings import JointReading
from diffdrive_odom.core.estimation.pipeline import ReadingPipeline
from diffdrive_odom.core.evaluation import calibration, crossval, determinacy
from diffdrive_odom.core.evaluation.metrics import Metrics
from diffdrive_odom.core.evaluation.recorded_run import Run, values_of
from diffdrive_odom.core.geometry.kinematics import Geometry
from diffdrive_odom.core.uncertainty.noise import (
    DEFAULT_K,
    DEFAULT_RADIUS_STDDEV_RATIO,
    DEFAULT_SEPARATION_STDDEV_RATIO,
    SESSION_DRIFT_RATIO,
)
from diffdrive_odom.core.uncertainty.propagation import geometry_term
from diffdrive_odom.settings.odometry import odometry_settings
from diffdrive_odom.tools.bags import bagreadings, poses

ROOT = Path(__file__).resolve().parent.parent
SHARED = ROOT.parent / "shared" / "data"
TRAIN, TEST = SHARED / "optiodom_train", SHARED / "optiodom"
NOMINAL = Geometry(0.042, 0.200)
NOMINAL_VALUES = values_of(NOMINAL)  # (left radius, right radius, separation) [m]
PARAMS = {"wheel_radius": 0.042, "wheel_separation": 0.200}
REFERENCE_ERROR = np.diag([0.001**2, 0.001**2, math.radians(0.5) ** 2])
# Quoted from the project README / issue 16 (the paper's text is not in this repository):
# worst final position error after calibration per kind; the squares' E_max.
PAPER = {"circular": "0.009 (OptiOdom)", "square": "0.007 (UMBmark)",
         "square/231220200029": "E_max 0.0304 OptiOdom, 0.0230 UMBmark; nominal 0.1075"}


@dataclass
class Data:
    """A run with its experiment and its readings (for the node's pipeline)."""

    run: Run
    kind: str
    exp: str
    readings: list[JointReading]

    @property
    def group(self) -> str:
        return f"{self.kind}/{self.exp}"


def cache_dir() -> Path:
    base = os.environ.get("XDG_CACHE_HOME") or "/tmp"
    return Path(base) / "diffdrive_odom" / "optiodom_train_bags"


def load(bag: Path, kind: str, exp: str) -> Data:
    settings = odometry_settings(PARAMS)
    readings = list(bagreadings.read_joint_states(bag))
    steps = batch.wheel_steps(readings, settings)
    ref = poses.read_trajectory(bag, "/ground_truth/pose")
    return Data(Run(bag.name, steps, ref), kind, exp, readings)


def bags() -> Path:
    """The 45 training runs as bags in the cache folder, converted on first use."""
    out = cache_dir()
    if len([p for p in out.glob("*_run-*") if p.is_dir()]) < 45:
        out.mkdir(parents=True, exist_ok=True)
        print(f"converting {TRAIN} into {out} (its to_rosbag2.py) ...", flush=True)
        subprocess.run([sys.executable, str(TRAIN / "to_rosbag2.py"), str(out)], check=True,
                       stdout=subprocess.DEVNULL)
    return out


def load_all(quick: bool) -> list[Data]:
    out = bags()
    data = []
    for bag in sorted(p for p in out.glob("*_run-*") if p.is_dir()):
        kind, exp, _ = bag.name.split("_")
        if quick and kind != "square":
            continue
        data.append(load(bag, kind, exp))
    if not quick:
        data += [load(bag, "square", "231220200029") for bag in sorted(TEST.glob("square_*"))]
    return data


def fitter(**kw: Any) -> Callable[[Sequence[Run]], calibration.Fit]:
    def f(runs: Sequence[Run]) -> calibration.Fit:
        return calibration.fit(runs, NOMINAL, figures=False, **kw)
    return f


_SHAPES: dict[str, determinacy.Shape] = {}


def lever_rule(runs: Sequence[Run]) -> calibration.MountSpec:
    """``calibrate``'s rule for the mount: its lever arm fitted where these runs determine it.

    The runs' shapes taken on the axle (where these references are), once per run.
    """
    for r in runs:
        if r.name not in _SHAPES:
            _SHAPES[r.name] = determinacy.shape(r, NOMINAL, lever=True)
    held = determinacy.lever_reason([_SHAPES[r.name] for r in runs])
    return calibration.YAW_ONLY if held else calibration.MountSpec(lever=True)


def product(runs: Sequence[Run]) -> calibration.Fit:
    """The product's fit: the whole trajectory, the mount's yaw, its lever arm where determined."""
    return calibration.fit(runs, NOMINAL, figures=False, mount=lever_rule(runs))


TRAIN_ONLY = "231220200029"  # the bag squares: never in a training group of the others


def cross_validate(data: Sequence[Data], fit: Callable[[Sequence[Run]], calibration.Fit]
                   ) -> dict[str, dict[str, list[Metrics]]]:
    """Per group: metrics of each run for nominal, in-sample, LORO and LOEO geometries."""
    groups = dict.fromkeys(d.group for d in data)
    out: dict[str, dict[str, list[Metrics]]] = {}
    for g in groups:
        mine = [d for d in data if d.group == g]
        kind = mine[0].kind
        others = [d.run for d in data if d.kind == kind and d.group != g
                  and d.exp != TRAIN_ONLY]
        runs = [d.run for d in mine]
        cols: dict[str, list[Metrics]] = {"nominal": [], "in-sample": [], "LORO": [],
                                          "LOEO": []}
        g_in = fit(runs).geometry
        g_eo = fit(others).geometry if others else None
        cols["nominal"] = [calibration.figures_of(r, NOMINAL) for r in runs]
        cols["in-sample"] = [calibration.figures_of(r, g_in) for r in runs]
        if len(runs) > 1 and mine[0].exp != TRAIN_ONLY:
            cols["LORO"] = [calibration.figures_of(r, h.geometry) for r, h in
                            zip(runs, crossval.held_out(runs, NOMINAL, fitter=fit), strict=True)
                            if h.geometry is not None]
        if g_eo is not None:
            cols["LOEO"] = [calibration.figures_of(r, g_eo) for r in runs]
        out[g] = cols
    return out


def summary(ms: Sequence[Metrics]) -> tuple[float, float, float, float]:
    fpe = [m.final_position_error_aligned_m for m in ms]
    return (float(np.mean(fpe)), float(np.max(fpe)),
            float(np.mean([m.ate_rmse_aligned_m for m in ms])),
            float(np.nanmean([m.rpe_translation_per_m for m in ms])))


def pooled(cv: dict[str, dict[str, list[Metrics]]], col: str) -> list[Metrics]:
    return [m for g, c in cv.items() if TRAIN_ONLY not in g for m in c[col]]


def worse(cv: dict[str, dict[str, list[Metrics]]]) -> int:
    """Experiments where a held-out mean final error is above nominal's."""
    n = 0
    for c in cv.values():
        nom = summary(c["nominal"])[0]
        n += any(c[k] and summary(c[k])[0] > nom for k in ("LORO", "LOEO"))
    return n


def objectives(data: Sequence[Data], quick: bool) -> None:
    print("\n== 1. Objectives on held-out runs: mean final position error (start aligned) "
          "and ATE [m], all training runs ==")
    print(f"{'objective':34s} {'in-sample':>9s} {'LORO':>7s} {'LOEO':>7s} {'ATE LORO':>8s} "
          f"{'ATE LOEO':>8s} {'exp. worse':>10s}")
    rows: list[tuple[str, dict[str, Any]]] = [
            ("end poses (OptiOdom-like)", dict(ends_only=True, loss="linear",
                                               mount=calibration.ON_AXLE)),
            ("end poses + start yaw", dict(ends_only=True, loss="linear")),
            ("whole trajectory", dict(loss="linear", mount=calibration.ON_AXLE)),
            ("whole trajectory + start yaw", dict(loss="linear")),
            ("whole trajectory + yaw, Cauchy", {}),
            ("whole trajectory + mount, Cauchy *", {"mount": None})]
    if quick:
        rows = rows[2:]
    for label, kw in rows:
        cv = cross_validate(data, product if kw.get("mount", 0) is None else fitter(**kw))
        s = [summary(pooled(cv, c)) for c in ("in-sample", "LORO", "LOEO")]
        print(f"{label:34s} {s[0][0]:9.4f} {s[1][0]:7.4f} {s[2][0]:7.4f} {s[1][2]:8.4f} "
              f"{s[2][2]:8.4f} {worse(cv):4d} of {len(cv)}", flush=True)
    print("* the product's fit (the mount's yaw, its lever arm where the runs determine it; "
          "'start yaw' is the mount's yaw alone). Nominal: "
          + "{:.4f} m final, {:.4f} m ATE".format(*[summary(pooled(cv, 'nominal'))[i]
                                                     for i in (0, 2)]))


def per_experiment(data: Sequence[Data]) -> None:
    cv = cross_validate(data, product)
    print("\n== 2. The product's fit per experiment: final position error mean/worst [m], "
          "ATE [m], relative error [%/m] ==")
    cols = ("nominal", "in-sample", "LORO", "LOEO")
    print(f"{'experiment':24s}" + "".join(f"{c:>30s}" for c in cols) + "  paper (quoted)")
    rows = [*cv.items(), ("ALL training runs", {c: pooled(cv, c) for c in cols})]
    for g, c in rows:
        line = f"{g:24s}"
        for col in cols:
            if not c[col]:
                line += f"{'-':>30s}"
                continue
            m, w, a, r = summary(c[col])
            line += f"  {m:.4f}/{w:.4f} {a:.4f} {100 * r:5.2f}%"
        paper = PAPER.get(g.split("/")[0] if TRAIN_ONLY not in g else g, "")
        print(line + "  " + paper)
    print("(square/231220200029: the two bags of ../optiodom; LOEO = fitted on the 12 "
          "training squares; no LORO: one square per direction)")


def june(group: str) -> bool:
    """An experiment of the June 2020 sessions (its name starts ddmmyy)."""
    return group.split("/")[1][2:6] == "0620"


def coverage(data: Sequence[Data]) -> dict[str, tuple[Geometry, np.ndarray | None]]:
    print("\n== 3. Bootstrap over runs (20 resamples) + drift between sessions: the printed "
          "sigma and its coverage held out ==")
    fits: dict[str, tuple[Geometry, np.ndarray | None]] = {}
    for g in dict.fromkeys(d.group for d in data):
        runs = [d.run for d in data if d.group == g]
        geo = fitter()(runs).geometry
        cov = crossval.bootstrap(runs, NOMINAL)
        fits[g] = (geo, cov)
        v = values_of(geo)
        sig = "fewer than 3 runs: none" if cov is None else "bootstrap " + " ".join(
            f"{s:.5f}" for s in np.sqrt(np.diag(cov))) + ", printed " + " ".join(
            f"{s:.5f}" for s in np.sqrt(np.diag(crossval.with_drift(v, cov))))
        print(f"{g:24s} r_L {v[0]:.5f} r_R {v[1]:.5f} b {v[2]:.5f}  1-sigma {sig}")
    est = {g: (values_of(geo), c) for g, (geo, c) in fits.items() if c is not None}
    names = list(est)
    sets = {"June": [g for g in names if june(g)], "Dec/Jan": [g for g in names if not june(g)]}
    chosen: dict[str, float | None] = {}
    for label, gs in sets.items():
        dates = sorted({g.split("/")[1][:6] for g in gs})
        r = None if len(gs) < 2 else crossval.drift_ratio([est[g][0] for g in gs],
                                                          [est[g][1] for g in gs])
        chosen[label] = r
        ratio = "-" if r is None else f"{100 * r:.3f} %"
        print(f"drift ratio chosen on the {label} experiments ({len(gs)}, recorded on "
              f"{', '.join(dates) or '-'} ddmmyy): {ratio}")
    print(f"printed (SESSION_DRIFT_RATIO, chosen on June): "
          f"{100 * SESSION_DRIFT_RATIO:.3f} %")
    pairs = {"June-June (chose the term)": [(a, b) for a in sets["June"] for b in sets["June"]
                                            if a < b],
             "Dec/Jan-Dec/Jan (held out)": [(a, b) for a in sets["Dec/Jan"]
                                            for b in sets["Dec/Jan"] if a < b],
             "fit in June, judged Dec/Jan (held out)": [(a, b) for a in sets["June"]
                                                        for b in sets["Dec/Jan"]],
             "same kind, any session": [(a, b) for a in names for b in names
                                        if a < b and a.split("/")[0] == b.split("/")[0]],
             "any two": [(a, b) for a in names for b in names if a < b]}
    ratios = {"bootstrap only (before)": 0.0,
              "+ drift chosen on June (printed)": SESSION_DRIFT_RATIO,
              "+ drift chosen on Dec/Jan": chosen["Dec/Jan"]}
    print("|z| = |fit A - fit B| / sqrt(A's printed sigma^2 + B's bootstrap sigma^2), per "
          "value (r_L, r_R, b); % within 1 (2) sigma, 68 (95) % if it covers:")
    print(f"{'pairs of experiments':40s} {'n':>3s}" + "".join(f"{k:>34s}" for k in ratios))
    for label, ps in pairs.items():
        if not ps:
            continue
        line = f"{label:40s} {3 * len(ps):3d}"
        for r in ratios.values():
            if r is None:
                line += f"{'-':>34s}"
                continue
            z = np.array([crossval.pair_z(est[a][0], crossval.with_drift(*est[a], r), *est[b])
                          for a, b in ps])
            line += f"{100 * np.mean(z < 1):25.0f} % / {100 * np.mean(z < 2):3.0f} %"
        print(line)
    return fits


@dataclass
class Terms:
    """A run's final pose error and its covariance per unit k and its sensitivity J."""

    error: np.ndarray
    unit: np.ndarray  # P for k_left = k_right = 1
    sensitivity: tuple[tuple[float, ...], ...]


def terms(d: Data, geometry: Geometry) -> Terms:
    """The node's pipeline over the run's readings, k = 1 and no geometry term."""
    s = odometry_settings({**PARAMS, "wheel_noise_k_left": 1.0, "wheel_noise_k_right": 1.0,
                           "wheel_radius_stddev_ratio": 0.0,
                           "wheel_separation_stddev_ratio": 0.0,
                           "left_wheel_radius_multiplier": geometry.left_wheel_radius_multiplier,
                           "right_wheel_radius_multiplier":
                               geometry.right_wheel_radius_multiplier,
                           "wheel_separation_multiplier": geometry.wheel_separation_multiplier})
    pipe = ReadingPipeline(s)
    for r in d.readings:
        pipe.feed(r.stamp_ns, r.names, r.position, r.velocity)
    est = pipe.estimator
    assert est.uncertainty is not None
    ref = calibration.prepare(d.run, 0.5, ends_only=True).reference[-1]
    pose = est.pose
    err = np.array([pose.x - ref[0], pose.y - ref[1],
                    math.remainder(pose.theta - ref[2], 2 * math.pi)])
    return Terms(err, np.array(est.uncertainty.covariance), est.uncertainty.sensitivity)


def nees(t: Terms, k: float, sr: float, sb: float, reference: bool = True) -> float:
    cov = k * t.unit + np.array(geometry_term(t.sensitivity, sr, sb))
    if reference:
        cov = cov + REFERENCE_ERROR
    return float(t.error @ np.linalg.solve(cov, t.error))


def chi2_band(n: int) -> tuple[float, float]:
    """Two-sided 95 % band of the mean of n chi-square(3) values (Wilson-Hilferty)."""
    dof = 3 * n
    c = 2.0 / (9.0 * dof)
    return tuple(dof * (1 - c + z * math.sqrt(c)) ** 3 / n for z in (-1.96, 1.96))  # type: ignore[return-value]


def verdict(label: str, values: dict[str, list[float]]) -> None:
    allv = [v for vs in values.values() for v in vs]
    lo, hi = chi2_band(len(allv))
    worst_g, worst = max(((g, float(np.mean(v))) for g, v in values.items()),
                         key=lambda t: t[1])
    mean = float(np.mean(allv))
    ok = "OK" if lo <= mean <= hi and worst <= 9.0 else "--"
    print(f"{label:52s} {len(allv):3d} runs mean {mean:5.2f} [{lo:.2f}, {hi:.2f}] worst "
          f"{worst_g} {worst:5.2f}  {ok}")


def nees_section(data: Sequence[Data], quick: bool) -> None:
    print("\n== 4. Final-pose NEES on real runs (3 dof; OK = mean in the two-sided 95 % band "
          "and no experiment mean above 9, i.e. 3x overconfident) ==")
    nominal = {d.run.name: terms(d, NOMINAL) for d in data}
    june = [d for d in data if d.exp[2:6] == "0620"]
    rest = [d for d in data if d.exp[2:6] != "0620"]

    def by_group(ds: Sequence[Data], f: Callable[[Data], float]) -> dict[str, list[float]]:
        out: dict[str, list[float]] = {}
        for d in ds:
            out.setdefault(d.group, []).append(f(d))
        return out

    verdict("before issue 16: k 1e-5, no geometry term, no ref.", by_group(
        data, lambda d: nees(nominal[d.run.name], 1e-5, 0.0, 0.0, False)))
    print("defaults chosen on the June 2020 sessions, judged on Dec 2020 / Jan 2021 "
          "(nominal geometry; * = the defaults):")
    for k in (3e-7, 1e-6, 3e-6):
        for sr in (0.001, 0.0025, 0.005):
            for sb in (0.005, 0.01, 0.02):
                star = "*" if (k, sr, sb) == (DEFAULT_K, DEFAULT_RADIUS_STDDEV_RATIO,
                                              DEFAULT_SEPARATION_STDDEV_RATIO) else " "
                if quick and star == " ":
                    continue
                for part, ds in (("June", june), ("other", rest)):
                    if ds:
                        def one(d: Data, k: float = k, sr: float = sr,
                                sb: float = sb) -> float:
                            return nees(nominal[d.run.name], k, sr, sb)
                        verdict(f"{star} k {k:g} sr {100 * sr:.2f} % sb {100 * sb:.1f} % {part}",
                                by_group(ds, one))
    d_k, d_r, d_b = DEFAULT_K, DEFAULT_RADIUS_STDDEV_RATIO, DEFAULT_SEPARATION_STDDEV_RATIO
    verdict("defaults, all runs", by_group(data, lambda d: nees(nominal[d.run.name],
                                                                 d_k, d_r, d_b)))
    verdict("defaults, all runs, without the reference error", by_group(
        data, lambda d: nees(nominal[d.run.name], d_k, d_r, d_b, False)))
    # Calibrated, held out: geometry and bootstrap ratios from the other experiments
    # of the kind (the bag squares: from the 12 training squares).
    held: dict[str, tuple[Terms, float, float]] = {}
    before: dict[str, tuple[float, float]] = {}
    for g in dict.fromkeys(d.group for d in data):
        mine = [d for d in data if d.group == g]
        others = [d.run for d in data if d.kind == mine[0].kind and d.group != g
                  and d.exp != TRAIN_ONLY]
        if len(others) < crossval.MIN_RUNS_FOR_SIGMA:
            continue
        geo = fitter()(others).geometry
        cov = crossval.bootstrap(others, NOMINAL)
        assert cov is not None
        sr, sb = crossval.stddev_ratios(values_of(geo), crossval.with_drift(values_of(geo),
                                                                             cov))
        br, bb = crossval.stddev_ratios(values_of(geo), cov)
        print(f"  LOEO {g}: fitted on {len(others)} runs, printed ratios radius "
              f"{100 * sr:.3f} %, separation {100 * sb:.3f} % (bootstrap alone "
              f"{100 * br:.3f} %, {100 * bb:.3f} %)")
        for d in mine:
            held[d.run.name] = (terms(d, geo), sr, sb)
            before[d.run.name] = (br, bb)
    ds = [d for d in data if d.run.name in held]
    for label, ref in (("calibrated LOEO (held out), k default, printed ratios", True),
                       ("the same without the reference error", False)):
        verdict(label, by_group(ds, partial(_held_nees, held, d_k, ref)))
    boot = {n: (t, *before[n]) for n, (t, _, _) in held.items()}
    verdict("the same with the bootstrap-only ratios (before)",
            by_group(ds, partial(_held_nees, boot, d_k, True)))


def _held_nees(held: dict[str, tuple[Terms, float, float]], k: float, reference: bool,
               d: Data) -> float:
    t, sr, sb = held[d.run.name]
    return nees(t, k, sr, sb, reference)


def main(argv: Sequence[str]) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true",
                    help="the 12 training squares only, fewer objectives (a smoke test)")
    args = ap.parse_args(list(argv))
    if not (TRAIN / "to_rosbag2.py").exists():
        print(f"skipped: {TRAIN} not found (the project's shared data; a clone has none)")
        return 0
    data = load_all(args.quick)
    print(f"{len(data)} runs, {len({d.group for d in data})} experiments")
    objectives(data, args.quick)
    per_experiment(data)
    coverage(data)
    nees_section(data, args.quick)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
