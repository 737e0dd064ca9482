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
saying when the runs want none. The printed text: :mod:`~.calibration_report`.
Where a bag has an IMU (``--imu-topic``, default: its only ``sensor_msgs/Imu`` topic),
its readings go through the pipeline with the gyro (``use_imu``, the params' gyro
settings), and the steps of each slip event the node's own rule finds are left out of
the fit (:mod:`diffdrive_odom.core.evaluation.leftout`); a line per run says how many.
Readings are decoded with the odometry node's own parameters and pipeline
(:func:`diffdrive_odom.core.bulk.batch.wheel_steps`), ground truth with ``eval``'s readers, so
a bag that replays or evaluates also calibrates. The result is printed as a
``/**: ros__parameters:`` block with the node's own parameter names, to paste into
its params file (``--yaml FILE`` also writes it). The fit (scipy) and the bag reader
(rosbags) are imported past the parsing, so ``--help`` works without the ``tools`` extra.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

from diffdrive_odom.core.bulk import batch
from diffdrive_odom.core.estimation.config import OdometrySettings
from diffdrive_odom.core.estimation.stamps import StampSource
from diffdrive_odom.core.evaluation import leftout, metrics
from diffdrive_odom.core.evaluation.recorded_run import CalibrationError, Run, trajectory
from diffdrive_odom.core.evaluation.umbmark import reference_end, umbmark
from diffdrive_odom.core.geometry.kinematics import Geometry
from diffdrive_odom.core.uncertainty.noise import (
    DEFAULT_K,
    SESSION_DRIFT_RATIO,
)
from diffdrive_odom.tools import evaluate, fleet
from diffdrive_odom.tools.args import (
    add_param_arguments,
    add_reference_arguments,
    fail,
    outputs_problem,
    settings_from_args,
)
from diffdrive_odom.tools.calibration_report import (
    check_lines,
    fit_report,
    left_out_lines,
    params_block,
    rotation_line,
    umbmark_report,
)
from diffdrive_odom.tools.cli import HelpFormatter

if TYPE_CHECKING:  # scipy and rosbags (the ``tools`` extra) only where they are used
    from diffdrive_odom.core.evaluation import consistency
    from diffdrive_odom.core.evaluation.calibration import Fit

PREFIX = "[calibrate]"
# The node's settings as given, and with the gyro on (for the bags with an IMU).
# (str: why the gyro's settings cannot work, said only for a bag that has an IMU).
Settings = tuple[OdometrySettings, "OdometrySettings | str"]


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
    ap.add_argument("--imu-topic", default=None, metavar="TOPIC",
                    help="Imu topic whose gyro finds the slips to leave out of the fit, by the "
                    "node's rule (use_imu, slip_min_angle; the params' gyro settings); 'none': "
                    "no slip test (default: the bag's only sensor_msgs/Imu topic, if any)")
    add_reference_arguments(ap)
    ap.add_argument("--force", action="store_true",
                    help="print the params block even when the calibrated geometry does not "
                    "beat the nominal one on held-out runs (default: refused, exit 1)")
    ap.add_argument("--session-drift", type=float, default=SESSION_DRIFT_RATIO, metavar="RATIO",
                    help="relative 1-sigma drift of the radii and separation between recording "
                    "sessions (tyres, floor), added in quadrature to the bootstrap sigma: what "
                    "the printed sigma covers on other days (chosen on the OptiOdom robot, "
                    "doc/concepts/calibration.md; 0: the bootstrap alone)")
    ap.add_argument("--reference-error", default="1,0.5", metavar="MM,DEG",
                    help="1-sigma error of the reference itself, position [mm] and heading "
                    "[deg], added to the covariance when rotation_noise_k is fitted (a motion "
                    "capture's: tracked point off the axle, markers' yaw; 0,0 for a "
                    "simulator's truth)")
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
        if _reference_error(args.reference_error) is None:
            return ("--reference-error: give MM,DEG, two finite numbers >= 0, got "
                    f"{args.reference_error!r}")
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


def _reference_error(text: str) -> tuple[float, float] | None:
    """``MM,DEG`` -> (metres, radians), or None if it is not two finite numbers >= 0."""
    try:
        mm, deg = (float(p) for p in text.split(","))
    except ValueError:
        return None
    if not (math.isfinite(mm) and math.isfinite(deg) and mm >= 0.0 and deg >= 0.0):
        return None
    return mm / 1000.0, math.radians(deg)


def _run(bag: str, settings: Settings, args: argparse.Namespace, reference: bool) -> Run:
    """Decode one bag into its wheel steps (and read its ground truth when asked).

    With an IMU topic (:func:`imu_topic`) the readings go through the pipeline with the
    gyro, which judges each step for slip (``WheelSteps.slip_spans``).
    """
    from diffdrive_odom.tools import bagblocks, bagio, bagreadings

    def notify(text: str) -> None:
        print(f"{PREFIX} {text}", file=sys.stderr)

    ref = None
    if reference:
        topic = evaluate.reference_topic(bag, args.ground_truth, (args.topic,), notify)
        ref = evaluate.read_trajectory(bag, topic, args.child_frame)
    plain, gyro = settings
    imu = imu_topic(bag, args.imu_topic, notify)
    if imu is not None and isinstance(gyro, str):
        raise CalibrationError(f"{bag} has an IMU ({imu}) to find slips with, but the gyro's "
                               f"settings cannot work: {gyro} (or --imu-topic none)")
    # Without an IMU the wheels alone, even with use_imu in the params: the gyro path would
    # run its slip test on no samples (and say so) and lose the fast lane.
    used = (dataclasses.replace(plain, gyro=None, online=None) if imu is None
            else plain if isinstance(gyro, str) else gyro)
    jump = int(used.estimator.time_jump_threshold * 1e9)
    if imu is None:
        steps = batch.wheel_steps(bagblocks.read_joint_blocks(bag, args.topic, jump), used)
    else:
        assert used.gyro is not None
        by_log = used.gyro.stamp_source is StampSource.RECEIVE_TIME
        with bagio.open_bag(bag) as reader:
            steps = batch.wheel_steps(bagreadings.iter_sensor_readings(
                reader, args.topic, imu, jump_back_ns=jump, imu_by_log_time=by_log), used)
    return Run(Path(bag).name, steps, ref)


def imu_topic(bag: str, requested: str | None, notify: Callable[[str], None]) -> str | None:
    """The Imu topic whose gyro judges the slips: ``requested``, else the bag's only one.

    None: no slip test (``none`` asked for, or no Imu topic in the bag); BagError when
    the bag has several and none is named.
    """
    if requested is not None:
        return None if requested.lower() == "none" else requested
    from diffdrive_odom.tools import bagio

    with bagio.open_bag(bag) as reader:
        found = sorted({str(c.topic) for c in reader.connections if c.msgtype == bagio.IMU})
    if len(found) > 1:
        raise bagio.BagError(f"{bag}: several Imu topics ({', '.join(found)}): name the one "
                             "to find slips with, --imu-topic TOPIC (or none)")
    if found:
        notify(f"{Path(bag).name}: the gyro on {found[0]} finds the slips to leave out of the "
               "fit (--imu-topic none: keep every step)")
    return found[0] if found else None


def gyro_settings(args: argparse.Namespace, settings: OdometrySettings) -> OdometrySettings | str:
    """How a bag with an IMU is decoded: the node's settings with the gyro on.

    ``use_imu`` true, its gyro parameters from the params given, no online estimate.
    """
    if settings.gyro is None:
        extra = argparse.Namespace(**vars(args))
        extra.ros_params = [*args.ros_params, ("param", "use_imu:=true")]
        got = settings_from_args(extra)
        if isinstance(got, str):
            return got
        settings = got
    return dataclasses.replace(settings, online=None)


def _decode_all(args: argparse.Namespace, plain: OdometrySettings,
                gyro: OdometrySettings | str) -> list[Run] | str:
    """Every bag decoded, on ``--jobs`` processes or a ``--dask`` cluster, in the order given.

    The fit is joint, so it is not made on what is left: every bag that failed is named
    (the one line returned), not only the first.
    """
    if args.jobs is not None and args.jobs < 1:
        return f"--jobs must be >= 1, got {args.jobs}"
    calls = [(bag, (plain, gyro), args, True) for bag in args.bags]
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
    if settings.open_loop is not None:
        return _error("open_loop is true: calibrate fits the wheel geometry to encoder "
                      "readings (joint_states), which open loop does not read; set "
                      "open_loop:=false for the calibration")
    gyro = gyro_settings(args, settings)
    from diffdrive_odom.tools import bagio

    try:
        if args.umbmark is not None:
            return _umbmark(args, (settings, gyro))
        runs = _decode_all(args, settings, gyro)
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
    folds = crossval.held_out(runs, nominal, fitter=crossval.default_fitter(nominal, w))
    verdict = crossval.judge(runs, folds, nominal, in_sample) if len(runs) >= 2 else None
    covariance = crossval.bootstrap(runs, nominal, end_weight=w)
    printed = None if covariance is None else crossval.with_drift(result.values, covariance,
                                                                  args.session_drift)
    ratios = None if printed is None else crossval.stddev_ratios(result.values, printed)
    refused = verdict is not None and not verdict.cannot_tell and not verdict.better
    print(check_lines(verdict, len(runs), refused and args.force))
    for line in left_out_lines(runs, nominal):
        print(line)
    how = f"least squares on {len(runs)} run(s)"
    if verdict is not None and verdict.cannot_tell:
        how += "; held-out check CANNOT TELL, see its first line"
    rotation = None
    reference = _reference_error(args.reference_error) or (0.0, 0.0)  # checked at the start
    if ratios is not None:
        rotation = rotation_fit(runs, [h.geometry for h in folds], settings, ratios, reference)
    text = params_block(result.geometry, ratios, how,
                        None if rotation is None else rotation.noise.k_rotation)
    if args.plot:
        plot(result, runs, args.plot)
    print(fit_report(result, covariance, args.session_drift))
    if rotation is not None:
        print(rotation_line(rotation, len(runs), reference))
    if refused and not args.force:
        print(f"{PREFIX} no params block: the nominal geometry did better on held-out runs "
              "(--force prints it anyway)")
        return 1
    if args.yaml:
        Path(args.yaml).write_text(text, encoding="utf-8")
    print(text, end="")
    return 0


def rotation_fit(runs: Sequence[Run], geometries: Sequence[Geometry | None],
                 settings: OdometrySettings, ratios: tuple[float, float],
                 reference: tuple[float, float]) -> consistency.NoiseFit:
    """``rotation_noise_k`` by maximum likelihood of the held-out final poses.

    Each run integrated with the geometry fitted on the others; the wheel noise k (the
    node's, from the params given) and the printed ratios held fixed.
    """
    from diffdrive_odom.core.evaluation import consistency

    noise = settings.noise
    k = DEFAULT_K if noise is None else 0.5 * (noise.k_left + noise.k_right)
    terms = consistency.held_out_terms(runs, geometries)
    return consistency.fit_noise(terms, consistency.Noise(k, 0.0, *ratios),
                                 reference=consistency.reference_error(*reference))


def _umbmark(args: argparse.Namespace, settings: Settings) -> int:
    typed = args.cw_end is not None
    cw = _run(args.umbmark[0], settings, args, not typed)
    ccw = _run(args.umbmark[1], settings, args, not typed)
    for line in left_out_lines((cw, ccw), settings[0].geometry):
        print(line)
    if typed:
        cw_end = _end_point(args.cw_end, "--cw-end")
        ccw_end = _end_point(args.ccw_end, "--ccw-end")
    else:
        assert cw.reference is not None and ccw.reference is not None
        cw_end = reference_end(cw, cw.reference)
        ccw_end = reference_end(ccw, ccw.reference)
    result = umbmark(cw, ccw, cw_end, ccw_end, side=args.side, nominal=settings[0].geometry)
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
        ax.plot(run.reference.x, run.reference.y, "k-", lw=1.5, label="ground truth")
        spans = leftout.bridges(run)  # drawn as fitted and judged: the slips left out
        for geometry, style, label, m in (
                (fit.nominal, "--", "nominal", figures.before),
                (fit.geometry, "-", "calibrated", figures.after)):
            est = leftout.trajectory(run, geometry, spans) if spans else trajectory(run, geometry)
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


__all__ = ["check_lines", "fit_report", "main", "params_block", "plot", "rotation_fit",
           "rotation_line", "umbmark_report"]

if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
