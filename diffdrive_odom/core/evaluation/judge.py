"""The one judge of a geometry on a run: its whole trajectory against the reference, and its end.

Pure Python + numpy. ``calibrate``'s objective chooser, its held-out check and its verdict
all ask one question of a geometry on a run: how far is the odometry it integrates from
where the reference saw the robot? One figure answers it for all three (:func:`judgment`):

- the reference moved onto base_link by its mount
  (:meth:`~diffdrive_odom.core.geometry.mount.Mount.base_poses`), so where the reference
  is mounted does not change the figure;
- the odometry laid on it by the least-squares SE(2) fit of all matched positions
  (:func:`~diffdrive_odom.core.evaluation.metrics.align_best_fit`), not by the
  reference's start pose: one sample's heading (a marker body's, yawed on its mount, or
  half a degree off by its own noise) would turn the whole path with it;
- ``path``: the RMS position error over every matched stamp; it sees the scale (a circle
  or a square of the wrong size lies off its reference all along, though it may end
  where it started) and the turns;
- ``end``: the position error at the last matched stamp after the same fit, where a
  user reads a run's error;
- the figure, :attr:`Judgment.error`: ``sqrt((path^2 + end^2) / 2)``, the end counted
  as much as the whole path.

Steps a gyro flagged as slip are bridged by the reference's motion, as the fit leaves
them out (:mod:`~diffdrive_odom.core.evaluation.leftout`); ``bridged=False`` integrates
every step, as wheels-only replay does.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from diffdrive_odom.core.evaluation import leftout
from diffdrive_odom.core.evaluation.metrics import Trajectory, align_best_fit, match
from diffdrive_odom.core.evaluation.recorded_run import CalibrationError, Run, trajectory
from diffdrive_odom.core.geometry.kinematics import Geometry
from diffdrive_odom.core.geometry.mount import AXLE, Mount


@dataclass(frozen=True)
class Judgment:
    """A geometry's error on one run [m] (see the module)."""

    path: float  # RMS position error along the whole trajectory, best SE(2) fit
    end: float  # position error at the last matched stamp, the same fit
    samples: int
    left_out: int = 0  # wheel steps bridged by the reference (slips)

    @property
    def error(self) -> float:
        """The judge's figure: ``sqrt((path^2 + end^2) / 2)``."""
        return math.sqrt(0.5 * (self.path**2 + self.end**2))


NAME = "whole-trajectory error"  # how the figure is named where it is printed
DEFINITION = ("RMS of the position error along the whole path and at its end, after the best "
              "SE(2) fit, the reference moved onto base_link by its mount")


def base_reference(ref: Trajectory, mount: Mount) -> Trajectory:
    """The reference's poses as base_link's (``R M^-1``); the same trajectory on the axle."""
    if mount == AXLE:
        return ref
    poses = mount.base_poses(np.column_stack((ref.x, ref.y, ref.yaw)))
    return Trajectory(ref.stamp_ns, poses[:, 0], poses[:, 1], poses[:, 2])


def odometry(run: Run, geometry: Geometry, mount: Mount = AXLE, max_gap: float = 0.5,
             bridged: bool = True) -> tuple[Trajectory, int]:
    """The run's odometry for ``geometry``, its slips bridged (unless not ``bridged``).

    Returns the trajectory and the number of steps the bridges replaced.
    """
    spans = leftout.bridges(run, max_gap) if bridged else ()
    if not spans:
        return trajectory(run, geometry), 0
    gone = int(leftout.replaced(spans, len(run.steps)).sum())
    return leftout.trajectory(run, geometry, spans, mount), gone


def judgment(run: Run, geometry: Geometry, mount: Mount = AXLE, max_gap: float = 0.5,
          bridged: bool = True) -> Judgment:
    """``geometry`` on ``run`` against its reference mounted at ``mount`` (see the module)."""
    if run.reference is None:
        raise CalibrationError(f"{run.name}: no reference trajectory")
    est, gone = odometry(run, geometry, mount, max_gap, bridged)
    m = match(est, base_reference(run.reference, mount), max_gap)
    fitted = align_best_fit(m.est, m.ref) if len(m.est) >= 2 else m.est
    err = np.hypot(fitted[:, 0] - m.ref[:, 0], fitted[:, 1] - m.ref[:, 1])
    return Judgment(float(np.sqrt(np.mean(err**2))), float(err[-1]), len(err), gone)


def mean_error(judgments: Sequence[Judgment]) -> float:
    """The mean of the judge's figure over runs."""
    return float(np.mean([j.error for j in judgments]))
