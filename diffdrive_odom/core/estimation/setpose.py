"""``~/set_pose``: overwrite the odometry's pose and covariance, at a reading's stamp.

The rule, in one place for the wheels' estimator (the node, both kinds, and anything else
that feeds the :class:`~diffdrive_odom.core.estimation.pipeline.ReadingPipeline`) and for
open loop (:mod:`~diffdrive_odom.core.estimation.open_loop`), typed against what it sets
a pose on (:class:`PoseHolder`), not either of them:

- a request is checked first (:func:`check_request`): its frame must be the odom frame
  (the pose is *in* odom: a pose in map is not one here until transformed), its
  position and quaternion finite, the quaternion of unit length (tf2's tolerance,
  ``|q|^2`` within :data:`UNIT_TOLERANCE` of 1), its 6x6 covariance finite, symmetric
  and positive semidefinite; else it is refused with a reason and nothing changes;
- a pose stamped at or before the last integrated reading (or stamped zero: "now") is
  taken as the pose *at that reading*: nothing is re-integrated, the readings since its
  stamp are not replayed onto it;
- one stamped ahead of the last reading is held until a reading reaches its stamp, and
  is then the pose at that reading (a newer request replaces a held one; a reset or a
  time reset drops it);
- the planar part is taken: x, y and the yaw of the quaternion, and the (x, y, yaw)
  block of the covariance; z, roll and pitch are ignored. With ``covariance_model:
  propagated`` that block is the new covariance (the geometry and gyro-bias terms start
  again from zero: the given covariance holds all there is); with ``static`` the
  published covariance stays the configured diagonal.

The jump this makes in the odom frame is the user's request (REP-105 wants odom
continuous; a set pose is a deliberate exception, as the reset service is). Pure Python
with numpy for the covariance check.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Protocol

import numpy as np
import numpy.typing as npt

from diffdrive_odom.core.geometry.integration import Pose2D
from diffdrive_odom.core.geometry.mat3 import Matrix

UNIT_TOLERANCE = 1e-2  # tf2's QUATERNION_NORMALIZATION_TOLERANCE, on |q|^2
PLANAR = (0, 1, 5)  # x, y, yaw in a 6x6 pose covariance


@dataclass(frozen=True, slots=True)
class PoseRequest:
    """A PoseWithCovarianceStamped's fields, as the node receives them."""

    stamp_ns: int
    frame_id: str
    position: tuple[float, float, float]
    orientation: tuple[float, float, float, float]  # x, y, z, w
    covariance: Sequence[float]  # 6x6 row-major (x, y, z, roll, pitch, yaw)


@dataclass(frozen=True, slots=True)
class PoseSet:
    """An accepted request: the planar pose, its 3x3 covariance, its stamp (0: now)."""

    stamp_ns: int
    pose: Pose2D
    covariance: Matrix


@dataclass(frozen=True, slots=True)
class PoseRefusal:
    """Why a request is refused: ``code`` to throttle by, ``reason`` to say."""

    code: str
    reason: str


def check_request(req: PoseRequest, odom_frame: str) -> PoseSet | PoseRefusal:
    """The request as a pose to set, or why it cannot be one (see the module text)."""
    if req.frame_id != odom_frame:
        return PoseRefusal("frame", f"frame_id '{req.frame_id}' is not the odom frame "
                           f"'{odom_frame}': set_pose takes a pose in {odom_frame} (transform "
                           "it first)")
    if req.stamp_ns < 0:
        return PoseRefusal("stamp", f"negative stamp ({req.stamp_ns} ns)")
    q = req.orientation
    if not all(math.isfinite(v) for v in (*req.position, *q)):
        return PoseRefusal("non_finite", f"position {req.position} or orientation {q} is not "
                           "finite")
    norm2 = sum(v * v for v in q)
    if abs(norm2 - 1.0) > UNIT_TOLERANCE:
        return PoseRefusal("quaternion", f"orientation {q} is not a unit quaternion "
                           f"(|q|^2 = {norm2:.6g})")
    cov = np.asarray(req.covariance, dtype=np.float64)
    problem = _covariance_problem(cov)
    if problem:
        return PoseRefusal("covariance", problem)
    x, y, z, w = (v / math.sqrt(norm2) for v in q)
    yaw = math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
    c = cov.reshape(6, 6)[np.ix_(PLANAR, PLANAR)]
    block = tuple(tuple(float(v) for v in row) for row in c)
    return PoseSet(req.stamp_ns, Pose2D(req.position[0], req.position[1], yaw), block)


