"""The batch path: decode readings once into wheel increments, integrate them many times.

Pure Python + numpy (no rclpy, no message or bag import), so replay, the benchmarks
and calibration share it whatever the readings come from (a bag, the simulator, a
list in a test). The estimator itself
(:class:`~diffdrive_odom.core.estimation.pipeline.ReadingPipeline`)
decides which readings become steps, so the batch path and the node agree on what is
dropped (the steps of a burst of outlier stamps it discards are taken back); the
steps are geometry-free joint angle increments, so any geometry can be integrated
from them with numpy (``kinematics.body_increment`` on arrays,
``integration.integrate_batch``): the cheap half that calibration repeats in its
fitting loop. The step's math stays in those two functions.
"""

from __future__ import annotations

from array import array
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass
from typing import Protocol

import numpy as np
import numpy.typing as npt

from diffdrive_odom.core.bulk import fastlane
from diffdrive_odom.core.bulk.readings import JointBlock
from diffdrive_odom.core.estimation.config import OdometrySettings
from diffdrive_odom.core.estimation.pipeline import ReadingPipeline
from diffdrive_odom.core.estimation.results import Outcome
from diffdrive_odom.core.estimation.wheels.encoders import Reason
from diffdrive_odom.core.estimation.wheels.timeline import Status
from diffdrive_odom.core.geometry.integration import Pose2D, integrate_batch
from diffdrive_odom.core.geometry.kinematics import Geometry, body_increment
from diffdrive_odom.core.geometry.se2 import wrap_angle

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]


class GyroSample(Protocol):
    """One IMU sample as :meth:`ReadingPipeline.feed_imu` takes it (``use_imu``)."""

    @property
    def stamp_ns(self) -> int:
        """Header stamp [ns]."""

    @property
    def wx(self) -> float:
        """Angular velocity about the IMU's x axis [rad/s] (y, z alike)."""

    @property
    def wy(self) -> float:
        """About y [rad/s]."""

    @property
    def wz(self) -> float:
        """About z [rad/s]."""


@dataclass(frozen=True)
class WheelSteps:
    """A run's accepted steps, geometry-free: joint angle increments per side.

    ``segment`` numbers the runs between restarts (a stamp jump back starts the pose
    over at the origin); ``segments`` counts them, so a restart with no step after it
    is still known. ``slip_spans``: with the gyro (``use_imu`` and IMU samples), each
    slip event's (stamp of its first step, stamp of its last step) by the node's rule
    (:mod:`~diffdrive_odom.core.estimation.gyro.slips`), ``slip_events`` how many there were
    (more than the spans kept when over ``slips.MAX_EVENTS``); None: no gyro judged.
    ``skipped``: the readings the rules did not integrate, by reason code: how many and
    the first one's words (``too_fast``: a step skipped, its motion lost), so a tool
    that fits these steps can say what they leave out.
    """

    stamp_ns: IntArray  # stamp of the reading that ends each step
    dt: FloatArray
    d_left: FloatArray
    d_right: FloatArray
    segment: IntArray
    segments: int
    slip_spans: tuple[tuple[int, int], ...] | None = None
    slip_events: int = 0
    skipped: tuple[tuple[str, int, str], ...] = ()  # (code, readings, the first's words)

    def __len__(self) -> int:
        return len(self.dt)


