"""replay's commands engine (``-p open_loop:=true``): open-loop odometry over velocity commands.

The node's own core (:class:`~diffdrive_odom.core.estimation.open_loop.OpenLoopOdometry`),
fed the same calls in the same order: each command at its log time, and the node's timer
(``publish_rate``, 50 Hz when 0) as
:func:`~diffdrive_odom.core.estimation.open_loop.publication_times` from the first
command to the end of the bag, the pose published at each tick by the
node's rule (:func:`~diffdrive_odom.core.estimation.publication.publication`). A bag
with commands only (no joint_states) is enough; ``--eval`` then judges it against the
bag's ground truth.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable
from types import MappingProxyType
from typing import TYPE_CHECKING

from diffdrive_odom.core.estimation.config import OdometrySettings
from diffdrive_odom.core.estimation.open_loop import (
    TIME_RESET,
    OpenLoopOdometry,
    publication_rate,
    publication_times,
)
from diffdrive_odom.core.estimation.publication import Refusal, publication
from diffdrive_odom.core.estimation.results import PipelineStats
from diffdrive_odom.core.estimation.wheels.timeline import Status
from diffdrive_odom.tools.replaying.sinks import Published
from diffdrive_odom.tools.replaying.stats import ReplayStats

if TYPE_CHECKING:  # the bag library only where a bag is read (``tools`` extra)
    from diffdrive_odom.tools.bags.bagcommands import CommandSample

OPEN_LOOP_NOTE = "open loop: odometry from the commanded velocity on {topic}, not measured"
TIME_RESET_TEXT = "the log time went back over time_jump_threshold: restarted at the origin"


def replay_commands(
    commands: Iterable[CommandSample], settings: OdometrySettings,
    sink: Callable[[Published], None] | None, end_ns: int, topic: str = "/cmd_vel",
) -> ReplayStats:
    """Commands through a fresh open-loop core, ticks interleaved; poses to ``sink``.

    ``end_ns``: the last tick's bound (the bag's end), so the pose after the last
    command (held until ``cmd_vel_timeout``, then at rest) is published as the node would.
    """
    cfg = settings.open_loop
    assert cfg is not None, "open_loop is false"
    odo = OpenLoopOdometry(cfg, settings.geometry, settings.estimator.time_jump_threshold)
    rate = publication_rate(settings.publish_rate)
    stats = ReplayStats(unit="commands")
    stats.notes[OPEN_LOOP_NOTE.format(topic=topic)] = 1
    start = time.perf_counter()
    published = 0

    def tick(t: int) -> None:
        nonlocal published
        if odo.advance(t) == TIME_RESET:
            _count(stats, TIME_RESET, TIME_RESET_TEXT)
        out = publication(odo.pose, odo.linear, odo.angular, *odo.covariances())
        if isinstance(out, Refusal):
            stats.refused[out.reason] += 1
            return
        published += 1
        if sink is not None:
            sink(Published(t, t, out.pose, out.linear, out.angular, Status.UPDATED,
                           out.pose_covariance, out.twist_covariance))

    ticks = None
    pending: int | None = None
    for c in commands:
        if ticks is None:
            ticks = publication_times(c.log_ns, max(end_ns, c.log_ns), rate)
            pending = next(ticks, None)
        while pending is not None and pending < c.log_ns:
            tick(pending)
            pending = next(ticks, None)
        code = odo.command(c.log_ns, c.linear, c.angular, c.stamp_ns)
        stats.statuses["taken" if code in ("", TIME_RESET) else "dropped"] += 1
        if code:
            _count(stats, code, f"velocity command refused ({code}): v={c.linear!r} "
                   f"w={c.angular!r}" if code != TIME_RESET else TIME_RESET_TEXT)
    while ticks is not None and pending is not None:
        tick(pending)
        pending = next(ticks, None)
    s = odo.stats
    stats.seconds = time.perf_counter() - start
    stats.readings = s.commands
    stats.published = published
    stats.pipeline = PipelineStats(
        readings=s.commands, published=published,
        dropped=MappingProxyType(dict(s.dropped)), time_resets=s.time_resets,
        last_usable_stamp_ns=s.last_command_ns)
    stats.final_pose = odo.pose
    stats.final_stamp_ns = odo.stamp_ns
    return stats


def _count(stats: ReplayStats, code: str, text: str) -> None:
    stats.reasons[code] += 1
    stats.examples.setdefault(code, text)