def _covariance_problem(cov: npt.NDArray[np.float64]) -> str:
    """'' for a usable 6x6 covariance, else what is wrong with it."""
    if cov.shape != (36,):
        return f"covariance has {cov.size} values, not 36"
    if not np.isfinite(cov).all():
        return "covariance is not finite"
    m = cov.reshape(6, 6)
    scale = float(np.abs(m).max())
    if float(np.abs(m - m.T).max()) > 1e-9 * scale:
        return "covariance is not symmetric"
    for part, name in ((m, "6x6"), (m[np.ix_(PLANAR, PLANAR)], "(x, y, yaw)")):
        eig = np.linalg.eigvalsh(part)
        if eig.min() < -1e-9 * max(float(np.abs(eig).max()), 1e-300):
            return (f"covariance is not positive semidefinite (its {name} part has eigenvalue "
                    f"{eig.min():.6g})")
    return ""


class PoseHolder(Protocol):
    """What a pose is set on: the wheels' estimator, or open loop's integrator."""

    @property
    def stamp_ns(self) -> int | None:
        """The time integrated to (None: nothing yet)."""

    @property
    def on_trial(self) -> bool:
        """A reading is being tried (its pose not yet the odometry's): nothing is set now."""

    def place(self, pose: Pose2D, covariance: Matrix) -> None:
        """Overwrite the pose (and a propagated covariance) where it stands."""


class SetPoseRule:
    """The held request, and when a request takes effect (see the module text).

    Named in the log: ``now``, where the odometry stands ("the last reading" for the
    wheels, "the time integrated to" for open loop); ``ahead``, what reaches a held stamp
    ("a reading", "the clock").
    """

    def __init__(self, now: str = "the last reading", ahead: str = "a reading") -> None:
        self.pending: PoseSet | None = None
        self.now, self.ahead = now, ahead

    def offer(self, accepted: PoseSet, holder: PoseHolder, static: bool) -> str:
        """Set the pose now or hold it; returns the line that names it in the log."""
        last = holder.stamp_ns
        x, y, th = accepted.pose.x, accepted.pose.y, accepted.pose.theta
        what = (f"set_pose: x={x:.6g} m, y={y:.6g} m, yaw={th:.6g} rad"
                + (" (covariance_model static: the covariance stays the configured diagonal)"
                   if static else " with its covariance"))
        if last is not None and accepted.stamp_ns <= last and not holder.on_trial:
            self.pending = None
            holder.place(accepted.pose, accepted.covariance)
            return f"{what}, as the pose at {self.now} (stamped {_s(last)})"
        self.pending = accepted
        when = (f"stamped {_s(accepted.stamp_ns)}" if accepted.stamp_ns else "the next reading")
        return f"{what}, held until {self.ahead} reaches its stamp ({when})"

    def due(self, stamp_ns: int, holder: PoseHolder) -> PoseSet | None:
        """The held request ``stamp_ns`` reaches (taken off hold), None if none is due."""
        held = self.pending
        if held is None or stamp_ns < held.stamp_ns or holder.on_trial:
            return None
        self.pending = None
        return held

    def reached(self, stamp_ns: int, holder: PoseHolder) -> bool:
        """After a usable reading: set the held pose if this reading reached its stamp."""
        held = self.due(stamp_ns, holder)
        if held is not None:
            holder.place(held.pose, held.covariance)
        return held is not None


def _s(ns: int) -> str:
    return f"{ns // 1_000_000_000}.{ns % 1_000_000_000:09d}"
