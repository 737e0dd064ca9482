"""replay's readings engine: wheel readings (and gyro, reference) through the node's pipeline.

One code path with the node: a fresh
:class:`~diffdrive_odom.core.estimation.pipeline.ReadingPipeline` (estimator, zero stamps
dropped, gap rule, ``publish_rate``), what is published decided by its rule
(:func:`~diffdrive_odom.core.estimation.publication.pipeline_publication`: nothing
non-finite goes out), the poses handed to a sink (:mod:`.sinks`). Stretches where no rule
can fire go through the fast lane (:mod:`diffdrive_odom.core.bulk.fastlane`) in bulk,
with the same result. Readings come from :mod:`diffdrive_odom.tools.bags.bagreadings`
(one by one) or :mod:`~diffdrive_odom.tools.bags.bagblocks` (in blocks); velocity
commands (open loop) go through :mod:`.openloop` instead. The vectorised way through a
bag (decode once, integrate for any geometry) is the core's
:mod:`diffdrive_odom.core.bulk.batch`, which calibration re-runs in its fitting loop.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable, Iterator
from typing import TYPE_CHECKING

from diffdrive_odom.core.bulk import fastlane
from diffdrive_odom.core.bulk.readings import JointBlock, JointReading
from diffdrive_odom.core.estimation.config import OdometrySettings
from diffdrive_odom.core.estimation.pipeline import ReadingPipeline
from diffdrive_odom.core.estimation.publication import Refusal, pipeline_publication
from diffdrive_odom.core.estimation.results import Outcome
from diffdrive_odom.core.estimation.wheels.encoders import Reason
from diffdrive_odom.core.estimation.wheels.timeline import Status
from diffdrive_odom.tools.replaying import sinks
from diffdrive_odom.tools.replaying.sinks import Published
from diffdrive_odom.tools.replaying.stats import ReplayStats

if TYPE_CHECKING:  # the bag library only where bags are read (``tools`` extra)
    from diffdrive_odom.tools.bags import bagreadings

__all__ = ["replay_readings"]


def _stretch_out(stretch: fastlane.Stretch, sink: Callable[[Published], None]) -> None:
    """The poses of a stretch the fast lane integrated, as the node would publish them."""
    if isinstance(sink, sinks.OutputSink):  # in bulk: the same bytes and text
        sink.stretch(stretch)
        return
    for stamp, log, pose, lin, ang, pcov, tcov in stretch.poses():
        sink(Published(stamp, log, pose, lin, ang, Status.UPDATED, pcov, tcov))


def replay_readings(
    readings: Iterable[bagreadings.Reading | JointBlock],
    settings: OdometrySettings,
    sink: Callable[[Published], None] | None = None,
    fast: bool = True,
) -> ReplayStats:
    """Feed readings through a fresh pipeline; the poses the node would publish go to ``sink``.

    ``fast``: stretches where no rule can fire go through :mod:`diffdrive_odom.core.bulk.fastlane`
    (the same result, proven by test/core/bulk/test_fastlane.py); False: every reading one by one.
    A :class:`~diffdrive_odom.core.bulk.readings.JointBlock` stands for its readings in order.

    What is published is decided as in the node (:func:`pipeline_publication`): a pose
    it refuses is counted in ``refused``, not written. Without a sink nothing is written,
    so nothing is built or checked (the estimator alone, as the benchmarks time it).
    """
    from diffdrive_odom.tools.bags import bagreadings  # rosbags: only where bags are read

    pipe = ReadingPipeline(settings, trace=True)
    est = pipe.estimator
    stats = ReplayStats()
    start = time.perf_counter()
    # The bag's log time is the receive time: the node's rules on stamps apply alike.
    def one_by_one(
        rs: Iterable[bagreadings.Reading | JointBlock],
    ) -> Iterator[tuple[JointReading, Outcome]]:
        for item in rs:
            for r in item if isinstance(item, JointBlock) else (item,):
                if isinstance(r, bagreadings.ImuSample):  # use_imu: gyro samples, as the node's
                    pipe.feed_imu(r.stamp_ns, r.wx, r.wy, r.wz, r.log_ns,
                                  covariance=r.covariance)
                    continue
                if isinstance(r, bagreadings.ReferenceSample):  # the online estimate's scale
                    pipe.feed_reference(r.stamp_ns, r.x, r.y, r.yaw)
                    continue
                yield r, pipe.feed(r.stamp_ns, r.names, r.position, r.velocity, r.log_ns)

    items: Iterable[tuple[JointReading, Outcome] | fastlane.Stretch] = (
        fastlane.lanes(pipe, readings, chunk=fastlane.CHUNK)  # type: ignore[arg-type]
        if fast and settings.takes_bulk else one_by_one(readings))
    for item in items:
        if isinstance(item, fastlane.Stretch):
            stats.statuses[Status.UPDATED.value] += item.count
            if sink is not None:
                _stretch_out(item, sink)
            continue
        r, outcome = item
        if outcome.warning:
            stats.warnings.append(outcome.warning)
        if outcome.note:
            stats.notes[outcome.note] += 1
        verdict = outcome.verdict
        stats.statuses[verdict.status.value] += 1
        if verdict.code not in (Reason.UPDATED, Reason.FIRST):
            stats.reasons[verdict.code] += verdict.count  # a discarded burst: all
            stats.examples.setdefault(verdict.code, verdict.reason)
        if outcome.publish and sink is not None:
            out = pipeline_publication(pipe)
            if isinstance(out, Refusal):
                stats.refused[out.reason] += 1
            else:
                sink(Published(outcome.stamp_ns, r.log_ns, out.pose, out.linear, out.angular,
                               verdict.status, out.pose_covariance, out.twist_covariance))
    stats.seconds = time.perf_counter() - start
    stats.pipeline = pipe.stats
    stats.online_trace = [] if pipe.online is None else pipe.online.trace
    stats.readings = stats.pipeline.readings
    stats.published = stats.pipeline.published - sum(stats.refused.values())
    stats.final_pose = est.pose
    stats.final_stamp_ns = est.stamp_ns
    return stats