def wheel_steps(readings: Iterable[fastlane.Reading | JointBlock | GyroSample],
                settings: OdometrySettings) -> WheelSteps:
    """Decode readings once into the steps the estimator integrates (as the pipeline decides).

    With ``use_imu`` the IMU samples among ``readings`` (in stamp order, as replay
    merges them) go to the gyro, every reading through the pipeline one by one, and
    the slip events it found come back in ``slip_spans``; otherwise samples are ignored.
    """
    pipe = ReadingPipeline(settings)
    est = pipe.estimator
    stamps, dts, lefts, rights, segs = array("q"), array("d"), array("d"), array("d"), array("q")
    segments = 0
    skipped: dict[str, tuple[int, str]] = {}
    trial_start = 0  # steps before the timeline on trial (estimator.on_trial) began
    on_trial = False
    # The fast lane (core.bulk.fastlane): its stretches are plain steps, never on trial.
    items = (_one_by_one(pipe, readings) if settings.gyro is not None
             else fastlane.lanes(pipe, _wheels(readings), receive=False))
    for item in items:
        if isinstance(item, fastlane.Stretch):
            header, dt, left, right = item.steps
            stamps.extend(header.tolist())
            dts.extend(dt.tolist())
            lefts.extend(left.tolist())
            rights.extend(right.tolist())
            segs.extend([segments - 1] * item.count)
            continue
        r, outcome = item
        verdict = outcome.verdict
        status = verdict.status
        if verdict.code not in (Reason.UPDATED, Reason.FIRST):
            n, said = skipped.get(verdict.code, (0, verdict.reason))
            skipped[verdict.code] = (n + verdict.count, said)
        if on_trial != est.on_trial:
            if not on_trial:  # this reading's step starts the trial
                trial_start = len(dts)
            elif verdict.code is Reason.FUTURE_STAMP:  # discarded: so are its steps
                for column in (stamps, dts, lefts, rights, segs):
                    del column[trial_start:]
        if verdict.code is Reason.GAP_INTEGRATED and est.last_gap is not None:
            end, gap = est.last_gap  # the gap's own step, before the one after it
            stamps.append(end)
            dts.append(gap.dt)
            lefts.append(gap.d_left)
            rights.append(gap.d_right)
            segs.append(segments - 1)
        if status is Status.UPDATED:
            inc = est.last_increment
            assert inc is not None  # set by every UPDATED step
            stamps.append(r.stamp_ns)
            dts.append(inc.dt)
            lefts.append(inc.d_left)
            rights.append(inc.d_right)
            segs.append(segments - 1)
        elif status is Status.TIME_RESET or (status is Status.REFERENCE and segments == 0):
            segments += 1
        on_trial = est.on_trial
    gyro = pipe.gyro
    return WheelSteps(
        np.frombuffer(stamps, dtype=np.int64).copy(),
        np.frombuffer(dts, dtype=np.float64).copy(),
        np.frombuffer(lefts, dtype=np.float64).copy(),
        np.frombuffer(rights, dtype=np.float64).copy(),
        np.frombuffer(segs, dtype=np.int64).copy(),
        segments,
        None if gyro is None else tuple(gyro.slip_spans),
        0 if gyro is None else gyro.slips.events,
        tuple((code, n, said) for code, (n, said) in skipped.items()),
    )


def _is_gyro(item: object) -> bool:
    return hasattr(item, "wz")


def _wheels(readings: Iterable[fastlane.Reading | JointBlock | GyroSample]
            ) -> Iterator[fastlane.Reading | JointBlock]:
    """The wheel readings alone (no gyro: its samples have nothing to do)."""
    for item in readings:
        if not _is_gyro(item):
            yield item  # type: ignore[misc]


def _one_by_one(pipe: ReadingPipeline,
                readings: Iterable[fastlane.Reading | JointBlock | GyroSample]
                ) -> Iterator[tuple[fastlane.Reading, Outcome]]:
    """Every reading through the pipeline, each IMU sample to the gyro (as replay does)."""
    for item in readings:
        if _is_gyro(item):
            g: GyroSample = item  # type: ignore[assignment]
            pipe.feed_imu(g.stamp_ns, g.wx, g.wy, g.wz,
                          covariance=getattr(g, "covariance", ()))
            continue
        block: Sequence[fastlane.Reading] = (
            item if isinstance(item, JointBlock) else (item,))  # type: ignore[assignment]
        for r in block:
            yield r, pipe.feed(r.stamp_ns, r.names, r.position, r.velocity)


def integrate_steps(
    steps: WheelSteps, geometry: Geometry
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Pose after every step for ``geometry``: ``x, y, theta`` (theta continuous per segment)."""
    ds, dtheta = body_increment(geometry, steps.d_left, steps.d_right)
    if steps.segments <= 1:
        return integrate_batch(ds, dtheta)
    x, y, th = (np.empty(len(steps)) for _ in range(3))
    bounds = np.flatnonzero(np.diff(steps.segment)) + 1
    for lo, hi in zip(
        np.concatenate(([0], bounds)), np.concatenate((bounds, [len(steps)])), strict=True
    ):
        x[lo:hi], y[lo:hi], th[lo:hi] = integrate_batch(ds[lo:hi], dtheta[lo:hi])
    return x, y, th


def final_pose(steps: WheelSteps, geometry: Geometry) -> Pose2D:
    """Where the batch path ends (the origin if the last segment has no step)."""
    if len(steps) == 0 or steps.segment[-1] != steps.segments - 1:
        return Pose2D()
    x, y, th = integrate_steps(steps, geometry)
    return Pose2D(float(x[-1]), float(y[-1]), wrap_angle(float(th[-1])))
