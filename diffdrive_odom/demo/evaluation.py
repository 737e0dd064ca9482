"""The demo's evaluation: calibrate from the run, replay it, each geometry's row.

Pure (numpy, scipy; no rclpy, no bag): the package's own calibration
(:mod:`diffdrive_odom.core.evaluation.calibration`, the whole-trajectory fit against
the sim's ground truth, and Borenstein and Feng's UMBmark from the two squares' end
poses), each geometry re-integrated through the batch path
(:mod:`diffdrive_odom.core.bulk.batch`, the estimator's own step) and compared with the
truth; the recorded readings replayed through the node's
:class:`~diffdrive_odom.core.estimation.pipeline.ReadingPipeline` wheels only and with
the recorded gyro. With the gyro the calibration leaves out the steps of the slip
events it finds, as ``calibrate`` does (:mod:`diffdrive_odom.core.evaluation.leftout`).
The rows and the table: :mod:`.report`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace
from itertools import pairwise
from typing import Any

import numpy as np

from diffdrive_odom.core.bulk import batch
from diffdrive_odom.core.estimation.config import OdometrySettings
from diffdrive_odom.core.estimation.online.online_estimate import OnlineEstimate
from diffdrive_odom.core.estimation.online.ratios import multipliers
from diffdrive_odom.core.estimation.pipeline import ReadingPipeline
from diffdrive_odom.core.estimation.wheels.timeline import Status
from diffdrive_odom.core.evaluation import calibration, leftout
from diffdrive_odom.core.evaluation.metrics import Trajectory, evaluate
from diffdrive_odom.core.evaluation.recorded_run import (
    CalibrationError,
    Run,
    trajectory,
    with_values,
)
from diffdrive_odom.core.evaluation.umbmark import reference_end, umbmark
from diffdrive_odom.core.geometry.kinematics import Geometry
from diffdrive_odom.core.motion.paths import Point

from .report import (
    FIT,
    GYRO,
    NOMINAL,
    TRUE,
    UMBMARK,
    WHEELS,
    ImuReading,
    JointSample,
    Recording,
    Row,
)
from .settings import DemoError

# --- calibration and evaluation -----------------------------------------------------


def _row(geometry: Geometry, est: Trajectory, truth: Trajectory,
         bridged: Trajectory | None = None) -> Row:
    m = evaluate(est, truth)
    b = None if bridged is None else evaluate(bridged, truth)
    return Row((geometry.left_radius, geometry.right_radius, geometry.separation),
               m.final_position_error_m, m.final_heading_error_rad,
               (float(est.x[-1]), float(est.y[-1]), float(est.yaw[-1])),
               None if b is None else b.final_position_error_m,
               None if b is None else b.final_heading_error_rad)


def merged(readings: Sequence[JointSample], imu: Sequence[ImuReading] = ()
           ) -> list[JointSample | ImuReading]:
    """Readings and IMU samples in stamp order, a sample before a reading of its stamp.

    As replay's merge by stamp feeds them to the pipeline.
    """
    items: list[JointSample | ImuReading] = [*imu, *readings]
    items.sort(key=lambda r: (r.stamp_ns, isinstance(r, JointSample)))
    return items


def _run(name: str, readings: Sequence[JointSample], odo: OdometrySettings,
         truth: Trajectory, imu: Sequence[ImuReading] = (),
         span: tuple[int, int] | None = None) -> Run:
    """The readings (inside ``span``) decoded once into the estimator's wheel steps.

    With ``odo.gyro`` the IMU samples go in too, and the gyro judges each step for slip.
    """
    def inside(t: int, before: int = 0) -> bool:
        return span is None or span[0] - before <= t <= span[1]

    chosen = [r for r in readings if inside(r.stamp_ns)]
    samples = [s for s in imu if inside(s.stamp_ns, 10**9)] if odo.gyro is not None else []
    return Run(name, batch.wheel_steps(merged(chosen, samples), odo), truth)


def distance_to_polyline(xy: np.ndarray[Any, Any], points: Sequence[Point]) -> np.ndarray[
        Any, Any]:
    """Each point's distance to the nearest segment of the polyline through ``points``."""
    best = np.full(len(xy), np.inf)
    for a, b in pairwise(points):
        ab = np.subtract(b, a)
        t = np.clip(((xy - a) @ ab) / float(ab @ ab), 0.0, 1.0)
        best = np.minimum(best, np.hypot(*(xy - (a + t[:, None] * ab)).T))
    return best


