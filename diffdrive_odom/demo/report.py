"""What the demo measured, calibrated and prints: pure (numpy, scipy; no rclpy, no bag).

The recorder (:mod:`.loop`) hands over what it heard; here the run is calibrated with
the package's own calibration (:mod:`diffdrive_odom.core.evaluation.calibration`: the
whole-trajectory
fit against the sim's ground truth, and Borenstein and Feng's UMBmark from the two
squares' end poses), each geometry is re-integrated through the batch path
(:mod:`diffdrive_odom.core.bulk.batch`, the estimator's own step) and compared with the truth.
The recorded readings are also replayed through the node's
:class:`~diffdrive_odom.core.estimation.pipeline.ReadingPipeline` twice, wheels only and with the
recorded gyro (``use_imu``, Borenstein and Feng, "Gyrodometry: A New Method for Combining
Data from Gyros and Odometry in Mobile Robots"), so the sim's scripted wheel slip shows
what the gyro saves.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from itertools import pairwise
from typing import Any, NamedTuple

import numpy as np

from diffdrive_odom.core.bulk import batch
from diffdrive_odom.core.estimation.config import OdometrySettings
from diffdrive_odom.core.estimation.gyro import GyroConfig
from diffdrive_odom.core.estimation.pipeline import ReadingPipeline
from diffdrive_odom.core.estimation.timeline import Status
from diffdrive_odom.core.evaluation import calibration
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

from .settings import DemoError

# Table rows, in the order printed; the keys of ``results.json``'s "rows".
NOMINAL, FIT, UMBMARK, TRUE = "nominal", "fit", "umbmark", "true"
WHEELS, GYRO = "wheels", "gyro"  # the replays: nominal geometry, without and with the gyro
# Smaller slips are no slip events (the one rule: core.estimation.slips, slip_min_angle).
MIN_SLIP_RAD = GyroConfig().slip_min_angle
LABELS = {
    NOMINAL: "nominal (odometry_node as run)",
    FIT: "calibrated: fit to ground truth",
    UMBMARK: "calibrated: UMBmark end poses",
    TRUE: "true geometry (the sim's)",
    WHEELS: "replay: wheels only",
    GYRO: "replay: gyro-aided (use_imu)",
}


class JointSample(NamedTuple):
    """One recorded JointState, as the batch path reads it (``fastlane.Reading``)."""

    stamp_ns: int
    names: tuple[str, ...]
    position: tuple[float, ...]
    velocity: tuple[float, ...]


class ImuReading(NamedTuple):
    """One recorded Imu's stamp and angular velocity (its own frame), as ``feed_imu`` takes it."""

    stamp_ns: int
    wx: float
    wy: float
    wz: float


@dataclass
class PoseSeries:
    """Poses by stamp as received (odometry or ground truth)."""

    stamp_ns: list[int] = field(default_factory=list)
    x: list[float] = field(default_factory=list)
    y: list[float] = field(default_factory=list)
    yaw: list[float] = field(default_factory=list)

    def add(self, stamp_ns: int, x: float, y: float, yaw: float) -> None:
        """Append one pose."""
        self.stamp_ns.append(stamp_ns)
        self.x.append(x)
        self.y.append(y)
        self.yaw.append(yaw)

    def trajectory(self) -> Trajectory:
        """As the metrics module's trajectory (sorted, unwrapped)."""
        return Trajectory.from_arrays(self.stamp_ns, self.x, self.y, self.yaw)


@dataclass(frozen=True)
class Square:
    """One square as driven: its direction, the corners sent, and its span [ns, sim time]."""

    clockwise: bool
    points: tuple[Point, ...]
    start_ns: int
    end_ns: int


@dataclass(frozen=True)
class Recording:
    """Everything the demo heard that the evaluation needs."""

    joint_states: tuple[JointSample, ...]
    odom: Trajectory
    truth: Trajectory
    squares: tuple[Square, ...]
    cross_track_odom_m: float  # largest |e1| the follower reported (on odometry)
    imu: tuple[ImuReading, ...] = ()  # the sim's gyro (empty: imu_rate 0)


