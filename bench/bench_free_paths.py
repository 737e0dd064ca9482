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

Section 2 measures what else could bring the free paths' in-sample worst down, each
judged the same way on all runs: the reference's offset from the axle fitted (its mount,
``se2.conjugate``), its clock lag fitted, one start yaw per run or none, each residual
sample weighted by the distance (and turn) it covers instead of by sample, the heading
residual weighted 0, 0.5 or 2 times half the separation. Section 3 is the floor no
objective can beat: the smallest worst final error over free/030120210001's two runs that
any single geometry reaches (a minimax fit), free and with the wheel scale (mean radius)
held at the values this robot's fits give.

``--quick``: the free paths only, the default and W = 0.5, and section 3.
"""

from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Callable, Sequence
from functools import partial
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
from scipy import optimize

from diffdrive_odom.core.bulk.batch import integrate_steps
from diffdrive_odom.core.evaluation import calibration
from diffdrive_odom.core.evaluation.metrics import interpolate
from diffdrive_odom.core.evaluation.recorded_run import Run, start_stamp, values_of, with_values
from diffdrive_odom.core.geometry.kinematics import Geometry
from diffdrive_odom.core.geometry.mount import AXLE
from diffdrive_odom.core.geometry.se2 import between, conjugate, wrap_angles

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "bench"))
import bench_calibration as bc  # noqa: E402

FREE = "free/030120210001"  # the free-path experiment with two runs
# Section 2: what else was tried (keyword arguments of candidate_fit).
CANDIDATES: tuple[tuple[str, dict[str, Any]], ...] = (
    ("default (this fit; = calibrate's)", {}),
    ("+ mount offset", {"mount": True}),
    ("+ clock lag", {"lag": True}),
    ("+ mount offset + clock lag", {"mount": True, "lag": True}),
    ("start yaw per run", {"yaw": "per run"}),
    ("no start yaw", {"yaw": "none"}),
    ("weights by distance", {"weight": "distance"}),
    ("heading x0.5", {"heading": 0.5}),
    ("heading x2", {"heading": 2.0}),
    ("heading x0 (positions only)", {"heading": 0.0}),
)
TURN_LENGTH = 0.1  # m per rad of turn, for the distance weights (about half the separation)

OBJECTIVES: tuple[tuple[str, dict[str, Any]], ...] = (
    ("default (whole trajectory)", {}),
    ("+ end weight 0.2", {"end_weight": 0.2}),
    ("+ end weight 0.5", {"end_weight": 0.5}),
    ("+ end weight 1", {"end_weight": 1.0}),
    ("end poses (OptiOdom-like)", {"ends_only": True, "loss": "linear",
                                   "mount": calibration.ON_AXLE}),
)


def _fpe(ms: Sequence[Any]) -> list[float]:
    return [m.final_position_error_aligned_m for m in ms]


def _cell(values: list[float]) -> str:
    return f"{np.mean(values):.4f}/{max(values):.4f}" if values else "-"


class _Samples:
    """A run's residual samples (``calibration.prepare``), its reference re-read at a lag."""

    def __init__(self, run: Run) -> None:
        self.prepared = calibration.prepare(run, 0.5)
        self.run = run
        self.stamps = np.concatenate(([start_stamp(run.steps)],
                                      run.steps.stamp_ns[self.prepared.index]))
        ref = self.prepared.reference
        step = np.diff(np.vstack((np.zeros(3), ref)), axis=0)
        covered = np.hypot(step[:, 0], step[:, 1]) + TURN_LENGTH * np.abs(step[:, 2])
        self.distance_weight = np.sqrt(covered / covered.sum())

    def reference(self, lag: float) -> np.ndarray:
        if lag == 0.0:
            return self.prepared.reference
        poses = interpolate(self.run.reference, self.stamps, lag)  # type: ignore[arg-type]
        return between(np.repeat(poses[:1], len(poses) - 1, axis=0), poses[1:])


