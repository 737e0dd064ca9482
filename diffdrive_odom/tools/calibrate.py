"""``diffdrive-odom calibrate``: wheel radii, separation and their uncertainty from runs.

The CLI only reads bags and prints; the fit is :mod:`diffdrive_odom.core.evaluation.calibration`,
the held-out check and the bootstrap :mod:`diffdrive_odom.core.evaluation.crossval`. It judges its
own result first: each run integrated with a geometry fitted on the others, against
the nominal geometry, over the folds whose training runs determine the geometry (the
others are named and left out); when the nominal one does better it says so on the
first line, exits 1 and prints no block (``--force`` prints it anyway); when no fold
remains it says it cannot tell and prints the block with that warning. With 3 runs or
more it also fits ``rotation_noise_k`` (the turn's own noise) by maximum likelihood of the
held-out final poses (:mod:`diffdrive_odom.core.evaluation.consistency`) and prints it,
saying when the runs want none. The objective fitted (the whole trajectory, with end
positions weighted in, or the end poses only) is chosen by leave-one-run-out
(:mod:`diffdrive_odom.core.evaluation.objective`) unless ``--objective``/``--end-weight``
name one. The printed text: :mod:`~.calibrating.report`.
Bags become runs in :mod:`~.calibrating.runs` (the node's own pipeline; where a bag has
an IMU, the slips its gyro finds are left out of the fit, a line per run says how many),
on ``--jobs`` processes or a ``--dask`` cluster (:mod:`~.fleet`).
The result is printed as a
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

from diffdrive_odom.core.estimation.config import OdometrySettings
from diffdrive_odom.core.evaluation import metrics
from diffdrive_odom.core.evaluation.judge import base_reference, odometry
from diffdrive_odom.core.evaluation.recorded_run import CalibrationError, Run
from diffdrive_odom.core.evaluation.umbmark import reference_end, umbmark
from diffdrive_odom.core.geometry.kinematics import Geometry
from diffdrive_odom.core.geometry.mount import AXLE, Mount
from diffdrive_odom.core.uncertainty.noise import (
    DEFAULT_K,
    SESSION_DRIFT_RATIO,
)
from diffdrive_odom.tools import fleet
from diffdrive_odom.tools.calibrating.report import (
    check_lines,
    coverage_line,
    fit_report,
    implausible_lines,
    left_out_lines,
    mount_lines,
    objective_lines,
    params_block,
    rotation_line,
    umbmark_report,
)
from diffdrive_odom.tools.calibrating.runs import PREFIX, Settings, decode, gyro_settings
from diffdrive_odom.tools.cli import command_parser
from diffdrive_odom.tools.cmdline.args import (
    add_param_arguments,
    add_reference_arguments,
    fail,
    outputs_problem,
    settings_from_args,
)

if TYPE_CHECKING:  # scipy and rosbags (the ``tools`` extra) only where they are used
    from diffdrive_odom.core.evaluation import consistency
    from diffdrive_odom.core.evaluation.calibration import Fit


def _parser() -> argparse.ArgumentParser:
    ap = command_parser("calibrate", "Fit wheel radii and separation to ground truth "
                        "recorded with the wheel readings, check the fit on held-out runs, "
                        "bootstrap its uncertainty; or run Borenstein and Feng's UMBmark "
                        "(--umbmark CW_BAG CCW_BAG --side L); prints a params block to paste.")
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
    ap.add_argument("--imu-topic", default=None, metavar="TOPIC",
                    help="Imu topic whose gyro finds the slips to leave out of the fit, by the "
                    "node's rule (use_imu, slip_min_angle; the params' gyro settings); 'none': "
                    "no slip test (default: the bag's only sensor_msgs/Imu topic, if any)")
    add_reference_arguments(ap, "fitted beside the geometry: its yaw from the direction of "
                            "travel, its lever arm where the runs determine it (turns both "
                            "ways or spins), else 0, said so; printed with its sigma")
    ap.add_argument("--force", action="store_true",
                    help="print the params block even when the calibrated geometry does not "
                    "beat the nominal one on held-out runs, or moved a value more than 10 %% "
                    "from nominal and 5 sigma (default: refused, exit 1)")
    ap.add_argument("--session-drift", type=float, default=SESSION_DRIFT_RATIO, metavar="RATIO",
                    help="relative 1-sigma drift of the radii and separation between recording "
                    "sessions (tyres, floor), added in quadrature to the bootstrap sigma: what "
                    "the printed sigma covers on other days (chosen on the OptiOdom robot, "
                    "doc/concepts/calibration.md; 0: the bootstrap alone)")
    ap.add_argument("--reference-error", default="1,0.5", metavar="MM,DEG",
                    help="1-sigma error of the reference itself, position [mm] and heading "
                    "[deg] (its own noise: where it is mounted is --reference-offset's), "
                    "added to the covariance when rotation_noise_k is fitted (0,0 for a "
                    "simulator's truth)")
    ap.add_argument("--objective", choices=("auto", "trajectory", "end-poses"), default=None,
                    help="what the fit minimises: auto chooses among the whole trajectory, it "
                    "with end weight 0.5 or 1, and the end poses only (OptiOdom's) by "
                    "leave-one-run-out and prints the table; trajectory: the whole "
                    "trajectory (with --end-weight W); end-poses: the end poses only "
                    "(default: auto; trajectory when --end-weight is given)")
    ap.add_argument("--end-weight", type=float, default=None, metavar="W",
                    help="fit the whole trajectory and each run's final position, its square "
                    "weighted W^2 times the run's mean squared error along the path (0: the "
                    "trajectory alone; what each gives: doc/concepts/calibration.md; "
                    "default: chosen, see --objective)")
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
        if _reference_error(args.reference_error) is None:
            return ("--reference-error: give MM,DEG, two finite numbers >= 0, got "
                    f"{args.reference_error!r}")
        w = args.end_weight
        if w is not None and not (math.isfinite(w) and w >= 0.0):
            return f"--end-weight: give a finite W >= 0, got {w!r}"
        if w is not None and args.objective not in (None, "trajectory"):
            return f"--end-weight weighs the trajectory objective, not --objective {args.objective}"
        if args.window is not None or args.no_mount:
            return ("--window/--no-mount are gone: the fit uses the whole trajectory with the "
                    "reference's mount as its nuisance (--reference-offset, or fitted; clock "
                    "lag fixed at 0); see doc/concepts/calibration.md")
    else:
        if args.bags:
            return "--umbmark takes its two bags itself; no other BAG"
        if args.side is None:
            return "--umbmark needs --side L (the squares' side in metres)"
        if bool(args.cw_end) != bool(args.ccw_end):
            return "give both --cw-end and --ccw-end, or neither (ground truth from the bags)"
    return outputs_problem(("--yaml", args.yaml), ("--plot", args.plot))


def _reference_error(text: str) -> tuple[float, float] | None:
    """``MM,DEG`` -> (metres, radians), or None if it is not two finite numbers >= 0."""
    try:
        mm, deg = (float(p) for p in text.split(","))
    except ValueError:
        return None
    if not (math.isfinite(mm) and math.isfinite(deg) and mm >= 0.0 and deg >= 0.0):
        return None
    return mm / 1000.0, math.radians(deg)


def main(argv: Sequence[str]) -> int:
    """``diffdrive-odom calibrate``; exit 2 with one line for a bad bag, topic or option."""
    args = _parser().parse_args(list(argv))
    problem = _usage_problem(args)
    if problem:
        return _error(problem)
    settings = settings_from_args(args, PREFIX)
    if isinstance(settings, str):
        return _error(settings)
    if settings.open_loop is not None:
        return _error("open_loop is true: calibrate fits the wheel geometry to encoder "
                      "readings (joint_states), which open loop does not read; set "
                      "open_loop:=false for the calibration")
    gyro = gyro_settings(args, settings)
    from diffdrive_odom.tools.bags import bagio

    try:
        if args.umbmark is not None:
            return _umbmark(args, (settings, gyro))
        runs = decode_all(args, settings, gyro)
        if isinstance(runs, str):
            return _error(runs)
        return _least_squares(args, settings, runs)
    except (bagio.BagError, CalibrationError) as err:
        return _error(str(err))
    except OSError as err:
        return _error(f"cannot write: {err}")
    return 0


def decode_all(args: argparse.Namespace, plain: OdometrySettings,
                gyro: OdometrySettings | str) -> list[Run] | str:
    """Every bag decoded, on ``--jobs`` processes or a ``--dask`` cluster, in the order given.

    The fit is joint, so it is not made on what is left: every bag that failed is named
    (the one line returned), not only the first.
    """
    if args.jobs is not None and args.jobs < 1:
        return f"--jobs must be >= 1, got {args.jobs}"
    calls = [(bag, (plain, gyro), args, True) for bag in args.bags]
    try:
        done = fleet.map_calls(decode, calls, args.jobs, args.dask)
    except fleet.FleetError as err:
        return str(err)
    bad = [(bag, _said(r)) for bag, r in zip(args.bags, done, strict=True)
           if isinstance(r, Exception)]
    if len(bad) == 1:
        return bad[0][1]  # the error names its bag
    if bad:
        return (f"{len(bad)} of {len(done)} bags failed, so no fit: "
                + "; ".join(f"{bag}: {err}" for bag, err in bad))
    return done


def _said(err: Exception) -> str:
    """A bag's failure in one line, never an empty one.

    A bag's or the calibration's own message; anything else (a bug, a worker that died)
    with its kind, as the fleet names it.
    """
    from diffdrive_odom.tools.bags import bagio

    if isinstance(err, (bagio.BagError, CalibrationError)):
        return str(err)
    return f"{type(err).__name__}: {err}"


def _least_squares(args: argparse.Namespace, settings: OdometrySettings,
                   runs: Sequence[Run]) -> int:
    """Fit, check it on held-out runs, bootstrap its sigma; print (or refuse) the block."""
    from diffdrive_odom.core.evaluation import assessment

    a = assessment.assess(runs, settings.geometry, given=args.reference_offset,
                          objective_name=args.objective, end_weight=args.end_weight,
                          drift=args.session_drift)
    result, verdict, ratios = a.fit, a.verdict, a.ratios
    print(check_lines(verdict, len(runs), a.refused and args.force))
    for line in left_out_lines(runs, settings.geometry):
        print(line)
    print(objective_lines(a.choice))
    how = f"least squares on {len(runs)} run(s), {a.choice.objective.name}"
    if verdict is not None and verdict.cannot_tell:
        how += "; held-out check CANNOT TELL, see its first line"
    rotation = None
    reference = _reference_error(args.reference_error) or (0.0, 0.0)  # checked at the start
    if ratios is not None:
        rotation = rotation_fit(runs, [None if h.geometry is None or h.mount is None
                                       else (h.geometry, h.mount) for h in a.spread_folds],
                                settings, ratios, reference, result.mount)
    text = params_block(result.geometry, ratios, how,
                        None if rotation is None else rotation.noise.k_rotation)
    if args.plot:
        plot(result, runs, args.plot)
    print(fit_report(result, a.geometry_covariance, args.session_drift))
    print(mount_lines(a.mount))
    if coverage_line(a):
        print(coverage_line(a))
    if rotation is not None:
        print(rotation_line(rotation, len(runs), reference))
    for line in implausible_lines(a.implausible, a.mount, args.force):
        print(line)
    if a.withheld and not args.force:
        why = ("the nominal geometry did better on held-out runs" if a.refused
               else "a value moved too far to be the wheels (above)")
        print(f"{PREFIX} no params block: {why} (--force prints it anyway)")
        return 1
    if args.yaml:
        Path(args.yaml).write_text(text, encoding="utf-8")
    print(text, end="")
    return 0


def rotation_fit(runs: Sequence[Run], fitted: Sequence[tuple[Geometry, Mount] | None],
                 settings: OdometrySettings, ratios: tuple[float, float],
                 reference: tuple[float, float], mount: Mount) -> consistency.NoiseFit:
    """``rotation_noise_k`` by maximum likelihood of the held-out final poses.

    Each run integrated with the geometry fitted on the others (the reference moved onto
    base_link by that fit's mount); the wheel noise k (the node's, from the params
    given), the printed ratios and the reference's own error (seen through ``mount``'s
    lever arm) held fixed.
    """
    from diffdrive_odom.core.evaluation import consistency

    noise = settings.noise
    k = DEFAULT_K if noise is None else 0.5 * (noise.k_left + noise.k_right)
    terms = consistency.held_out_terms(runs, fitted)
    return consistency.fit_noise(terms, consistency.Noise(k, 0.0, *ratios),
                                 reference=consistency.reference_error(*reference, mount))


def _umbmark(args: argparse.Namespace, settings: Settings) -> int:
    typed = args.cw_end is not None
    cw = decode(args.umbmark[0], settings, args, not typed)
    ccw = decode(args.umbmark[1], settings, args, not typed)
    for line in left_out_lines((cw, ccw), settings[0].geometry):
        print(line)
    nominal = settings[0].geometry
    mount = AXLE
    if typed:
        cw_end = _end_point(args.cw_end, "--cw-end")
        ccw_end = _end_point(args.ccw_end, "--ccw-end")
    else:
        from diffdrive_odom.core.evaluation import assessment

        assert cw.reference is not None and ccw.reference is not None
        found = assessment.reference_mount((cw, ccw), nominal, args.reference_offset)
        mount = found.mount
        print(mount_lines(found))
        cw_end = reference_end(cw, cw.reference, mount)
        ccw_end = reference_end(ccw, ccw.reference, mount)
    result = umbmark(cw, ccw, cw_end, ccw_end, side=args.side, nominal=nominal, mount=mount)
    text = params_block(result.geometry, None, f"UMBmark, side {args.side:g} m")
    if args.yaml:
        Path(args.yaml).write_text(text, encoding="utf-8")
    print(umbmark_report(result))
    print(text, end="")
    return 0


def plot(fit: Fit, runs: Sequence[Run], path: str | Path) -> None:
    """PNG: per run, the reference and the odometry before and after calibration."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(runs), figsize=(5.5 * len(runs), 5.5), squeeze=False)
    for ax, run, figures in zip(axes[0], runs, fit.runs, strict=True):
        assert run.reference is not None
        ref = base_reference(run.reference, fit.mount)  # base_link, as judged
        ax.plot(ref.x, ref.y, "k-", lw=1.5, label="ground truth (base_link)")
        for geometry, style, label, j in (
                (fit.nominal, "--", "nominal", figures.before),
                (fit.geometry, "-", "calibrated", figures.after)):
            est, _ = odometry(run, geometry, fit.mount)  # the slips left out, as fitted
            matched = metrics.match(est, ref)
            aligned = metrics.align_best_fit(matched.est, matched.ref)
            ax.plot(aligned[:, 0], aligned[:, 1], style, lw=1.0,
                    label=f"{label}: {j.error:.3f} m")
        ax.set_aspect("equal", adjustable="datalim")
        ax.set_xlabel("x [m]")
        ax.set_ylabel("y [m]")
        ax.grid(True, alpha=0.3)
        ax.legend(loc="best", fontsize=8)
        ax.set_title(run.name, fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


__all__ = ["check_lines", "fit_report", "main", "params_block", "plot", "rotation_fit",
           "rotation_line", "umbmark_report"]

if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