@dataclass(frozen=True)
class Row:
    """One geometry's odometry against the ground truth at the end of the run."""

    geometry: tuple[float, float, float]  # left radius, right radius, separation [m]
    position_m: float
    heading_rad: float
    final_pose: tuple[float, float, float]

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready."""
        left, right, sep = self.geometry
        return {"left_radius": left, "right_radius": right, "separation": sep,
                "final_position_error_m": self.position_m,
                "final_heading_error_rad": self.heading_rad,
                "final_pose": list(self.final_pose)}


@dataclass(frozen=True)
class DemoResult:
    """What the demo measured; ``as_dict`` is written to ``results.json``."""

    route: str
    side_m: float
    distance_m: float
    sim_seconds: float
    wall_seconds: float
    truth_final_pose: tuple[float, float, float]
    rows: dict[str, Row]  # NOMINAL, FIT, TRUE, WHEELS; with both squares UMBMARK; GYRO
    cross_track_odom_m: float
    cross_track_truth_m: float
    squares: tuple[Square, ...]
    messages: dict[str, int]
    bag: str | None
    plot: str | None
    # The slip events the gyro-aided replay found: (stamp of the first step, size [rad]).
    slips: tuple[tuple[int, float], ...] = ()

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready."""
        return {
            "route": self.route, "side_m": self.side_m, "distance_m": self.distance_m,
            "sim_seconds": self.sim_seconds, "wall_seconds": self.wall_seconds,
            "truth_final_pose": list(self.truth_final_pose),
            "rows": {k: r.as_dict() for k, r in self.rows.items()},
            "follower": {"max_cross_track_error_odometry_m": self.cross_track_odom_m,
                         "max_distance_truth_to_path_m": self.cross_track_truth_m},
            "squares": [{"clockwise": s.clockwise, "points": [list(p) for p in s.points],
                         "start_ns": s.start_ns, "end_ns": s.end_ns} for s in self.squares],
            "messages": self.messages, "bag": self.bag, "plot": self.plot,
            "slip_events": [{"stamp_ns": t, "size_rad": a} for t, a in self.slips],
        }

    def table(self, program: str = "diffdrive-odom") -> str:
        """The table the demo prints: each geometry's values and its error at the end.

        ``program``: how to run diffdrive-odom from here, for the closing hint.
        """
        true = self.rows[TRUE].geometry

        def value(v: float, t: float) -> str:
            return f"{v:.5f} ({100.0 * (v / t - 1.0):+.2f}%)"

        kinds = "CW then CCW" if len(self.squares) == 2 else (
            "CW" if self.squares[0].clockwise else "CCW")
        lines = [
            f"{self.route} ({self.side_m:g} m squares, {kinds}), path_follower_node on the "
            f"odometry: {self.distance_m:.2f} m driven in {self.sim_seconds:.0f} s of "
            f"simulated time ({self.wall_seconds:.0f} s wall)",
            f"follower: cross-track error <= {100 * self.cross_track_odom_m:.1f} cm on the "
            f"odometry; ground truth within {100 * self.cross_track_truth_m:.1f} cm of the "
            "commanded path",
            "",
            f"{'geometry':<32} {'r_left [m]':>17} {'r_right [m]':>17} {'b [m]':>17} "
            f"{'final position error':>21} {'heading error':>14}",
        ]
        for key in (NOMINAL, FIT, UMBMARK, TRUE, WHEELS, GYRO):
            row = self.rows.get(key)
            if row is None:
                continue
            left, right, sep = row.geometry
            share = 100.0 * row.position_m / self.distance_m if self.distance_m > 0 else math.nan
            lines.append(
                f"{LABELS[key]:<32} {value(left, true[0]):>17} {value(right, true[1]):>17} "
                f"{value(sep, true[2]):>17} {row.position_m:>9.4f} m ({share:5.2f} %) "
                f"{math.degrees(row.heading_rad):>10.3f} deg")
        lines.append("(percentages: against the sim's true geometry; UMBmark keeps the "
                     "nominal mean wheel radius, a closed square cannot see the scale)")
        if GYRO in self.rows:
            t0 = self.squares[0].start_ns
            at = ", ".join(f"{(t - t0) * 1e-9:.1f} s ({math.degrees(a):.1f} deg)"
                           for t, a in self.slips)
            lines += [
                f"wheel slip over {math.degrees(MIN_SLIP_RAD):g} deg: the gyro-aided "
                f"replay found {len(self.slips)}" + (f", at {at} into the route" if at else "")
                + "; slip inflates the nominal and calibrated rows",
                "(the fit and UMBmark take its heading for geometry). Replays: the recorded "
                "readings through the node's pipeline with the nominal geometry; the live "
                "odometry_node ran wheels only.",
            ]
        if self.plot or self.bag:
            lines.append("")
        if self.plot:
            lines.append(f"plot: {self.plot}")
        if self.bag:
            lines.append(f"bag:  {self.bag}  (try: {program} eval {self.bag})")
        return "\n".join(lines)


# --- calibration and evaluation -----------------------------------------------------


def _row(geometry: Geometry, est: Trajectory, truth: Trajectory) -> Row:
    m = evaluate(est, truth)
    return Row((geometry.left_radius, geometry.right_radius, geometry.separation),
               m.final_position_error_m, m.final_heading_error_rad,
               (float(est.x[-1]), float(est.y[-1]), float(est.yaw[-1])))