def candidate_fit(runs: Sequence[Run], *, yaw: str = "shared", mount: bool = False,
                  lag: bool = False, weight: str = "sample", heading: float = 1.0) -> Geometry:
    """``calibration.fit``'s objective (whole trajectory, Cauchy scaled by the MAD of a
    least-squares fit) with other nuisances and weights: ``yaw`` "shared" (the default),
    "per run" or "none"; the reference's ``mount`` offset (x, y on the robot) and clock
    ``lag`` fitted; ``weight`` "sample" (1/sqrt(samples) per run) or "distance"; the
    heading residual times ``heading`` x half the separation."""
    samples = [_Samples(r) for r in runs]
    x0 = values_of(bc.NOMINAL)
    heading_length = heading * 0.5 * bc.NOMINAL.separation
    n_yaw = {"none": 0, "shared": 1, "per run": len(runs)}[yaw]
    extra = [(-math.pi, math.pi, 1e-2)] * n_yaw + [(-0.1, 0.1, 1e-3)] * (2 * mount) \
        + [(-0.2, 0.2, 1e-2)] * lag

    def geometry(x: np.ndarray) -> Geometry:
        return with_values(bc.NOMINAL, *(float(v) for v in x0 * x[:3]))

    def res(x: np.ndarray) -> np.ndarray:
        g, rest = geometry(x), x[3:]
        yaws = np.broadcast_to(rest[:n_yaw], len(runs)) if n_yaw else np.zeros(len(runs))
        dx, dy = rest[n_yaw:n_yaw + 2] if mount else (0.0, 0.0)
        lg = float(rest[-1]) if lag else 0.0
        out = []
        for p, psi in zip(samples, yaws, strict=True):
            x_, y_, th = integrate_steps(p.run.steps, g)
            i = p.prepared.index
            ref = conjugate(p.reference(lg), float(dx), float(dy), float(psi))
            e = np.column_stack((x_[i] - ref[:, 0], y_[i] - ref[:, 1],
                                 heading_length * wrap_angles(th[i] - ref[:, 2])))
            w = p.distance_weight if weight == "distance" else 1.0 / math.sqrt(len(i))
            out.append((e * np.reshape(w, (-1, 1))).ravel())
        return np.concatenate(out)

    lo, hi, scale = (np.array([0.2] * 3 + [e[0] for e in extra]),
                     np.array([5.0] * 3 + [e[1] for e in extra]),
                     np.array([1e-3] * 3 + [e[2] for e in extra]))
    kw: dict[str, Any] = {"bounds": (lo, hi), "x_scale": scale, "xtol": 1e-12, "ftol": 1e-12,
                          "gtol": 1e-12}
    sol = optimize.least_squares(res, np.concatenate((np.ones(3), np.zeros(len(extra)))), **kw)
    mad = 1.4826 * float(np.median(np.abs(sol.fun - np.median(sol.fun)))) or 1e-6
    sol = optimize.least_squares(res, sol.x, loss="cauchy", f_scale=mad, **kw)
    return geometry(np.asarray(sol.x))


def geometry_of(fit: Callable[[Sequence[Run]], calibration.Fit]
                ) -> Callable[[Sequence[Run]], Geometry]:
    """A fitter's geometry alone."""
    return lambda runs: fit(runs).geometry


def as_fit(fit: Callable[[Sequence[Run]], Geometry]) -> Callable[[Sequence[Run]], Any]:
    """A geometry fitter as the held-out folds take one (its mount: the axle, these runs')."""
    return lambda runs: SimpleNamespace(geometry=fit(runs), mount=AXLE)


def end_errors(runs: Sequence[Run], geometry: Geometry) -> np.ndarray:
    """Each run's final position error, start aligned (``eval``'s figure), [m]."""
    return _end_errors([calibration.prepare(r, 0.5, ends_only=True) for r in runs], geometry)


def _end_errors(ends: Sequence[Any], geometry: Geometry) -> np.ndarray:
    out = []
    for p in ends:
        x, y, _ = integrate_steps(p.run.steps, geometry)
        i = int(p.index[-1])
        out.append(math.hypot(x[i] - p.reference[-1, 0], y[i] - p.reference[-1, 1]))
    return np.array(out)


def best_worst(runs: Sequence[Run], nominal: Geometry, scale: float | None = None
               ) -> tuple[float, Geometry]:
    """The smallest worst final error over ``runs`` any single geometry reaches, and it.

    A minimax fit (Nelder-Mead from three starts) over the mean radius (times
    ``nominal``'s; held at ``scale`` if given), the radius ratio and the separation: no
    objective can end all ``runs`` closer than this.
    """
    r0, b0 = nominal.wheel_radius, nominal.wheel_separation
    ends = [calibration.prepare(r, 0.5, ends_only=True) for r in runs]

    def geometry(p: Sequence[float]) -> Geometry:
        s = scale if scale is not None else p[2]
        return with_values(nominal, s * r0 * (1 - p[0]), s * r0 * (1 + p[0]), p[1] * b0)

    def worst(p: np.ndarray) -> float:
        return float(_end_errors(ends, geometry(list(p))).max())

    def margin(q: np.ndarray) -> np.ndarray:  # the bound q[-1] minus each run's error
        return np.asarray(q[-1] - _end_errors(ends, geometry(list(q[:-1]))))

    starts = [[0.0, b, 1.0] for b in (0.95, 1.0, 1.05)]
    found = [optimize.minimize(worst, s[:2] if scale is not None else s, method="Nelder-Mead",
                               options={"xatol": 1e-9, "fatol": 1e-9, "maxiter": 4000})
             for s in starts]
    best = min(found, key=lambda o: float(o.fun))
    # Nelder-Mead stalls on the max's kink; the epigraph form (least bound t with every
    # error <= t) is smooth: polish there.
    polish = optimize.minimize(lambda q: q[-1], np.append(best.x, best.fun), method="SLSQP",
                               constraints=[{"type": "ineq", "fun": margin}],
                               options={"ftol": 1e-12, "maxiter": 500})
    x = polish.x[:-1] if worst(polish.x[:-1]) < best.fun else best.x  # (its status may
    # say "precision" at the optimum)
    return worst(x), geometry(list(x))


