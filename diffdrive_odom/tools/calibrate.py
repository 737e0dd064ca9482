"""``diffdrive-odom calibrate``: wheel radii, separation and their uncertainty from runs.

The CLI only reads bags and prints; the fit is :mod:`diffdrive_odom.core.evaluation.calibration`,
the held-out check and the bootstrap :mod:`diffdrive_odom.core.evaluation.crossval`. It judges its
own result first: each run integrated with a geometry fitted on the others, against
the nominal geometry, over the folds whose training runs determine the geometry (the
others are named and left out); when the nominal one does better it says so on the
first line, exits 1 and prints no block (``--force`` prints it anyway); when no fold
remains it says it cannot tell and prints the block with that warning.
Readings are decoded with the odometry node's own parameters and pipeline
(:func:`diffdrive_odom.core.bulk.batch.wheel_steps`), ground truth with ``eval``'s readers, so
a bag that replays or evaluates also calibrates. The result is printed as a
``/**: ros__parameters:`` block with the node's own parameter names, to paste into
its params file (``--yaml FILE`` also writes it). The fit (scipy) and the bag reader
(rosbags) are imported past the parsing, so ``--help`` works without the ``tools`` extra.
"""

from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt

from diffdrive_odom.core.bulk import batch
from diffdrive_odom.core.estimation.config import OdometrySettings
from diffdrive_odom.core.evaluation import metrics
from diffdrive_odom.core.evaluation.recorded_run import CalibrationError, Run, trajectory, values_of
from diffdrive_odom.core.evaluation.umbmark import Umbmark, reference_end, umbmark
from diffdrive_odom.core.geometry.kinematics import Geometry
from diffdrive_odom.core.uncertainty.propagation import (
    DEFAULT_RADIUS_STDDEV_RATIO,
    DEFAULT_SEPARATION_STDDEV_RATIO,
    SESSION_DRIFT_RATIO,
)
from diffdrive_odom.settings.params import yaml_text
from diffdrive_odom.tools import evaluate, fleet
from diffdrive_odom.tools.args import (
    add_param_arguments,
    add_reference_arguments,
    fail,
    outputs_problem,
    settings_from_args,
)
from diffdrive_odom.tools.cli import HelpFormatter

if TYPE_CHECKING:  # scipy and rosbags (the ``tools`` extra) only where they are used
    from diffdrive_odom.core.evaluation import crossval
    from diffdrive_odom.core.evaluation.calibration import Fit

PREFIX = "[calibrate]"


def _parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(
        prog="diffdrive-odom calibrate",
        description="Fit wheel radii and separation to ground truth recorded with the wheel "
        "readings, check the fit on held-out runs, bootstrap its uncertainty; or run "
        "Borenstein and Feng's UMBmark (--umbmark CW_BAG CCW_BAG --side L); prints a params "
        "block to paste.",
        formatter_class=HelpFormatter,
    )
    ap.add_argument("bags", nargs="*", metavar="BAG",
                    help="runs with /joint_states and a ground-truth pose topic")
    ap.add_argument("--umbmark", nargs=2, metavar=("CW_BAG", "CCW_BAG"), default=None,
                    help="UMBmark from a clockwise and a counter-clockwise square "
                    "(default: least squares on the BAGs)")
    ap.add_argument("--side", type=float, default=None, metavar="M",
                    help="with --umbmark: the squares' side [m] (no default: required there)")
    ap.add_argument("--cw-end", default=None, metavar="X,Y",
                    help="with --umbmark: measured end position of the CW square [m], start "
                    "frame (x forward, y left); --cw-end=-0.1,0.2 when X is negative "
                    "(default: from the ground-truth topic)")
    ap.add_argument("--ccw-end", default=None, metavar="X,Y",
                    help="with --umbmark: the same for the CCW square (default: from the "
                    "ground-truth topic)")
    fleet.add_fleet_arguments(ap)
    add_param_arguments(ap, required=False, file_help="the node's ROS 2 params YAML: nominal "
                        "geometry, joint names, encoders (repeatable, later files win; default: "
                        "none, but this or -p must give wheel_radius and wheel_separation)")
    ap.add_argument("--topic", default="/joint_states", help="JointState topic in the bags")
    add_reference_arguments(ap)
    ap.add_argument("--force", action="store_true",
                    help="print the params block even when the calibrated geometry does not "
                    "beat the nominal one on held-out runs (default: refused, exit 1)")
    ap.add_argument("--session-drift", type=float, default=SESSION_DRIFT_RATIO, metavar="RATIO",
                    help="relative 1-sigma drift of the radii and separation between recording "
                    "sessions (tyres, floor), added in quadrature to the bootstrap sigma: what "
                    "the printed sigma covers on other days (chosen on the OptiOdom robot, "
                    "doc/concepts/calibration.md; 0: the bootstrap alone)")
    ap.add_argument("--end-weight", type=float, default=0.0, metavar="W",
                    help="also fit each run's final position, its square weighted W^2 times "
                    "the run's mean squared error along the path (0: the whole trajectory "
                    "alone; what each gives: doc/concepts/calibration.md)")
    ap.add_argument("--window", default=None, help=argparse.SUPPRESS)  # refused: see below
    ap.add_argument("--no-mount", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--yaml", metavar="FILE",
                    help="also write the params block to FILE (default: printed only)")
    ap.add_argument("--plot", metavar="FILE",
                    help="write a PNG of the paths before and after (default: none)")
    return ap


