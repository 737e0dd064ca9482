"""``diffdrive-odom eval``: how far odometry is from ground truth, in numbers and a plot.

The figures are computed by the pure :mod:`diffdrive_odom.core.evaluation.metrics` (see its
docstring for what each means), the trajectories read from bags by
:mod:`diffdrive_odom.tools.bags.poses`; this module is the CLI, and writes the JSON and
the plot (replay ``--eval`` writes them here too). The reference is first moved onto
base_link (:func:`on_base_link`): by ``--reference-offset`` when given, else by the
yaw its own direction of travel shows (:func:`~diffdrive_odom.core.evaluation.metrics.travel_yaw`),
its lever arm then taken as 0 and said so. Callers that compute figures import them from
:mod:`~diffdrive_odom.core.evaluation.metrics`, where they are defined.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from diffdrive_odom.core.evaluation.judge import base_reference
from diffdrive_odom.core.evaluation.metrics import (
    Metrics,
    Trajectory,
    align_start,
    evaluate,
    match,
    travel_yaw,
)
from diffdrive_odom.core.geometry.mount import Mount
from diffdrive_odom.tools import fleet
from diffdrive_odom.tools.cli import command_parser
from diffdrive_odom.tools.cmdline.args import (
    add_reference_arguments,
    fail,
    outputs_problem,
)

__all__ = ["OFFSET_DEFAULT", "main", "on_base_link", "plot", "report", "run_bag",
           "summary_figures"]

PREFIX = "[eval]"
OFFSET_DEFAULT = ("its yaw from the reference's own direction of travel, its lever arm 0; "
                  "calibrate fits both where its runs determine them")


def on_base_link(ref: Trajectory, offset: Mount | None) -> tuple[Trajectory, str]:
    """The reference moved onto base_link, and the line that says by what mount.

    ``offset``: ``--reference-offset`` (None: the yaw from its direction of travel,
    :func:`~diffdrive_odom.core.evaluation.metrics.travel_yaw`, the lever arm 0).
    """
    if offset is not None:
        return base_reference(ref, offset), f"reference mount (--reference-offset): {offset.text()}"
    yaw, sigma, moved = travel_yaw(ref)
    mount = Mount(0.0, 0.0, yaw)
    if moved <= 0.0:
        return ref, "reference mount: taken as base_link's (the reference never moves straight)"
    return base_reference(ref, mount), (
        f"reference mount: yaw {math.degrees(yaw):+.2f} +- {math.degrees(sigma):.2f} deg from "
        f"its direction of travel ({moved:.1f} m), lever arm taken as 0 (give "
        "--reference-offset X,Y,YAW if it is off the axle: calibrate prints it)")


# --- output ---------------------------------------------------------------------------------


def plot(
    est: Trajectory,
    ref: Trajectory,
    path: str | Path,
    labels: tuple[str, str] = ("odometry", "reference"),
    max_gap: float = 0.5,
) -> None:
    """PNG: the paths (raw and start-aligned odometry) and the position error over time."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    m = match(est, ref, max_gap)
    aligned = align_start(m.est, m.ref)
    t = (m.stamp_ns - m.stamp_ns[0]) * 1e-9
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(12, 5.5))
    ax1.plot(ref.x, ref.y, "k-", lw=1.5, label=labels[1])
    ax1.plot(est.x, est.y, "-", color="tab:blue", lw=1.0, label=labels[0])
    ax1.plot(aligned[:, 0], aligned[:, 1], "--", color="tab:orange", lw=1.0,
             label=f"{labels[0]}, start aligned")
    ax1.plot(m.ref[-1, 0], m.ref[-1, 1], "ko")
    ax1.plot(m.est[-1, 0], m.est[-1, 1], "o", color="tab:blue")
    ax1.set_aspect("equal", adjustable="datalim")
    ax1.set_xlabel("x [m]")
    ax1.set_ylabel("y [m]")
    ax1.grid(True, alpha=0.3)
    ax1.legend(loc="best", fontsize=8)
    ax1.set_title("path")
    ax2.plot(t, np.hypot(*(m.est[:, :2] - m.ref[:, :2]).T), color="tab:blue", label="raw")
    ax2.plot(t, np.hypot(*(aligned[:, :2] - m.ref[:, :2]).T), "--", color="tab:orange",
             label="start aligned")
    ax2.set_xlabel("time [s]")
    ax2.set_ylabel("position error [m]")
    ax2.grid(True, alpha=0.3)
    ax2.legend(loc="best", fontsize=8)
    ax2.set_title("error against the reference")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def report(
    metrics: Metrics,
    est: Trajectory,
    ref: Trajectory,
    json_path: str | None,
    plot_path: str | None,
    labels: tuple[str, str] = ("odometry", "reference"),
) -> None:
    """Write JSON and PNG when asked, then print the table.

    Files first: a closed pipe on stdout must not lose them. Without matplotlib (the
    ``tools`` extra) the table is still printed, then the ModuleNotFoundError goes on
    to the command's one line naming the extra.
    """
    if json_path:
        figures = {k: (None if isinstance(v, float) and not math.isfinite(v) else v)
                   for k, v in metrics.as_dict().items()}
        Path(json_path).write_text(json.dumps(figures, indent=2) + "\n", encoding="utf-8")
    try:
        if plot_path:
            plot(est, ref, plot_path, labels)
    finally:
        print(metrics.table())


