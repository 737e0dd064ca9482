"""``diffdrive-odom replay``: run the node's estimator over a bag offline, as fast as the disk.

The command line: its flags, the checks made before any work, and what it prints. One
code path with the node: the same parameter file (``rcl.resolve_parameters`` +
``odometry_settings``, so a bad value is refused with the same one line; the flags it
shares with calibrate are :mod:`diffdrive_odom.tools.cmdline.args`), the same pipeline
and publication rule (the engines in :mod:`diffdrive_odom.tools.replaying`: readings,
open-loop commands), frames with the tf prefix. The output is what the node would have
published, written as a rosbag2 (``odom`` and ``/tf``) and/or a CSV (columns in
:mod:`diffdrive_odom.tools.replaying.csvout`); ``--eval`` judges it against the bag's
ground truth (:mod:`diffdrive_odom.tools.evaluate`), several bags are a fleet
(:mod:`diffdrive_odom.tools.fleet`).
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

from diffdrive_odom.core.evaluation import metrics
from diffdrive_odom.tools import evaluate, fleet
from diffdrive_odom.tools.cli import command_parser
from diffdrive_odom.tools.cmdline.args import (
    DEFAULT_REFERENCE,
    add_offset_argument,
    add_param_arguments,
    fail,
    outputs_problem,
    settings_from_args,
)
from diffdrive_odom.tools.cmdline.outputs import STORAGES
from diffdrive_odom.tools.replaying import online_report
from diffdrive_odom.tools.replaying.stats import ReplayStats

__all__ = ["main", "run_bag"]

PREFIX = "[replay]"


# --- CLI -------------------------------------------------------------------------------


def _parser() -> argparse.ArgumentParser:
    ap = command_parser("replay", "Run the odometry node's estimator over a bag offline and "
                        "write what the node would publish (odom + /tf) to a rosbag2 and/or "
                        "CSV, and/or evaluate it.")
    ap.add_argument("bags", nargs="+", metavar="BAG",
                    help="rosbag2 directory (mcap/sqlite3) or ROS 1 .bag; several: a fleet "
                    "(each bag's outputs in the -o/--csv/--json/--plot directories, named "
                    "after it, and one table at the end)")
    add_param_arguments(ap, required=True, file_help="the node's ROS 2 params YAML "
                        "(required; repeatable, later files win)")
    ap.add_argument("--topic", default="/joint_states", help="JointState topic in the bag")
    ap.add_argument("--imu-topic", default="/imu",
                    help="Imu topic in the bag, read when the parameters set use_imu")
    ap.add_argument("--cmd-topic", default=None, metavar="TOPIC",
                    help="Twist/TwistStamped topic in the bag, read when the parameters set "
                    "open_loop (default: /cmd_vel, or /cmd_vel_out with open_loop_source "
                    "cmd_vel_out)")
    ap.add_argument("-o", "--output", metavar="OUT_BAG",
                    help="output rosbag2 directory, must not exist (default: none)")
    ap.add_argument("--storage", choices=STORAGES, default="mcap",
                    help="storage of the output bag")
    ap.add_argument("--odom-topic", default="/odom", help="odometry topic in the output bag")
    ap.add_argument("--tf-topic", default="/tf", help="transform topic in the output bag")
    ap.add_argument("--csv", metavar="FILE",
                    help="write published poses as CSV, columns in doc/tools/replay.md "
                         "(default: none)")
    ap.add_argument("--keep-input", action="store_true",
                    help="copy every input topic into the output bag (ROS 1 -> CDR) "
                    "(default: only the replayed odom and /tf)")
    ap.add_argument("--eval", nargs="?", const=AUTO_REFERENCE, default=None,
                    metavar="GT_TOPIC", help="evaluate against ground truth in the input bag "
                    f"(default: no evaluation; GT_TOPIC defaults to "
                    f"{DEFAULT_REFERENCE}, else the bag's only ground-truth topic)")
    ap.add_argument("--child-frame", default=None, metavar="FRAME",
                    help="ground truth child frame when it is on /tf (default: the only one)")
    add_offset_argument(ap, f"with --eval: {evaluate.OFFSET_DEFAULT}")
    ap.add_argument("--json", metavar="FILE",
                    help="with --eval: write the figures as JSON (default: none)")
    ap.add_argument("--plot", metavar="FILE",
                    help="a PNG: --eval's plot; --online-calibration's estimate with its sigma "
                    "(with both: FILE's name + '_online') (default: none)")
    online_report.add_arguments(ap)
    ap.add_argument("--progress", action=argparse.BooleanOptionalAction, default=None,
                    help="progress line on stderr (default: on a terminal, for long bags)")
    fleet.add_fleet_arguments(ap)
    fleet.add_summary_argument(ap)
    return ap


AUTO_REFERENCE = "<auto>"  # --eval without a topic: poses.reference_topic decides


def _error(text: str) -> int:
    return fail(PREFIX, text)


def _output_problem(args: argparse.Namespace) -> str | None:
    """Why the asked-for outputs cannot be written (checked before any work), or None."""
    if not (args.output or args.csv or args.eval or args.online_calibration):
        return ("nothing to do: give -o OUT_BAG, --csv FILE, --eval and/or "
                "--online-calibration (see diffdrive-odom replay --help)")
    if args.json and not args.eval:
        return "--json needs --eval"
    if args.plot and not (args.eval or args.online_calibration):
        return "--plot needs --eval or --online-calibration"
    if args.output and Path(args.output).exists():
        return f"-o {args.output}: exists: remove it or choose another output"
    return outputs_problem(("-o", args.output), ("--csv", args.csv), ("--json", args.json),
                           ("--plot", args.plot), ("--plot", online_report.plot_path(
                               args.plot, args.online_calibration, args.eval)))


def main(argv: Sequence[str]) -> int:
    """``diffdrive-odom replay``; exit 2 on a bad parameter, bag or output, or nothing to do.

    Several bags: each as one would be (:func:`run_bag`) on ``--jobs`` processes or a
    ``--dask`` cluster; the exit status is then the number that failed.
    """
    args = _parser().parse_args(list(argv))
    return fleet.dispatch(
        args, run_bag, PREFIX, (("output", ""), ("csv", ".csv"), ("json", ".json"),
                                ("plot", ".png")), "--eval --json FILE",
        None if args.output or args.csv or args.eval else
        "nothing to do: give -o OUT_DIR, --csv DIR and/or --eval")


def run_bag(args: argparse.Namespace) -> int:
    """One bag (``args.bag``) with the parsed flags: what ``replay BAG ...`` does."""
    settings = online_report.replay_settings(
        args, lambda a, settled: settings_from_args(a, PREFIX, settled),
        lambda text: print(f"{PREFIX} {text}", file=sys.stderr))
    if isinstance(settings, str):
        return _error(settings)
    problem = _output_problem(args)
    if problem:
        return _error(problem)
    from diffdrive_odom.tools.bags import bagio, poses  # past the parsing: --help needs no rosbags
    from diffdrive_odom.tools.replaying import bag, lagcheck

    if args.plot:  # a missing matplotlib is said before the replay, not after its outputs
        import matplotlib  # noqa: F401

    ref: metrics.Trajectory | None = None
    gt_topic = ""
    if args.eval:  # the reference first: a wrong topic must not cost a whole replay

        def notify(text: str) -> None:
            print(f"{PREFIX} --eval: {text}", file=sys.stderr)

        try:
            gt_topic = poses.reference_topic(
                args.bag, None if args.eval == AUTO_REFERENCE else args.eval, notify=notify,
                flag="--eval TOPIC")
            ref, line = evaluate.on_base_link(poses.read_trajectory(
                args.bag, gt_topic, args.child_frame, "--child-frame", notify),
                args.reference_offset)
            notify(line)
        except bagio.BagError as err:
            return _error(f"--eval: {err}")
    try:
        stats, traj = bag.replay_bag(args, settings)
    except bagio.BagError as err:
        return _error(str(err))
    except OSError as err:
        return _error(f"cannot write the output: {err}")
    except KeyboardInterrupt:  # the staged outputs were removed on the way out
        print(f"{PREFIX} interrupted; no output written", file=sys.stderr)
        return 130
    if not stats.usable:
        _remove_outputs(args)
        return _error(_no_usable_reading(stats, args.cmd_topic or args.topic))
    print(stats.summary())
    if args.online_calibration:
        print(online_report.report(stats.online_trace, stats.pipeline.online))
        where = online_report.plot_path(args.plot, True, args.eval)
        try:
            print(online_report.plot(where, stats.online_trace, Path(args.bag).name), end="")
        except OSError as err:
            return _error(f"--plot: cannot write: {err}")
    gyro = stats.pipeline.gyro
    fleet.record(args, readings=stats.readings, poses=stats.published,
                 slips=None if gyro is None else gyro.slips.events)
    judged: tuple[metrics.Trajectory, metrics.Metrics] | None = None
    if ref is not None:
        try:
            est = traj.trajectory()
            judged = est, metrics.evaluate(est, ref)
        except ValueError as err:
            return _error(f"--eval: {err}")
    lag = lagcheck.advice(args, settings, stats, ref,
                          None if judged is None else judged[1].final_position_error_aligned_m)
    for warning in [*lagcheck.other_warnings(stats), *([lag] if lag else [])]:
        print(f"{PREFIX} {warning}", file=sys.stderr)
    for note, count in stats.notes.items():
        print(f"{PREFIX} {count} x {note}", file=sys.stderr)
    for line in stats.reason_lines():
        print(line, file=sys.stderr)
    for reason, count in stats.refused.most_common():  # the node's warning, counted
        print(f"{PREFIX} {reason}: {count} pose(s) not written", file=sys.stderr)
    if ref is not None and judged is not None:
        est, figures = judged
        fleet.record(args, **evaluate.summary_figures(figures))
        try:
            evaluate.report(figures, est, ref, args.json, args.plot,
                            labels=("replay", gt_topic))
        except ValueError as err:
            return _error(f"--eval: {err}")
        except OSError as err:
            return _error(f"--eval: cannot write: {err}")
    return 0


def _no_usable_reading(stats: ReplayStats, topic: str) -> str:
    """The one line for a bag none of whose readings could be used, with the main reason."""
    head = f"no usable reading in {stats.readings} on {topic}: no output written"
    if not stats.reasons:
        return head
    code, count = stats.reasons.most_common(1)[0]
    return f"{head}; {count} x {code}: {stats.examples[code]}"


def _remove_outputs(args: argparse.Namespace) -> None:
    """Delete what this run created (the output path did not exist before it)."""
    import shutil

    if args.output:
        shutil.rmtree(args.output, ignore_errors=True)
    if args.csv:
        Path(args.csv).unlink(missing_ok=True)


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