def _error(text: str) -> int:
    return fail(PREFIX, text)


def _end_point(text: str, flag: str) -> tuple[float, float]:
    parts = text.split(",")
    try:
        x, y = (float(p) for p in parts)
    except ValueError:
        raise CalibrationError(f"{flag}: give X,Y in metres, got {text!r}") from None
    if not (math.isfinite(x) and math.isfinite(y)):
        raise CalibrationError(f"{flag}: X,Y must be finite, got {text!r}")
    return x, y


def _usage_problem(args: argparse.Namespace) -> str | None:
    """What is wrong with the command line as a whole, before any bag is opened."""
    if not args.ros_params:
        return ("give the nominal geometry: --params-file FILE (the node's params) or "
                "-p wheel_radius:=R -p wheel_separation:=B")
    if args.umbmark is None:
        if not args.bags:
            return "give one or more BAGs, or --umbmark CW_BAG CCW_BAG --side L"
        if args.side is not None or args.cw_end or args.ccw_end:
            return "--side/--cw-end/--ccw-end need --umbmark"
        if not (math.isfinite(args.session_drift) and 0.0 <= args.session_drift < 1.0):
            return f"--session-drift: give a ratio in [0, 1), got {args.session_drift!r}"
        if not (math.isfinite(args.end_weight) and args.end_weight >= 0.0):
            return f"--end-weight: give a finite W >= 0, got {args.end_weight!r}"
        if args.window is not None or args.no_mount:
            return ("--window/--no-mount are gone: the fit uses the whole trajectory with the "
                    "reference's start yaw as its only nuisance (offset from the axle and "
                    "clock lag fixed at 0); see doc/concepts/calibration.md")
    else:
        if args.bags:
            return "--umbmark takes its two bags itself; no other BAG"
        if args.side is None:
            return "--umbmark needs --side L (the squares' side in metres)"
        if bool(args.cw_end) != bool(args.ccw_end):
            return "give both --cw-end and --ccw-end, or neither (ground truth from the bags)"
    return outputs_problem(("--yaml", args.yaml), ("--plot", args.plot))


def _run(bag: str, settings: OdometrySettings, args: argparse.Namespace,
         reference: bool) -> Run:
    """Decode one bag into its wheel steps (and read its ground truth when asked)."""
    from diffdrive_odom.tools import bagblocks

    ref = None
    if reference:
        topic = evaluate.reference_topic(bag, args.ground_truth, (args.topic,),
                                         lambda t: print(f"{PREFIX} {t}", file=sys.stderr))
        ref = evaluate.read_trajectory(bag, topic, args.child_frame)
    jump = int(settings.estimator.time_jump_threshold * 1e9)
    steps = batch.wheel_steps(bagblocks.read_joint_blocks(bag, args.topic, jump), settings)
    return Run(Path(bag).name, steps, ref)


def _decode_all(args: argparse.Namespace, settings: OdometrySettings) -> list[Run] | str:
    """Every bag decoded, on ``--jobs`` processes or a ``--dask`` cluster, in the order given.

    The fit is joint, so it is not made on what is left: every bag that failed is named
    (the one line returned), not only the first.
    """
    if args.jobs is not None and args.jobs < 1:
        return f"--jobs must be >= 1, got {args.jobs}"
    calls = [(bag, settings, args, True) for bag in args.bags]
    try:
        done = fleet.map_calls(_run, calls, args.jobs, args.dask)
    except fleet.FleetError as err:
        return str(err)
    bad = [(bag, r) for bag, r in zip(args.bags, done, strict=True) if isinstance(r, Exception)]
    if len(bad) == 1:
        return str(bad[0][1])  # the error names its bag
    if bad:
        return (f"{len(bad)} of {len(done)} bags failed, so no fit: "
                + "; ".join(f"{bag}: {err}" for bag, err in bad))
    return done


