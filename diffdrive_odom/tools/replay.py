"""``diffdrive-odom replay``: run the node's estimator over a bag offline, as fast as the disk.

One code path with the node: the same parameter file (``params.resolve_parameters`` +
``odometry_settings``, so a bad value is refused with the same one line), the
same :class:`~diffdrive_odom.core.pipeline.ReadingPipeline` (estimator, zero stamps
dropped, gap rule, ``publish_rate``), frames with the tf prefix. The
output is what the node would have published, written as a rosbag2 (``odom`` and
``/tf``) and/or a CSV (columns in :mod:`diffdrive_odom.tools.bagio`).

Two ways through a bag:

- streaming (:func:`replay_readings`): one reading at a time, constant memory, used
  by the CLI;
- vectorised (:func:`~diffdrive_odom.core.batch.wheel_steps` then
  :func:`~diffdrive_odom.core.batch.integrate_steps`, in the pure :mod:`diffdrive_odom.core.batch`):
  the bag decoded once into geometry-free wheel increments, then integrated for any
  geometry with numpy. The estimator itself decides which readings become steps, so
  both ways agree on what is dropped; calibration re-runs only the cheap second half
  in its fitting loop.
"""

from __future__ import annotations

import argparse
import sys
import time
from array import array
from collections import Counter
from collections.abc import Callable, Iterable, Iterator, Sequence
from contextlib import ExitStack
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
from rosbags.highlevel import AnyReader
from rosbags.interfaces import Connection

from diffdrive_odom.core.cdr import OdometryLayout, TransformLayout
from diffdrive_odom.core.estimator import Reason, Status
from diffdrive_odom.core.integration import Pose2D
from diffdrive_odom.core.pipeline import PipelineStats, ReadingPipeline
from diffdrive_odom.settings.odometry import OdometrySettings, odometry_settings
from diffdrive_odom.settings.params import (
    ParameterError,
    ParamSource,
    resolve_parameters,
)
from diffdrive_odom.settings.registry import unknown_parameters_report
from diffdrive_odom.tools import bagio, evaluate
from diffdrive_odom.tools.cli import HelpFormatter

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]
NODE_NAME = "odometry_node"
PROGRESS_MIN_READINGS = 20_000  # below this a bar is noise


def load_settings(
    params: str | Path | Sequence[ParamSource], node_name: str = NODE_NAME,
    namespace: str = "/",
) -> OdometrySettings:
    """Return the node's settings from its params files and ``-p`` overrides.

    Sources are in command-line order, resolved as rclpy resolves them for this node
    name and namespace, and validated exactly as the node does.
    """
    sources = [("file", str(params))] if isinstance(params, (str, Path)) else list(params)
    values = resolve_parameters(sources, node_name, namespace)
    for line in unknown_parameters_report(list(values)):
        if line:
            print(f"[replay] {line}", file=sys.stderr)
    return odometry_settings(values, "/" + namespace.strip("/"))


class _RosParam(argparse.Action):
    """Keeps ``--params-file`` and ``-p`` in one list, in command-line order (rcl's order)."""

    def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace,
                 values: Any, option_string: str | None = None) -> None:
        kind = "file" if option_string == "--params-file" else "param"
        namespace.ros_params = [*(getattr(namespace, "ros_params", None) or []), (kind, values)]


@dataclass
class Published:
    """One pose the node would publish."""

    stamp_ns: int
    log_ns: int
    pose: Pose2D
    linear: float
    angular: float
    status: Status
    pose_covariance: Sequence[float]  # 6x6 row-major, as the node publishes it
    twist_covariance: Sequence[float]


@dataclass
class ReplayStats:
    """What a replay did, for the summary line and the tests.

    ``reasons`` counts by reason code (see ``encoders.Reason``), ``examples`` keeps
    the first human text of each code; ``pipeline`` is the shared counters' snapshot.
    """

    readings: int = 0
    published: int = 0
    statuses: Counter[str] = field(default_factory=Counter)
    reasons: Counter[str] = field(default_factory=Counter)
    examples: dict[str, str] = field(default_factory=dict)
    final_pose: Pose2D = field(default_factory=Pose2D)
    final_stamp_ns: int | None = None
    seconds: float = 0.0
    pipeline: PipelineStats = field(default_factory=PipelineStats)

    @property
    def usable(self) -> bool:
        """True when at least one reading got past the drop rules."""
        return self.pipeline.last_usable_stamp_ns is not None

    def summary(self) -> str:
        """One human line."""
        p = self.final_pose
        rate = self.readings / self.seconds if self.seconds > 0 else float("inf")
        counts = ", ".join(f"{k} {v}" for k, v in sorted(self.statuses.items()))
        return (
            f"{self.readings} readings ({counts}) -> {self.published} poses in "
            f"{self.seconds:.2f} s ({rate:,.0f} readings/s); final pose x={p.x:.6f} m "
            f"y={p.y:.6f} m yaw={p.theta:.6f} rad"
        )