def minimax_section(data: Sequence[bc.Data]) -> None:
    runs = [d.run for d in data if d.group == FREE]
    print(f"\n== 3. The floor on {FREE}: the smallest worst final error (start aligned) over "
          "its runs any single geometry reaches ==")
    fits: dict[str, Callable[[Sequence[Run]], Geometry]] = {
        "end poses (OptiOdom-like)": geometry_of(bc.fitter(ends_only=True, loss="linear",
                                                           mount=calibration.ON_AXLE)),
        "default (whole trajectory)": geometry_of(bc.fitter())}
    rows: list[tuple[str, Geometry]] = [(k, f(runs)) for k, f in fits.items()]
    rows += [(f"default, {r.name[-6:]} alone", bc.fitter()([r]).geometry) for r in runs]
    free, g = best_worst(runs, bc.NOMINAL)
    rows.append(("minimax, scale free", g))
    others = [values_of(bc.fitter()([d.run for d in data if d.group == grp]).geometry)
              for grp in dict.fromkeys(d.group for d in data) if grp != FREE]
    means = [0.5 * (v[0] + v[1]) / bc.NOMINAL.wheel_radius for v in others]
    scales = {"0.96 x nominal": 0.96, "0.98 x nominal": 0.98, "nominal": 1.0,
              "smallest of the other fits": min(means),
              "largest of the other fits": max(means),
              "the default fit here": float(np.mean(values_of(rows[1][1])[:2])) / 0.042}
    for label, s in scales.items():
        rows.append((f"minimax, scale of {label}", best_worst(runs, bc.NOMINAL, s)[1]))
    print(f"{'geometry':44s} {'r_L':>7s} {'r_R':>7s} {'b':>7s} [mm]  worst final  per run"
          "  ATE per run [m]")
    for label, geo in rows:
        v = 1e3 * values_of(geo)
        errs = end_errors(runs, geo)
        ate = [calibration.figures_of(r, geo).ate_rmse_aligned_m for r in runs]
        print(f"{label:44s} {v[0]:7.3f} {v[1]:7.3f} {v[2]:7.2f}       {errs.max():.4f}  "
              + " ".join(f"{e:.4f}" for e in errs) + "  " + " ".join(f"{a:.4f}" for a in ate))
    print(f"(the other experiments' fits: mean radius {min(means) * 42:.3f}-"
          f"{max(means) * 42:.3f} mm; minimax with the scale free: {free:.4f} m)")


def candidates_section(data: Sequence[bc.Data]) -> None:
    print("\n== 2. Other nuisances and weights, all runs: final position error (start "
          "aligned) mean [m]; ATE mean; experiments held out worse than nominal; "
          f"{FREE}: in-sample worst, held out mean/worst ==")
    print(f"{'candidate':34s} {'in-sample':>9s} {'LORO':>7s} {'LOEO':>7s} {'ATE LORO':>8s} "
          f"{'ATE LOEO':>8s} {'worse':>5s}  {'free in':>7s} {'free LORO':>13s} "
          f"{'free LOEO':>13s}")
    for label, kw in CANDIDATES:
        cv = bc.cross_validate(data, as_fit(partial(candidate_fit, **kw)))
        s = [bc.summary(bc.pooled(cv, c)) for c in ("in-sample", "LORO", "LOEO")]
        f = cv[FREE]
        print(f"{label:34s} {s[0][0]:9.4f} {s[1][0]:7.4f} {s[2][0]:7.4f} {s[1][2]:8.4f} "
              f"{s[2][2]:8.4f} {bc.worse(cv):5d}  {max(_fpe(f['in-sample'])):7.4f} "
              f"{_cell(_fpe(f['LORO'])):>13s} {_cell(_fpe(f['LOEO'])):>13s}", flush=True)


def main(argv: Sequence[str]) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true",
                    help="free paths only, the default and end weight 0.5; no section 2")
    args = ap.parse_args(list(argv))
    if not (bc.TRAIN / "to_rosbag2.py").exists():
        print(f"skipped: {bc.TRAIN} not found (the project's shared data; a clone has none)")
        return 0
    everything = [d for d in bc.load_all(quick=False) if d.exp != bc.TRAIN_ONLY]
    data, objectives = everything, OBJECTIVES
    if args.quick:
        data = [d for d in data if d.kind == "free"]
        objectives = (OBJECTIVES[0], OBJECTIVES[2])
    print("== 1. Objectives per experiment: final position error, start aligned [m]: "
          "in-sample worst; held out mean/worst (LORO, LOEO) with nominal's on the same runs ==")
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
    if not args.quick:
        candidates_section(data)
    minimax_section(everything)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