def main(argv: Sequence[str]) -> int:
    """``diffdrive-odom calibrate``; exit 2 with one line for a bad bag, topic or option."""
    args = _parser().parse_args(list(argv))
    problem = _usage_problem(args)
    if problem:
        return _error(problem)
    settings = settings_from_args(args)
    if isinstance(settings, str):
        return _error(settings)
    from diffdrive_odom.tools import bagio

    try:
        if args.umbmark is not None:
            return _umbmark(args, settings)
        runs = _decode_all(args, settings)
        if isinstance(runs, str):
            return _error(runs)
        return _least_squares(args, settings, runs)
    except (bagio.BagError, CalibrationError) as err:
        return _error(str(err))
    except OSError as err:
        return _error(f"cannot write: {err}")
    return 0


def _least_squares(args: argparse.Namespace, settings: OdometrySettings,
                   runs: Sequence[Run]) -> int:
    """Fit, check it on held-out runs, bootstrap its sigma; print (or refuse) the block."""
    from diffdrive_odom.core.evaluation import calibration, crossval

    nominal = settings.geometry
    w = args.end_weight
    result = calibration.fit(runs, nominal, end_weight=w)
    in_sample = [r.after.final_position_error_aligned_m for r in result.runs]
    held = crossval.held_out(runs, nominal, fitter=crossval.default_fitter(nominal, w))
    verdict = crossval.judge(runs, held, nominal, in_sample) if len(runs) >= 2 else None
    covariance = crossval.bootstrap(runs, nominal, end_weight=w)
    printed = None if covariance is None else crossval.with_drift(result.values, covariance,
                                                                  args.session_drift)
    ratios = None if printed is None else crossval.stddev_ratios(result.values, printed)
    refused = verdict is not None and not verdict.cannot_tell and not verdict.better
    print(check_lines(verdict, len(runs), refused and args.force))
    how = f"least squares on {len(runs)} run(s)"
    if verdict is not None and verdict.cannot_tell:
        how += "; held-out check CANNOT TELL, see its first line"
    text = params_block(result.geometry, ratios, how)
    if args.plot:
        plot(result, runs, args.plot)
    print(fit_report(result, covariance, args.session_drift))
    if refused and not args.force:
        print(f"{PREFIX} no params block: the nominal geometry did better on held-out runs "
              "(--force prints it anyway)")
        return 1
    if args.yaml:
        Path(args.yaml).write_text(text, encoding="utf-8")
    print(text, end="")
    return 0


def check_lines(v: crossval.Verdict | None, runs: int, forced: bool) -> str:
    """The verdict of the held-out check (calibrate's first line), then each fold left out.

    First line: ``held-out check: ...`` (better, or cannot be made), ``NOT BETTER THAN
    NOMINAL ...`` or ``CANNOT TELL ...``; then one ``held-out fold left out: RUN: WHY``
    line per fold that cannot judge the fit.
    """
    if v is None:
        return (f"held-out check: cannot be made with {runs} run (give 2 or more runs: each "
                "is then judged with a geometry fitted on the others)")
    left = [f"held-out fold left out: {run}: {why}" for run, why in v.left_out]
    c = v.check
    if c is None:
        return "\n".join([
            f"CANNOT TELL on held-out runs: none of the {len(v.left_out)} folds can judge the "
            "fit (paths that turn both ways as they go, circles or squares each way, judge "
            "it; straight lines and spins on the spot cannot); the block is printed, judge it "
            "yourself", *left])
    figures = (f"mean final position error {c.fpe_nominal:.4f} m nominal, {c.fpe_held_out:.4f} "
               f"m calibrated; ATE {c.ate_nominal:.4f} -> {c.ate_held_out:.4f} m "
               f"(leave-one-run-out over {c.runs} runs"
               + (f", {len(v.left_out)} left out" if v.left_out else "") + ")")
    if v.within_margin:
        head = (f"CANNOT TELL on held-out runs: {figures}; the change is within its noise, "
                f"{v.margin:.4f} m (the RMS in-sample final error over the square root of "
                "the folds); the block is printed, judge it yourself")
    elif v.better:
        head = ("held-out check: calibrated geometry better than nominal on runs it did not "
                f"see: {figures}")
    else:
        head = ("NOT BETTER THAN NOMINAL on held-out runs"
                + (" (--force: block printed anyway)" if forced else "") + f": {figures}")
    return "\n".join([head, *left])


