"""What the demo measured and prints: the rows, the table, ``results.json``. Pure.

The recorder (:mod:`.loop`) hands over what it heard (:class:`Recording`); the
calibration and the replays that fill the rows are :mod:`.evaluation`. Each row says
where its geometry ends with every recorded wheel step and, where the gyro found slips,
with those steps bridged by the truth (what the geometry alone does); the gyro-aided
replay's online geometry estimate is printed below.
"""

from __future__ import annotations

import math
import textwrap
from dataclasses import dataclass
from typing import Any, NamedTuple

from diffdrive_odom.core.estimation.gyro.config import GyroConfig
from diffdrive_odom.core.estimation.online.online_estimate import OnlineEstimate
from diffdrive_odom.core.evaluation.metrics import Trajectory
from diffdrive_odom.core.motion.paths import Point

# Table rows, in the order printed; the keys of ``results.json``'s "rows".
NOMINAL, FIT, UMBMARK, TRUE = "nominal", "fit", "umbmark", "true"
WHEELS, GYRO = "wheels", "gyro"  # the replays: nominal geometry, without and with the gyro
# Smaller slips are no slip events (the one rule: core.estimation.gyro.slips, slip_min_angle).
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
    position_m: float  # every wheel step integrated (slips included)
    heading_rad: float
    final_pose: tuple[float, float, float]
    # The same geometry with the slip steps bridged by the truth (None: no slip left out).
    left_out_position_m: float | None = None
    left_out_heading_rad: float | None = None

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready."""
        left, right, sep = self.geometry
        return {"left_radius": left, "right_radius": right, "separation": sep,
                "final_position_error_m": self.position_m,
                "final_heading_error_rad": self.heading_rad,
                "final_pose": list(self.final_pose),
                "slips_left_out": None if self.left_out_position_m is None else {
                    "final_position_error_m": self.left_out_position_m,
                    "final_heading_error_rad": self.left_out_heading_rad}}


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
    # What the calibration left out: (slip events, steps, steps in all); None: no gyro.
    left_out: tuple[int, int, int] | None = None
    online: OnlineEstimate | None = None  # the gyro-aided replay's at the end
    true_multipliers: tuple[float, float, float] | None = None  # the same convention

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
            "calibration_left_out": None if self.left_out is None else dict(zip(
                ("slip_events", "steps", "steps_in_all"), self.left_out, strict=True)),
            "online_estimate": None if self.online is None else {
                "multipliers": list(self.online.multipliers),
                "stddevs": list(self.online.stddevs), "determined": self.online.determined,
                "true_multipliers": None if self.true_multipliers is None
                else list(self.true_multipliers)},
        }

    def table(self, program: str = "diffdrive-odom") -> str:
        """The table the demo prints: each geometry's values and its error at the end.

        ``program``: how to run diffdrive-odom from here, for the closing hint.
        """
        kinds = "CW then CCW" if len(self.squares) == 2 else (
            "CW" if self.squares[0].clockwise else "CCW")
        lines = [
            f"{self.route} ({self.side_m:g} m squares, {kinds}), path_follower_node on the "
            f"odometry: {self.distance_m:.2f} m driven in {self.sim_seconds:.0f} s of "
            "simulated time",
            f"follower: cross-track error <= {100 * self.cross_track_odom_m:.1f} cm on the "
            f"odometry; ground truth within {100 * self.cross_track_truth_m:.1f} cm of the "
            "commanded path",
            "",
            *self.grid(),
        ]
        lines.append("(percentages: against the sim's true geometry; UMBmark keeps the "
                     "nominal mean wheel radius, a closed square cannot see the scale)")
        if GYRO in self.rows:
            t0 = self.squares[0].start_ns
            at = ", ".join(f"{(t - t0) * 1e-9:.1f} s ({math.degrees(a):.1f} deg)"
                           for t, a in self.slips)
            lines.append(f"wheel slip over {math.degrees(MIN_SLIP_RAD):g} deg: the gyro-aided "
                         f"replay found {len(self.slips)}"
                         + (f", at {at} into the route" if at else ""))
        lines += self._meaning()
        if self.plot or self.bag:
            lines.append("")
        if self.plot:
            lines.append(f"plot: {self.plot}")
        if self.bag:
            lines.append(f"bag:  {self.bag}  (try: {program} eval {self.bag})")
        return "\n".join(lines)

    def grid(self, keys: tuple[str, ...] = (NOMINAL, FIT, UMBMARK, TRUE, WHEELS, GYRO)
             ) -> list[str]:
        """The table's header and the rows of ``keys`` (those of the run), as printed."""
        true = self.rows[TRUE].geometry

        def value(v: float, t: float) -> str:
            return f"{v:.5f} ({100.0 * (v / t - 1.0):+.2f}%)"

        def error(position: float | None, heading: float | None) -> str:
            if position is None or heading is None:
                return f"{'-':>21} {'-':>14}"
            share = 100.0 * position / self.distance_m if self.distance_m > 0 else math.nan
            return f"{position:>9.4f} m ({share:5.2f} %) {math.degrees(heading):>10.3f} deg"

        gone = self.left_out is not None
        lines = [
            f"{'':<32} {'':>17} {'':>17} {'':>17} {'end error, every wheel step':>36}"
            + (f" {'end error, slip steps left out':>36}" if gone else ""),
            f"{'geometry':<32} {'r_left [m]':>17} {'r_right [m]':>17} {'b [m]':>17} "
            f"{'position':>21} {'heading':>14}"
            + (f" {'position':>21} {'heading':>14}" if gone else ""),
        ]
        for key in keys:
            row = self.rows.get(key)
            if row is None:
                continue
            left, right, sep = row.geometry
            lines.append(
                f"{LABELS[key]:<32} {value(left, true[0]):>17} {value(right, true[1]):>17} "
                f"{value(sep, true[2]):>17} {error(row.position_m, row.heading_rad)}"
                + (f" {error(row.left_out_position_m, row.left_out_heading_rad)}"
                   if gone else ""))
        return lines

    def _meaning(self) -> list[str]:
        """What each column and row integrates, and the online estimate (wrapped)."""
        if self.left_out is not None:
            events, steps, total = self.left_out
            text = (f"Calibration left out the {steps} of {total} wheel steps of the {events} "
                    "slip event(s), found by the node's slip rule, as calibrate does. 'every "
                    "wheel step': the row's geometry over all recorded wheel steps (a slip "
                    "turns it by what the robot never turned, which no geometry undoes); "
                    "'slip steps left out': the same with those steps bridged by the truth's "
                    "motion: what the geometry alone does.")
        else:
            text = ("The fit and UMBmark take any slip's heading for geometry: no gyro was "
                    "recorded to find the slips.")
        text += (" Replays: the recorded readings through the node's pipeline with the "
                 "nominal geometry; the live odometry_node ran wheels only.")
        out = textwrap.wrap(text, 110)
        e = self.online
        if e is not None:
            cells = ", ".join(f"{name} {m:.5f} +- {sd:.5f}" for name, m, sd in zip(
                ("left", "right", "separation"), e.multipliers, e.stddevs, strict=True))
            truth = "" if self.true_multipliers is None else "; true: {}".format(
                ", ".join(f"{m:.5f}" for m in self.true_multipliers))
            state = "" if e.determined else "; not yet determined (turn both ways)"
            out += textwrap.wrap(
                "Online estimate (the gyro-aided replay, online_calibration: monitor; "
                f"multipliers, mean radius held): {cells}{truth}{state}", 110)
        return out