def _within_truth(rec: Recording) -> list[JointSample]:
    """The readings by stamp from the truth's first one on.

    The recorder may hear the encoders a moment before the ground truth (each topic
    is matched on its own): odometry started earlier could not be compared from its
    start.
    """
    t0 = int(rec.truth.stamp_ns[0]) if len(rec.truth) else 0
    return sorted((r for r in rec.joint_states if r.stamp_ns >= t0), key=lambda r: r.stamp_ns)


@dataclass(frozen=True)
class Calibrated:
    """:func:`calibrate_rows`' result: rows, the paths to draw, what was left out.

    ``paths``: the calibrated geometries with the slip steps bridged by the truth
    where the gyro found slips (what the geometry alone does), the nominal one the
    node's own odometry; ``left_out``: (slip events, steps left out, steps in all),
    None without the gyro.
    """

    rows: dict[str, Row]
    paths: dict[str, Trajectory]
    left_out: tuple[int, int, int] | None


def calibrate_rows(rec: Recording, odo: OdometrySettings, true: Geometry, side: float,
                   gyro: OdometrySettings | None = None) -> Calibrated:
    """Calibrate from the run: each geometry's row and its re-integrated trajectory.

    The nominal row is the node's own published odometry; the others re-integrate
    the whole run's wheel steps with their geometry. ``gyro``: the node's settings
    with ``use_imu``; with IMU samples recorded the slip steps it finds are left out
    of the fit and UMBmark, as ``calibrate`` leaves them out.
    """
    if len(rec.odom) < 2 or len(rec.truth) < 2 or len(rec.joint_states) < 3:
        raise DemoError("too little data to evaluate")
    nominal = odo.geometry
    judge = odo if gyro is None or gyro.gyro is None or not rec.imu else replace(
        gyro, online=None)
    readings = _within_truth(rec)
    whole = _run("demo", readings, judge, rec.truth, rec.imu)
    try:
        # the sim's truth is base_link's own pose: its mount is given, on the axle
        fitted = calibration.fit([whole], nominal, mount=calibration.ON_AXLE,
                                 figures=False).geometry
        found = {FIT: fitted}
        cw = [s for s in rec.squares if s.clockwise]
        ccw = [s for s in rec.squares if not s.clockwise]
        if cw and ccw:
            # Inside the truth's span: UMBmark needs the true pose at both ends.
            t0, t1 = int(rec.truth.stamp_ns[0]), int(rec.truth.stamp_ns[-1])
            runs = [_run(name, readings, judge, rec.truth, rec.imu,
                         (max(s.start_ns, t0), min(s.end_ns, t1)))
                    for name, s in (("cw", cw[0]), ("ccw", ccw[0]))]
            ends = [reference_end(r, rec.truth) for r in runs]
            found[UMBMARK] = umbmark(runs[0], runs[1], ends[0], ends[1],
                                     side=side, nominal=nominal).geometry
    except CalibrationError as err:
        raise DemoError(f"calibration failed: {err}") from err
    found[TRUE] = with_values(nominal, true.left_radius, true.right_radius,
                              true.separation)
    lo = leftout.left_out(whole, nominal)
    spans = () if lo is None else lo.bridges
    bridged = {k: leftout.trajectory(whole, g, spans) for k, g in
               (*found.items(), (NOMINAL, nominal))} if spans else {}
    paths = {NOMINAL: rec.odom}
    paths.update({k: trajectory(whole, g) for k, g in found.items()})
    rows = {k: _row(nominal if k == NOMINAL else found[k], t, rec.truth, bridged.get(k))
            for k, t in paths.items()}
    paths.update({k: t for k, t in bridged.items() if k != NOMINAL})
    return Calibrated(rows, paths, None if lo is None else (lo.events, lo.steps, len(whole.steps)))