def _umbmark(args: argparse.Namespace, settings: OdometrySettings) -> int:
    typed = args.cw_end is not None
    cw = _run(args.umbmark[0], settings, args, not typed)
    ccw = _run(args.umbmark[1], settings, args, not typed)
    if typed:
        cw_end = _end_point(args.cw_end, "--cw-end")
        ccw_end = _end_point(args.ccw_end, "--ccw-end")
    else:
        assert cw.reference is not None and ccw.reference is not None
        cw_end = reference_end(cw, cw.reference)
        ccw_end = reference_end(ccw, ccw.reference)
    result = umbmark(cw, ccw, cw_end, ccw_end, side=args.side, nominal=settings.geometry)
    text = params_block(result.geometry, None, f"UMBmark, side {args.side:g} m")
    if args.yaml:
        Path(args.yaml).write_text(text, encoding="utf-8")
    print(umbmark_report(result))
    print(text, end="")
    return 0


def _num(value: float) -> str:
    return yaml_text(float(f"{value:.7g}"))


def params_block(geometry: Geometry, ratios: tuple[float, float] | None, how: str) -> str:
    """The ``/**: ros__parameters:`` block for the node (nominal values kept, multipliers set).

    The separation is given as ``wheel_separation_multiplier`` with the nominal
    ``wheel_separation``, as the radii are: diff_drive_controller's split. ``ratios``:
    the bootstrap's ``wheel_radius_stddev_ratio`` / ``wheel_separation_stddev_ratio``
    (None: too few runs for one; the node's defaults describe an uncalibrated robot).
    """
    lines = [
        f"# diffdrive-odom calibrate: {how}",
        "/**:",
        "  ros__parameters:",
        f"    wheel_radius: {_num(geometry.wheel_radius)}",
        f"    left_wheel_radius_multiplier: {_num(geometry.left_wheel_radius_multiplier)}",
        f"    right_wheel_radius_multiplier: {_num(geometry.right_wheel_radius_multiplier)}",
        f"    wheel_separation: {_num(geometry.wheel_separation)}",
        f"    wheel_separation_multiplier: {_num(geometry.wheel_separation_multiplier)}",
    ]
    if ratios is not None:
        lines += [f"    wheel_radius_stddev_ratio: {_num(ratios[0])}  # printed 1-sigma "
                  f"(bootstrap + session drift), relative (default "
                  f"{DEFAULT_RADIUS_STDDEV_RATIO:g})",
                  f"    wheel_separation_stddev_ratio: {_num(ratios[1])}  # (default "
                  f"{DEFAULT_SEPARATION_STDDEV_RATIO:g})"]
    return "\n".join(lines) + "\n"


