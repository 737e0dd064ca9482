"""What ``diffdrive-odom calibrate`` prints: the held-out verdict, the fit, the params block.

Text only, from results the core computed (:mod:`diffdrive_odom.core.evaluation`); the
command line that reads the bags and runs the fits is :mod:`diffdrive_odom.tools.calibrate`.
scipy is imported where a line needs it, so ``--help`` works without the ``tools`` extra.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt

from diffdrive_odom.core.evaluation import judge, leftout
from diffdrive_odom.core.evaluation.recorded_run import Run, values_of
from diffdrive_odom.core.evaluation.umbmark import Umbmark
from diffdrive_odom.core.geometry.kinematics import Geometry
from diffdrive_odom.core.uncertainty.noise import (
    DEFAULT_RADIUS_STDDEV_RATIO,
    DEFAULT_ROTATION_K,
    DEFAULT_SEPARATION_STDDEV_RATIO,
    SESSION_DRIFT_RATIO,
)
from diffdrive_odom.settings.params import yaml_text

if TYPE_CHECKING:  # scipy (the ``tools`` extra) only where it is used
    from diffdrive_odom.core.evaluation import (
        assessment,
        calibration,
        consistency,
        crossval,
        objective,
    )
    from diffdrive_odom.core.evaluation.calibration import Fit


def left_out_lines(runs: Sequence[Run], nominal: Geometry) -> list[str]:
    """Per run, what the slip test left out of the fit; nothing when no run had an IMU.

    So the output of runs without a gyro (OptiOdom's) stays as it was.
    """
    found = [(r, leftout.left_out(r, nominal)) for r in runs]
    if all(lo is None for _, lo in found):
        return []
    lines = []
    for run, lo in found:
        if lo is None:
            lines.append(f"slip test: {run.name}: no IMU, every step fitted")
        elif run.reference is None:
            lines.append(f"slip test: {run.name}: {lo.events} slip event(s) found, NOT left out "
                         "(typed end positions: no reference to bridge them with)")
        else:
            lines.append(
                f"slip test: {run.name}: {lo.events} slip event(s), {lo.steps} of "
                f"{len(run.steps)} steps left out of the fit ({lo.travel_m:.3f} m of travel "
                f"and {math.degrees(lo.turn_rad):.1f} deg of turn the wheels claimed over "
                f"them; the reference turned {math.degrees(lo.reference_turn_rad):.1f} deg), "
                "bridged by the reference's motion")
    return lines


def rotation_line(fit: consistency.NoiseFit, runs: int, reference: tuple[float, float]) -> str:
    """What the rotation-noise fit found and how much the runs want it (two lines).

    ``reference``: the reference's own error assumed, (m, rad) 1 sigma.
    """
    from diffdrive_odom.core.evaluation import consistency

    n = fit.noise
    wanted = ("the runs want it" if fit.lr_rotation > consistency.LR_5_PERCENT
              else "not distinguishable from 0")
    value = (f"{_num(n.k_rotation)} rad" if n.k_rotation > 0.0
             else "0 (the runs' final poses want none)")
    return (f"rotation_noise_k: {value}; likelihood ratio against 0: {fit.lr_rotation:.2f}, "
            f"{wanted} at 5 % (above {consistency.LR_5_PERCENT})\n"
            f"  maximum likelihood of the {runs} runs' final poses, each with the geometry "
            f"fitted on the others; held: wheel_noise_k {n.k:g} m, the printed ratios, the "
            f"reference's own error {1000 * reference[0]:g} mm, "
            f"{math.degrees(reference[1]):g} deg (--reference-error)")


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
    figures = (f"mean {judge.NAME} {c.nominal:.4f} m nominal, {c.held_out:.4f} m calibrated "
               f"(leave-one-run-out over {c.runs} runs"
               + (f", {len(v.left_out)} left out" if v.left_out else "") + ")")
    if v.within_margin:
        head = (f"CANNOT TELL on held-out runs: {figures}; the change is within its noise, "
                f"{v.margin:.4f} m (the RMS in-sample error over the square root of "
                "the folds); the block is printed, judge it yourself")
    elif v.better:
        head = ("held-out check: calibrated geometry better than nominal on runs it did not "
                f"see: {figures}")
    else:
        head = ("NOT BETTER THAN NOMINAL on held-out runs"
                + (" (--force: block printed anyway)" if forced else "") + f": {figures}")
    return "\n".join([head, *left])


def objective_lines(c: objective.Choice) -> str:
    """Which objective was fitted and why; when chosen, the table it was chosen from."""
    name = c.objective.name
    if c.forced:
        return f"objective: {name} (as asked; --objective auto chooses it held out)"
    if not c.scores:
        return f"objective: {name} (the default, not chosen: {c.why})"
    counted = len(c.scores[0].judged)
    lines = [f"objective: {name}, chosen by leave-one-run-out on the {c.runs} runs: each "
             f"refitted without one run, that run's {judge.NAME} over the {counted} folds "
             "that can judge a fit; the lowest worst taken",
             f"  {'objective':40s} {'worst [m]':>9s} {'mean [m]':>9s}  to force it"]
    for s in c.scores:
        o = s.objective
        flag = ("--objective end-poses" if o.ends_only else
                f"--end-weight {o.end_weight:g}" if o.end_weight else "--objective trajectory")
        mark = "*" if o == c.objective else " "
        lines.append(f"{mark} {o.name:40s} {s.worst:9.4f} {s.mean:9.4f}  {flag}")
    return "\n".join(lines)


def _num(value: float) -> str:
    return yaml_text(float(f"{value:.7g}"))


def params_block(geometry: Geometry, ratios: tuple[float, float] | None, how: str,
                 rotation: float | None = None) -> str:
    """The ``/**: ros__parameters:`` block for the node (nominal values kept, multipliers set).

    The separation is given as ``wheel_separation_multiplier`` with the nominal
    ``wheel_separation``, as the radii are: diff_drive_controller's split. ``ratios``:
    the bootstrap's ``wheel_radius_stddev_ratio`` / ``wheel_separation_stddev_ratio``
    (None: too few runs for one; the node's defaults describe an uncalibrated robot);
    ``rotation``: the fitted ``rotation_noise_k`` (None: not fitted).
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
    if rotation is not None:
        lines.append(f"    rotation_noise_k: {_num(rotation)}  # maximum likelihood, held out "
                     f"(default {DEFAULT_ROTATION_K:g})")
    return "\n".join(lines) + "\n"


def fit_report(fit: Fit, covariance: npt.NDArray[np.float64] | None,
               drift: float = SESSION_DRIFT_RATIO) -> str:
    """Human lines: values with their sigma, what is fixed, per-run errors.

    ``covariance`` is the bootstrap's; the 1-sigma column adds ``drift`` of each value
    (:func:`crossval.with_drift`), what the value may move by in another session.
    """
    from diffdrive_odom.core.evaluation import calibration, crossval

    nominal = values_of(fit.nominal)
    from diffdrive_odom.core.evaluation import objective

    how = objective.Objective(fit.end_weight, fit.ends_only).name
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
        + (" (the whole trajectory's refits: end poses alone leave a resample turning one "
           "way a combination of the values free)" if fit.ends_only else "")
        if std is not None else
        f"1-sigma: not given: it needs {crossval.MIN_RUNS_FOR_SIGMA} or more runs; the "
        "node's default stddev ratios stay")
    for what, value, why in calibration.FIXED:
        lines.append(f"fixed, not fitted: {what} = {value} ({why})")
    lines.append(f"RMS residual {fit.rms_before * 1e3:.2f} -> {fit.rms_after * 1e3:.2f} mm")
    lines.append(f"in-sample (the runs it was fitted to) {judge.NAME} ({judge.DEFINITION}), "
                 "nominal -> calibrated:")
    for r in fit.runs:
        lines.append(f"  {r.name}: {r.before.error:.4f} -> {r.after.error:.4f} m "
                     f"(path {r.before.path:.4f} -> {r.after.path:.4f}, end {r.before.end:.4f} "
                     f"-> {r.after.end:.4f})" + _every_step(r))
    return "\n".join(lines)


def _every_step(r: calibration.RunFigures) -> str:
    """What wheels-only replay will show of a run whose slips the fit left out ('' if none)."""
    if r.before_all is None or r.after_all is None:
        return ""
    return (f"\n    these figures leave out its {r.after.left_out} slip steps (bridged by the "
            "reference); wheels-only replay integrates them: replay --eval's final position "
            f"error, start aligned, {r.before_all.final_position_error_aligned_m:.4f} -> "
            f"{r.after_all.final_position_error_aligned_m:.4f} m (nominal -> calibrated, "
            "--reference-offset the mount below; use_imu takes the slips' heading from the "
            "gyro)")


def mount_lines(found: assessment.MountFound) -> str:
    """Where the reference sits on the robot, how it is known, and what is not."""
    m = found.mount
    if found.given:
        return f"reference mount (--reference-offset, held): {m.text()}"
    what = ("its yaw (the direction of travel against its heading) and its lever arm"
            if not found.lever_held else "its yaw (the direction of travel against its "
            "heading); its lever arm HELD AT 0, not determined by these runs: "
            f"{found.lever_held}; give --reference-offset X,Y,YAW if it is off the axle")
    return (f"reference mount (its frame in base_link), fitted: {m.text(found.sigma)} "
            f"(1-sigma: {found.source})\n  fitted: {what}")


def coverage_line(a: assessment.Assessment) -> str:
    """What all the runs do not determine ('' when they determine the geometry)."""
    reason = a.coverage.reason
    if not reason:
        return ""
    w = a.weakest
    return (f"NOT DETERMINED by these runs: {reason}; the combination they see least, "
            f"{w[0]:+.2f} left radius {w[1]:+.2f} right radius {w[2]:+.2f} separation "
            "(relative changes), is not determined: the values printed hold along it only "
            "as far as these runs go (runs that turn the other way determine it)")


def implausible_lines(found: Sequence[assessment.Implausible], mount: assessment.MountFound,
                      forced: bool) -> list[str]:
    """A value moved too far to be the wheels: named, with its likely causes."""
    from diffdrive_odom.core.evaluation import assessment as a

    if not found:
        return []
    lines = [f"IMPLAUSIBLE: the fit moved a value more than {100 * a.IMPLAUSIBLE_RATIO:g} % "
             f"from nominal and more than {a.IMPLAUSIBLE_SIGMAS:g} sigma"
             + (" (--force: block printed anyway)" if forced else "") + ":"]
    for v in found:
        sigma = (f"{abs(v.fitted - v.nominal) / v.sigma:.0f} sigma" if v.sigma
                 else "no sigma: fewer than 3 runs")
        lines.append(f"  {v.name}: {v.nominal:.6f} -> {v.fitted:.6f} m (x{v.ratio:.4f}, {sigma})")
    causes = ["a wrong nominal wheel_radius or ticks_per_revolution (or encoder units) in the "
              "params: every value moves by the same factor",
              "a wrong nominal wheel_separation"]
    if mount.lever_held:
        causes.append("the reference's lever arm, held at 0 but not determined by these runs: "
                      "give --reference-offset X,Y,YAW")
    elif not mount.given:
        causes.append(f"the reference's mount fitted where it is not ({mount.mount.text()}): "
                      "give --reference-offset X,Y,YAW")
    causes.append("a reference stamped late or on another clock, or runs that slip")
    lines.append("  likely causes: " + "; ".join(causes))
    return lines


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