@dataclass(frozen=True)
class Replayed:
    """One replay: the pose after each reading used, the slip events, the online trace."""

    trajectory: Trajectory
    slips: tuple[tuple[int, float], ...]
    online: list[tuple[int, OnlineEstimate]]


def replay(readings: Sequence[JointSample], odo: OdometrySettings,
           imu: Sequence[ImuReading] = ()) -> Replayed:
    """The recorded readings through the node's pipeline: its pose after each, and slips.

    With ``odo.gyro`` set (``use_imu``) the IMU samples go in through
    :meth:`ReadingPipeline.feed_imu` in stamp order, each before a wheel reading of the
    same or a later stamp (as replay's merge by stamp feeds them). Returns the pose
    after every reading the estimator used, each slip event the gyrodometry found
    (the stamp of its first step, the heading the wheels got wrong over it [rad]), by
    the one rule the node and ``replay`` count with (:mod:`~.gyro.slips`),
    and the online geometry estimate's trace (``online_calibration: monitor``; [] if off).
    """
    pipe = ReadingPipeline(odo, trace=True)
    stamps: list[int] = []
    poses: list[tuple[float, float, float]] = []
    for item in merged(readings, imu if odo.gyro is not None else ()):
        if isinstance(item, ImuReading):
            pipe.feed_imu(item.stamp_ns, item.wx, item.wy, item.wz)
            continue
        verdict = pipe.feed(item.stamp_ns, item.names, item.position, item.velocity).verdict
        if verdict.status in (Status.DROPPED, Status.HELD):
            continue
        p = pipe.estimator.pose
        stamps.append(item.stamp_ns)
        poses.append((p.x, p.y, p.theta))
    if len(stamps) < 2:
        raise DemoError("too little data to replay")
    x, y, th = zip(*poses, strict=True)
    slips = () if pipe.gyro is None else tuple(pipe.gyro.slip_events)
    online = [] if pipe.online is None else list(pipe.online.trace)
    return Replayed(Trajectory.from_arrays(stamps, x, y, th), slips, online)


def replay_rows(rec: Recording, odo: OdometrySettings, gyro: OdometrySettings
                ) -> tuple[dict[str, Row], dict[str, Trajectory], Replayed | None]:
    """The wheels-only and (with IMU samples recorded) gyro-aided replays' rows and paths.

    ``gyro``: the node's settings with ``use_imu`` true. Returns the rows, the
    trajectories and the gyro-aided replay (its slip events and online estimate).
    """
    readings = _within_truth(rec)
    paths = {WHEELS: replay(readings, odo).trajectory}
    aided = None
    if rec.imu and gyro.gyro is not None:
        aided = replay(readings, gyro, rec.imu)
        paths[GYRO] = aided.trajectory
    rows = {k: _row(odo.geometry, t, rec.truth) for k, t in paths.items()}
    return rows, paths, aided


def true_multipliers(nominal: Geometry, true: Geometry) -> tuple[float, float, float]:
    """The true geometry as the online estimate gives it: multipliers, mean radius held.

    The gyro sees the two ratios ``r/b`` only: the true ones, through the estimate's own
    mapping (:func:`~diffdrive_odom.core.estimation.online.ratios.multipliers`).
    """
    b = true.separation
    values, _ = multipliers(nominal, (true.right_radius / b, true.left_radius / b),
                            (0.0, 0.0, 0.0, 0.0))
    return values
