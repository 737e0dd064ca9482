"""One bag replayed into replay's outputs: the bag opened, the outputs staged, an engine run.

What ``diffdrive-odom replay BAG`` does between its flags and its report
(:mod:`diffdrive_odom.tools.replay`). The output bag (``odom``, ``/tf``, with
``--keep-input`` every input topic) and the CSV table are written under a staged name and
get theirs only if the whole replay worked
(:func:`~diffdrive_odom.tools.cmdline.outputs.staged`). The bag's wheel readings go
through the readings engine (:mod:`.readings`; in blocks where the fast lane takes them),
or, with ``open_loop``, its velocity commands through the commands engine
(:mod:`.openloop`); both into the one sink (:mod:`.sinks`).
"""

from __future__ import annotations

import argparse
from collections.abc import Iterable
from contextlib import ExitStack

from diffdrive_odom.core.bulk.readings import JointBlock
from diffdrive_odom.core.bulk.readings import count as reading_count
from diffdrive_odom.core.estimation.config import OdometrySettings
from diffdrive_odom.core.estimation.stamps import StampSource
from diffdrive_odom.tools.bags import bagblocks, bagcommands, bagio, bagreadings, bagwriter
from diffdrive_odom.tools.cmdline import progress
from diffdrive_odom.tools.cmdline.outputs import staged
from diffdrive_odom.tools.replaying import csvout, online_report, sinks
from diffdrive_odom.tools.replaying.openloop import replay_commands
from diffdrive_odom.tools.replaying.readings import replay_readings
from diffdrive_odom.tools.replaying.stats import ReplayStats

__all__ = ["command_topic", "replay_bag"]

PREFIX = "[replay]"  # the progress line's


def replay_bag(args: argparse.Namespace, settings: OdometrySettings
               ) -> tuple[ReplayStats, sinks.PoseLog]:
    """Replay ``args.bag`` into the outputs ``args`` names (replay's flags); what it did.

    The poses are also kept (the :class:`~.sinks.PoseLog`) when ``args.eval`` asks.
    """
    traj = sinks.PoseLog()
    settings = online_report.with_static_mount(args.bag, settings)
    with ExitStack() as stack:
        reader = stack.enter_context(bagio.open_bag(args.bag))
        total = bagio.count_messages(reader, args.topic)
        if settings.gyro is not None:  # the IMU's samples pass through the progress too
            total += bagio.count_messages(reader, args.imu_topic)
        writer = None
        if args.output:
            path = stack.enter_context(staged(args.output))
            writer = stack.enter_context(bagwriter.BagWriter(path, args.storage))
        csv_out = None
        if args.csv:
            csv_out = stack.enter_context(csvout.CsvWriter(stack.enter_context(
                staged(args.csv))))
        passthrough = None
        if writer is not None:
            writer.add_topic(args.odom_topic, bagio.ODOMETRY)
            if settings.enable_odom_tf:
                writer.add_topic(args.tf_topic, bagio.TF_MESSAGE)
            if args.keep_input:
                passthrough = sinks.keep_input(reader, writer, args.odom_topic)
        sink = sinks.OutputSink(settings, writer, csv_out, traj if args.eval else None,
                                odom_topic=args.odom_topic, tf_topic=args.tf_topic)
        if settings.open_loop is not None:  # commands, not wheel readings
            topic = args.cmd_topic = command_topic(args, settings)  # what the summary names
            commands = bagcommands.iter_commands(reader, topic, passthrough)
            return replay_commands(commands, settings, sink, int(reader.end_time), topic), traj
        jump = int(settings.estimator.time_jump_threshold * 1e9)
        readings: Iterable[bagreadings.Reading | JointBlock]
        if settings.takes_bulk and passthrough is None:  # runs of alike messages at once
            readings = bagblocks.iter_joint_blocks(reader, args.topic, jump_back_ns=jump)
        else:
            gyro = settings.gyro
            readings = bagreadings.iter_readings(
                reader, args.topic, None if gyro is None else args.imu_topic,
                online_report.reference_topic(settings), bagreadings.Stream(
                    passthrough, jump_back_ns=jump, imu_by_log_time=gyro is not None
                    and gyro.stamp_source is StampSource.RECEIVE_TIME))
        if progress.wanted(args.progress, total):
            readings = progress.progress(readings, total, PREFIX, weight=reading_count)
        stats = replay_readings(readings, settings, sink)
    return stats, traj


def command_topic(args: argparse.Namespace, settings: OdometrySettings) -> str:
    """``--cmd-topic``, else the source's topic at the root (``/cmd_vel``, ``/cmd_vel_out``)."""
    assert settings.open_loop is not None
    return str(args.cmd_topic or "/" + settings.open_loop.topic)