def fit_report(fit: Fit, covariance: npt.NDArray[np.float64] | None,
               drift: float = SESSION_DRIFT_RATIO) -> str:
    """Human lines: values with their sigma, what is fixed, per-run errors.

    ``covariance`` is the bootstrap's; the 1-sigma column adds ``drift`` of each value
    (:func:`crossval.with_drift`), what the value may move by in another session.
    """
    from diffdrive_odom.core.evaluation import calibration, crossval

    nominal = values_of(fit.nominal)
    how = "whole trajectory" + (f" + end positions x{fit.end_weight:g}" if fit.end_weight
                                 else "")
    lines = [f"calibrated from {len(fit.runs)} run(s): {how}, {fit.samples} "
             f"samples, {fit.loss} loss, {fit.evaluations} evaluations, {fit.seconds:.2f} s",
             f"{'':22s} {'nominal':>10s} {'fitted':>10s} {'bootstrap':>10s} {'1-sigma':>10s}"]
    boot = None if covariance is None else np.sqrt(np.diag(covariance))
    std = None if covariance is None else np.sqrt(np.diag(
        crossval.with_drift(fit.values, covariance, drift)))
    for i, (name, n, v) in enumerate(zip(("left wheel radius [m]", "right wheel radius [m]",
                                          "wheel separation [m]"), nominal, fit.values,
                                         strict=True)):
        b, sigma = ("-", "-") if boot is None or std is None else (f"{boot[i]:.6f}",
                                                                    f"{std[i]:.6f}")
        lines.append(f"{name:22s} {n:10.6f} {v:10.6f} {b:>10s} {sigma:>10s}")
    lines.append(
        f"1-sigma: covers the geometry on other days: bootstrap over runs "
        f"({crossval.BOOTSTRAP_RUNS} resamples) and a drift between sessions of "
        f"{100 * drift:.2f} % of each value (--session-drift), in quadrature"
        if std is not None else
        f"1-sigma: not given: it needs {crossval.MIN_RUNS_FOR_SIGMA} or more runs; the "
        "node's default stddev ratios stay")
    lines.append(f"fitted nuisance: the reference's yaw about the start "
                 f"{math.degrees(fit.start_yaw):+.3f} deg")
    for what, value, why in calibration.FIXED:
        lines.append(f"fixed, not fitted: {what} = {value} ({why})")
    lines.append(f"RMS residual {fit.rms_before * 1e3:.2f} -> {fit.rms_after * 1e3:.2f} mm")
    lines.append("in-sample (the runs it was fitted to) final position error, start aligned, "
                 "nominal -> calibrated; ATE RMSE:")
    for r in fit.runs:
        lines.append(f"  {r.name}: {r.before.final_position_error_aligned_m:.4f} -> "
                     f"{r.after.final_position_error_aligned_m:.4f} m; "
                     f"{r.before.ate_rmse_aligned_m:.4f} -> {r.after.ate_rmse_aligned_m:.4f} m")
    return "\n".join(lines)


def umbmark_report(u: Umbmark) -> str:
    """Human lines: the paper's single pass, the converged values, the end errors."""
    f = u.first
    n, one, it = (values_of(g) for g in (u.nominal, u.one_pass, u.geometry))
    lines = [
        f"UMBmark (Borenstein and Feng), side {u.side:g} m: end errors (measured - odometry) "
        f"CW ({f.cw_error[0]:+.4f}, {f.cw_error[1]:+.4f}) m, CCW ({f.ccw_error[0]:+.4f}, "
        f"{f.ccw_error[1]:+.4f}) m",
        f"  alpha {math.degrees(f.alpha):+.4f} deg (from y {math.degrees(f.alpha_y):+.4f}), "
        f"beta {math.degrees(f.beta):+.4f} deg (from y {math.degrees(f.beta_y):+.4f}); "
        f"E_d {f.e_d:.6f}, E_b {f.e_b:.6f}",
        f"{'':22s} {'nominal':>10s} {'one pass':>10s} {'converged':>10s}",
    ]
    for name, a, b, c in zip(("left wheel radius [m]", "right wheel radius [m]",
                              "wheel separation [m]"), n, one, it, strict=True):
        lines.append(f"{name:22s} {a:10.6f} {b:10.6f} {c:10.6f}")
    lines.append(f"converged in {u.passes} passes; end position error CW, CCW: "
                 f"{u.before[0]:.4f}, {u.before[1]:.4f} -> {u.after[0]:.4f}, "
                 f"{u.after[1]:.4f} m (E_max,syst {u.e_max_before:.4f} -> "
                 f"{u.e_max_after:.4f} m)")
    return "\n".join(lines)


def plot(fit: Fit, runs: Sequence[Run], path: str | Path) -> None:
    """PNG: per run, the reference and the odometry before and after calibration."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(runs), figsize=(5.5 * len(runs), 5.5), squeeze=False)
    for ax, run, figures in zip(axes[0], runs, fit.runs, strict=True):
        assert run.reference is not None
        ax.plot(run.reference.x, run.reference.y, "k-", lw=1.5, label="ground truth")
        for geometry, style, label, m in (
                (fit.nominal, "--", "nominal", figures.before),
                (fit.geometry, "-", "calibrated", figures.after)):
            est = trajectory(run, geometry)
            matched = metrics.match(est, run.reference)
            aligned = metrics.align_start(matched.est, matched.ref)
            ax.plot(aligned[:, 0], aligned[:, 1], style, lw=1.0,
                    label=f"{label}: end error {m.final_position_error_aligned_m:.3f} m")
        ax.set_aspect("equal", adjustable="datalim")
        ax.set_xlabel("x [m]")
        ax.set_ylabel("y [m]")
        ax.grid(True, alpha=0.3)
        ax.legend(loc="best", fontsize=8)
        ax.set_title(run.name, fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


__all__ = ["fit_report", "main", "params_block", "plot", "umbmark_report"]

if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