def summary_figures(metrics: Metrics) -> dict[str, float]:
    """A bag's row of a fleet's summary (start aligned, as the error per metre is)."""
    return {"distance_m": metrics.distance_m,
            "final_error_m": metrics.final_position_error_aligned_m,
            "ate_m": metrics.ate_rmse_aligned_m, "error_per_m": metrics.final_error_per_m}


def _parser() -> argparse.ArgumentParser:
    ap = command_parser("eval", "Compare odometry with ground truth recorded in a bag.")
    ap.add_argument("bags", nargs="+", metavar="BAG",
                    help="bag with the odometry (and, by default, the ground truth); several: "
                    "a fleet (--json/--plot then name directories; one table at the end)")
    ap.add_argument("--odom", default="/odom", metavar="TOPIC",
                    help="odometry topic (any pose type, or /tf)")
    ap.add_argument("--odom-child-frame", default=None, metavar="FRAME",
                    help="odometry child frame on /tf (default: the only one there)")
    add_reference_arguments(ap, OFFSET_DEFAULT)
    ap.add_argument("--reference-bag", default=None, metavar="BAG",
                    help="read the reference from this bag instead, e.g. replay's input "
                    "(default: BAG)")
    ap.add_argument("--segment-length", type=float, default=1.0, metavar="M",
                    help="stretch length for the relative error [m]")
    ap.add_argument("--max-gap", type=float, default=0.5, metavar="S",
                    help="longest reference gap to interpolate across [s]")
    ap.add_argument("--json", metavar="FILE",
                    help="write the figures as JSON (default: not written)")
    ap.add_argument("--plot", metavar="FILE", help="write a PNG plot (default: not written)")
    fleet.add_fleet_arguments(ap)
    fleet.add_summary_argument(ap)
    return ap


def main(argv: Sequence[str]) -> int:
    """``diffdrive-odom eval``; exit 2 when a topic, bag or output path cannot be used.

    Several bags: each as one would be (:func:`run_bag`), on ``--jobs`` processes or a
    ``--dask`` cluster; the exit status is then the number that failed.
    """
    args = _parser().parse_args(list(argv))
    return fleet.dispatch(
        args, run_bag, PREFIX, (("json", ".json"), ("plot", ".png")), "--json FILE",
        "--reference-bag takes one odometry bag (each of several bags holds its own "
        "reference)" if args.reference_bag else None)


def run_bag(args: argparse.Namespace) -> int:
    """One bag (``args.bag``) with the parsed flags: what ``eval BAG ...`` does."""
    if not (args.segment_length > 0 and args.max_gap > 0):
        return fail(PREFIX, "--segment-length and --max-gap must be > 0")
    problem = outputs_problem(("--json", args.json), ("--plot", args.plot))  # before any work
    if problem:
        return fail(PREFIX, problem)

    def notify(text: str) -> None:
        print(f"{PREFIX} {text}", file=sys.stderr)

    from diffdrive_odom.tools.bags import bagio  # past the parsing: --help needs no bag library
    from diffdrive_odom.tools.bags.poses import read_trajectory, reference_topic

    ref_bag = args.reference_bag or args.bag
    try:
        try:
            est = read_trajectory(args.bag, args.odom, args.odom_child_frame,
                                  "--odom-child-frame", notify)
        except bagio.UnreadableBagError:
            raise  # what to do is said; no other topic can help
        except bagio.BagError as err:
            raise bagio.BagError(f"{err}{_commands_only_hint(args.bag)}") from None
        exclude = [args.odom] if ref_bag == args.bag else []
        try:
            gt = reference_topic(ref_bag, args.ground_truth, exclude, notify)
        except bagio.BagError as err:
            if args.reference_bag is not None or args.ground_truth is not None:
                raise
            # The usual case: the output of replay, which holds only the odometry.
            raise bagio.BagError(f"{err}. A bag written by replay holds no ground truth: "
                                 "give the bag it replayed as --reference-bag BAG") from None
        ref, line = on_base_link(read_trajectory(ref_bag, gt, args.child_frame, "--child-frame",
                                                 notify), args.reference_offset)
        notify(line)
        metrics = evaluate(est, ref, args.segment_length, args.max_gap)
        fleet.record(args, **summary_figures(metrics))
        report(metrics, est, ref, args.json, args.plot, (args.odom, gt))
    except (bagio.BagError, ValueError) as err:
        return fail(PREFIX, str(err))
    except OSError as err:  # the output vanished or filled up after the check
        return fail(PREFIX, f"cannot write: {err}")
    return 0


def _commands_only_hint(bag: str | Path) -> str:
    """For a bag without odometry but with velocity commands: how to judge them (open loop)."""
    from diffdrive_odom.tools.bags import bagcommands, bagio

    with bagio.open_bag(bag) as reader:
        topics = bagcommands.command_topics(reader)
    if not topics:
        return ""
    return (f". It holds velocity commands ({', '.join(topics)}): integrate them in open loop "
            f"and judge that: diffdrive-odom replay {bag} --params-file ROBOT.yaml -p "
            "open_loop:=true --eval (--cmd-topic TOPIC)")


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