def replay_readings(
    readings: Iterable[bagio.JointReading],
    settings: OdometrySettings,
    sink: Callable[[Published], None] | None = None,
) -> ReplayStats:
    """Feed readings through a fresh pipeline; the poses the node would publish go to ``sink``."""
    pipe = ReadingPipeline(settings)
    est = pipe.estimator
    stats = ReplayStats()
    start = time.perf_counter()
    for r in readings:
        outcome = pipe.feed(r.stamp_ns, r.names, r.position, r.velocity)
        verdict = outcome.verdict
        stats.statuses[verdict.status.value] += 1
        if verdict.code not in (Reason.UPDATED, Reason.FIRST):
            stats.reasons[verdict.code] += 1
            stats.examples.setdefault(verdict.code, verdict.reason)
        if outcome.publish and sink is not None:
            sink(Published(r.stamp_ns, r.log_ns, est.pose, est.linear, est.angular,
                           verdict.status, *pipe.covariances()))
    stats.seconds = time.perf_counter() - start
    stats.pipeline = pipe.stats
    stats.readings, stats.published = stats.pipeline.readings, stats.pipeline.published
    stats.final_pose = est.pose
    stats.final_stamp_ns = est.stamp_ns
    return stats


# --- CLI -------------------------------------------------------------------------------


class _Trajectory:
    """Published poses kept compactly (32 bytes each) for ``--eval``."""

    def __init__(self) -> None:
        self.stamp_ns = array("q")
        self.xyz = array("d")

    def add(self, p: Published) -> None:
        self.stamp_ns.append(p.stamp_ns)
        self.xyz.extend((p.pose.x, p.pose.y, p.pose.theta))


def add_param_arguments(ap: argparse.ArgumentParser, required: bool, file_help: str) -> None:
    """Add the flags every tool running the node's estimator takes its settings from.

    ``--params-file`` / ``-p`` go into one ordered list (rcl's order), then
    ``--node-name`` and ``--namespace``.
    """
    ap.add_argument("--params-file", required=required, action=_RosParam, dest="ros_params",
                    metavar="FILE", help=file_help)
    ap.add_argument("-p", "--param", action=_RosParam, dest="ros_params", metavar="NAME:=VALUE",
                    help="parameter override, as the node's -p (repeatable; order with "
                         "--params-file matters as in rcl; default: none)")
    ap.add_argument("--node-name", default=NODE_NAME,
                    help="node name the params are resolved for (-r __node:=)")
    ap.add_argument("--namespace", default="/",
                    help="node namespace (-r __ns:=): params resolution and frame prefix")


def settings_from_args(args: argparse.Namespace) -> OdometrySettings | str:
    """The settings :func:`add_param_arguments`' flags give, or the one line why not."""
    try:
        return load_settings(args.ros_params, args.node_name, args.namespace)
    except ParameterError as err:
        return str(err)
    except OSError as err:
        return f"--params-file: {err}"


def _parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(
        prog="diffdrive-odom replay",
        description="Run the odometry node's estimator over a bag offline and write what "
        "the node would publish (odom + /tf) to a rosbag2 and/or CSV, and/or evaluate it.",
        formatter_class=HelpFormatter,
    )
    ap.add_argument("bag", help="rosbag2 directory (mcap/sqlite3) or ROS 1 .bag")
    add_param_arguments(ap, required=True, file_help="the node's ROS 2 params YAML "
                        "(required; repeatable, later files win)")
    ap.add_argument("--topic", default="/joint_states", help="JointState topic in the bag")
    ap.add_argument("-o", "--output", metavar="OUT_BAG",
                    help="output rosbag2 directory, must not exist (default: none)")
    ap.add_argument("--storage", choices=bagio.STORAGES, default="mcap",
                    help="storage of the output bag")
    ap.add_argument("--odom-topic", default="/odom", help="odometry topic in the output bag")
    ap.add_argument("--tf-topic", default="/tf", help="transform topic in the output bag")
    ap.add_argument("--csv", metavar="FILE",
                    help="write published poses as CSV, columns in the README (default: none)")
    ap.add_argument("--keep-input", action="store_true",
                    help="copy every input topic into the output bag (ROS 1 -> CDR) "
                    "(default: only the replayed odom and /tf)")
    ap.add_argument("--eval", nargs="?", const=AUTO_REFERENCE, default=None,
                    metavar="GT_TOPIC", help="evaluate against ground truth in the input bag "
                    f"(default: no evaluation; GT_TOPIC defaults to "
                    f"{evaluate.DEFAULT_REFERENCE}, else the bag's only ground-truth topic)")
    ap.add_argument("--child-frame", default=None, metavar="FRAME",
                    help="ground truth child frame when it is on /tf (default: the only one)")
    ap.add_argument("--json", metavar="FILE",
                    help="with --eval: write the figures as JSON (default: none)")
    ap.add_argument("--plot", metavar="FILE",
                    help="with --eval: write a PNG plot (default: none)")
    ap.add_argument("--progress", action=argparse.BooleanOptionalAction, default=None,
                    help="progress line on stderr (default: on a terminal, for long bags)")
    return ap