def _run(name: str, readings: Sequence[JointSample], odo: OdometrySettings,
         truth: Trajectory, span: tuple[int, int] | None = None) -> Run:
    """The readings (inside ``span``) decoded once into the estimator's wheel steps."""
    chosen = [r for r in readings
              if span is None or span[0] <= r.stamp_ns <= span[1]]
    return Run(name, batch.wheel_steps(chosen, odo), truth)


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


def calibrate_rows(rec: Recording, odo: OdometrySettings, true: Geometry,
                   side: float) -> tuple[dict[str, Row], dict[str, Trajectory]]:
    """Calibrate from the run: each geometry's row and its re-integrated trajectory.

    The nominal row is the node's own published odometry; the others re-integrate
    the whole run's wheel steps with their geometry.
    """
    if len(rec.odom) < 2 or len(rec.truth) < 2 or len(rec.joint_states) < 3:
        raise DemoError("too little data to evaluate")
    nominal = odo.geometry
    readings = _within_truth(rec)
    whole = _run("demo", readings, odo, rec.truth)
    try:
        fitted = calibration.fit([whole], nominal, figures=False).geometry
        found = {FIT: fitted}
        cw = [s for s in rec.squares if s.clockwise]
        ccw = [s for s in rec.squares if not s.clockwise]
        if cw and ccw:
            # Inside the truth's span: UMBmark needs the true pose at both ends.
            t0, t1 = int(rec.truth.stamp_ns[0]), int(rec.truth.stamp_ns[-1])
            runs = [_run(name, readings, odo, rec.truth,
                         (max(s.start_ns, t0), min(s.end_ns, t1)))
                    for name, s in (("cw", cw[0]), ("ccw", ccw[0]))]
            ends = [reference_end(r, rec.truth) for r in runs]
            found[UMBMARK] = umbmark(runs[0], runs[1], ends[0], ends[1],
                                     side=side, nominal=nominal).geometry
    except CalibrationError as err:
        raise DemoError(f"calibration failed: {err}") from err
    found[TRUE] = with_values(nominal, true.left_radius, true.right_radius,
                              true.separation)
    paths = {NOMINAL: rec.odom}
    paths.update({k: trajectory(whole, g) for k, g in found.items()})
    rows = {k: _row(nominal if k == NOMINAL else found[k], t, rec.truth)
            for k, t in paths.items()}
    return rows, paths


def replay(readings: Sequence[JointSample], odo: OdometrySettings,
           imu: Sequence[ImuReading] = ()
           ) -> tuple[Trajectory, tuple[tuple[int, float], ...]]:
    """The recorded readings through the node's pipeline: its pose after each, and slips.

    With ``odo.gyro`` set (``use_imu``) the IMU samples go in through
    :meth:`ReadingPipeline.feed_imu` in stamp order, each before a wheel reading of the
    same or a later stamp (as replay's merge by stamp feeds them). Returns the pose
    after every reading the estimator used, and each slip event the gyrodometry found
    (the stamp of its first step, the heading the wheels got wrong over it [rad]), by
    the one rule the node and ``replay`` count with (:mod:`diffdrive_odom.core.estimation.slips`).
    """
    pipe = ReadingPipeline(odo)
    events: list[tuple[int, int, JointSample | ImuReading]] = [
        (s.stamp_ns, 0, s) for s in imu] if odo.gyro is not None else []
    events += [(r.stamp_ns, 1, r) for r in readings]
    events.sort(key=lambda e: (e[0], e[1]))
    stamps: list[int] = []
    poses: list[tuple[float, float, float]] = []
    for _, _, item in events:
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
    return Trajectory.from_arrays(stamps, x, y, th), slips


def replay_rows(rec: Recording, odo: OdometrySettings, gyro: OdometrySettings
                ) -> tuple[dict[str, Row], dict[str, Trajectory], tuple[tuple[int, float], ...]]:
    """The wheels-only and (with IMU samples recorded) gyro-aided replays' rows and paths.

    ``gyro``: the node's settings with ``use_imu`` true. Returns the rows, the
    trajectories and the slip events the gyro-aided replay found.
    """
    readings = _within_truth(rec)
    wheels, _ = replay(readings, odo)
    paths = {WHEELS: wheels}
    slips: tuple[tuple[int, float], ...] = ()
    if rec.imu and gyro.gyro is not None:
        paths[GYRO], slips = replay(readings, gyro, rec.imu)
    rows = {k: _row(odo.geometry, t, rec.truth) for k, t in paths.items()}
    return rows, paths, slips