AUTO_REFERENCE = "<auto>"  # --eval without a topic: evaluate.reference_topic decides


def _error(text: str) -> int:
    print(f"[replay] {text}", file=sys.stderr)
    return 2


def _output_problem(args: argparse.Namespace) -> str | None:
    """Why the asked-for outputs cannot be written (checked before any work), or None."""
    if not (args.output or args.csv or args.eval):
        return ("nothing to do: give -o OUT_BAG, --csv FILE and/or --eval "
                "(see diffdrive-odom replay --help)")
    if (args.json or args.plot) and not args.eval:
        return "--json/--plot need --eval"
    if args.output and Path(args.output).exists():
        return f"-o {args.output}: exists: remove it or choose another output"
    for flag, path in (("-o", args.output), ("--csv", args.csv)):
        problem = bagio.output_problem(path, flag) if path else None
        if problem:
            return problem
    return evaluate.output_problem(args.json, args.plot)


def main(argv: Sequence[str]) -> int:
    """``diffdrive-odom replay``; exit 2 on a bad parameter, bag or output, or nothing to do."""
    args = _parser().parse_args(list(argv))
    settings = settings_from_args(args)
    if isinstance(settings, str):
        return _error(settings)
    problem = _output_problem(args)
    if problem:
        return _error(problem)
    ref: evaluate.Trajectory | None = None
    gt_topic = ""
    if args.eval:  # the reference first: a wrong topic must not cost a whole replay

        def notify(text: str) -> None:
            print(f"[replay] --eval: {text}", file=sys.stderr)

        try:
            gt_topic = evaluate.reference_topic(
                args.bag, None if args.eval == AUTO_REFERENCE else args.eval, notify=notify)
            ref = evaluate.read_trajectory(args.bag, gt_topic, args.child_frame,
                                           "--child-frame", notify)
        except bagio.BagError as err:
            return _error(f"--eval: {err}")
    try:
        stats, traj = _run(args, settings)
    except bagio.BagError as err:
        return _error(str(err))
    except OSError as err:
        return _error(f"cannot write the output: {err}")
    except KeyboardInterrupt:  # the staged outputs were removed on the way out
        print("[replay] interrupted; no output written", file=sys.stderr)
        return 130
    if not stats.usable:
        _remove_outputs(args)
        print(f"[replay] {_no_usable_reading(stats, args.topic)}", file=sys.stderr)
        return 2
    print(stats.summary())
    for code, count in stats.reasons.most_common(5):
        print(f"  {count} x {code}: {stats.examples[code]}", file=sys.stderr)
    if ref is not None:
        try:
            est = evaluate.Trajectory.from_arrays(
                np.frombuffer(traj.stamp_ns, dtype=np.int64),
                *np.frombuffer(traj.xyz, dtype=np.float64).reshape(-1, 3).T,
            )
            metrics = evaluate.evaluate(est, ref)
            evaluate.report(metrics, est, ref, args.json, args.plot,
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


def _progress(readings: Iterable[bagio.JointReading], total: int) -> Iterator[bagio.JointReading]:
    """Pass readings through, redrawing one ``done/total`` line on stderr twice a second.

    A plain line instead of a progress-bar library: one dependency fewer on a robot,
    and all a replay at ~10-50 k readings/s needs.
    """
    def line(n: int, elapsed: float) -> str:
        rate = n / elapsed if elapsed > 0 else 0.0
        share = f" ({100 * n / total:3.0f} %)" if total else ""
        return f"\r[replay] {_si(n)}/{_si(total)} readings{share} {_si(int(rate))}/s"

    start = last = time.monotonic()
    n = 0
    for n, r in enumerate(readings, 1):
        now = time.monotonic()
        if now - last >= 0.5:
            sys.stderr.write(line(n, now - start))
            sys.stderr.flush()
            last = now
        yield r
    sys.stderr.write(line(n, time.monotonic() - start) + "\n")
    sys.stderr.flush()


def _si(n: int) -> str:
    return f"{n / 1e6:.2f}M" if n >= 10**6 else f"{n / 1e3:.2f}k" if n >= 1000 else str(n)


def _run(args: argparse.Namespace, settings: OdometrySettings) -> tuple[ReplayStats, _Trajectory]:
    """Replay into staged outputs; they get their names only if the whole replay worked."""
    traj = _Trajectory()
    with ExitStack() as stack:
        reader = stack.enter_context(bagio.open_bag(args.bag))
        total = bagio.count_messages(reader, args.topic)
        writer = None
        if args.output:
            staged = stack.enter_context(bagio.staged(args.output))
            writer = stack.enter_context(bagio.BagWriter(staged, args.storage))
        csv_out = None
        if args.csv:
            csv_out = stack.enter_context(bagio.CsvWriter(stack.enter_context(
                bagio.staged(args.csv))))
        passthrough = None
        if writer is not None:
            writer.add_topic(args.odom_topic, bagio.ODOMETRY)
            if settings.enable_odom_tf:
                writer.add_topic(args.tf_topic, bagio.TF_MESSAGE)
            if args.keep_input:
                passthrough = _keep_input(reader, writer, args)
        readings: Iterable[bagio.JointReading] = bagio.iter_joint_states(
            reader, args.topic, passthrough,
            jump_back_ns=int(settings.estimator.time_jump_threshold * 1e9))
        show = args.progress if args.progress is not None else (
            sys.stderr.isatty() and total >= PROGRESS_MIN_READINGS)
        if show:
            readings = _progress(readings, total)
        sink = output_sink(settings, writer, csv_out, traj if args.eval else None,
                           odom_topic=args.odom_topic, tf_topic=args.tf_topic)
        stats = replay_readings(readings, settings, sink)
    return stats, traj


def _keep_input(
    reader: AnyReader, writer: bagio.BagWriter, args: argparse.Namespace
) -> bagio.Passthrough:
    """Copy every input message (converted to CDR) into the output bag as it streams by."""
    convert = bagio.CdrConverter(reader)
    for conn in reader.connections:
        if conn.topic == args.odom_topic:
            raise bagio.BagError(
                f"--keep-input: the input bag already has {conn.topic}; choose another "
                "--odom-topic for the replayed odometry")
    registered: set[str] = set()

    def passthrough(conn: Connection, log_ns: int, raw: bytes) -> None:
        data = convert(conn, raw)
        if conn.topic not in registered:
            writer.add_topic(conn.topic, conn.msgtype, convert.typestore)
            registered.add(conn.topic)
        writer.write_cdr(conn.topic, log_ns, data)

    return passthrough


def output_sink(
    settings: OdometrySettings,
    writer: bagio.BagWriter | None,
    csv_out: bagio.CsvWriter | None,
    traj: _Trajectory | None = None,
    *,
    odom_topic: str = "/odom",
    tf_topic: str = "/tf",
) -> Callable[[Published], None]:
    """Where each published pose goes: output bag, CSV table, ``--eval`` trajectory.

    The bag's topics are registered by the caller.
    """
    # The node's own byte layouts: the bag holds what the node would have published.
    odom = OdometryLayout(settings.odom_frame_id, settings.base_frame_id)
    transform = TransformLayout(settings.odom_frame_id, settings.base_frame_id)
    tf = settings.enable_odom_tf

    def sink(p: Published) -> None:
        x, y, yaw = p.pose.x, p.pose.y, p.pose.theta
        if writer is not None:
            odom.covariance(p.pose_covariance, p.twist_covariance)
            writer.write_cdr(odom_topic, p.log_ns,
                             odom.planar(p.stamp_ns, x, y, yaw, p.linear, p.angular))
            if tf:
                writer.write_cdr(tf_topic, p.log_ns, transform.planar(p.stamp_ns, x, y, yaw))
        if csv_out is not None:
            csv_out.row(p.stamp_ns, x, y, yaw, linear=p.linear, angular=p.angular,
                        status=p.status.value, pose_covariance=p.pose_covariance)
        if traj is not None:
            traj.add(p)

    return sink


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
