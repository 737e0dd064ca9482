"""A recorded run as calibration reads it, and the geometry as the three values it fits.

Pure Python + numpy, shared by the fit (:mod:`diffdrive_odom.core.evaluation.calibration`) and
UMBmark (:mod:`diffdrive_odom.core.evaluation.umbmark`): each run is decoded once into
geometry-free wheel increments (:mod:`diffdrive_odom.core.bulk.batch`) and re-integrated
for any geometry with the estimator's own step.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from diffdrive_odom.core.bulk.batch import WheelSteps, integrate_steps
from diffdrive_odom.core.evaluation.metrics import Trajectory
from diffdrive_odom.core.geometry.kinematics import Geometry

FloatArray = npt.NDArray[np.float64]


class CalibrationError(ValueError):
    """A run that cannot be used for calibration (says which and why)."""


@dataclass(frozen=True)
class Run:
    """One recorded run: its wheel increments and, for the fit, a reference."""

    name: str
    steps: WheelSteps
    reference: Trajectory | None = None


def with_values(nominal: Geometry, left_radius: float, right_radius: float,
                separation: float) -> Geometry:
    """``nominal`` with effective radii and separation set, as multipliers of its nominals.

    The node's own parameters: ``wheel_radius`` and ``wheel_separation`` stay, the
    multipliers carry the calibration (diff_drive_controller's split).
    """
    return dataclasses.replace(
        nominal,
        left_wheel_radius_multiplier=left_radius / nominal.wheel_radius,
        right_wheel_radius_multiplier=right_radius / nominal.wheel_radius,
        wheel_separation_multiplier=separation / nominal.wheel_separation,
    )


def values_of(geometry: Geometry) -> FloatArray:
    """``(left radius, right radius, separation)`` in metres."""
    return np.array([geometry.left_radius, geometry.right_radius, geometry.separation])


def start_stamp(steps: WheelSteps) -> int:
    """Stamp of the reading before the first step: where the odometry is at the origin."""
    return int(steps.stamp_ns[0]) - round(float(steps.dt[0]) * 1e9)


def trajectory(run: Run, geometry: Geometry) -> Trajectory:
    """The odometry of ``run`` for ``geometry``: the origin at the start, then each step."""
    x, y, th = integrate_steps(run.steps, geometry)
    zero = np.zeros(1)
    return Trajectory(np.concatenate(([start_stamp(run.steps)], run.steps.stamp_ns)),
                      np.concatenate((zero, x)), np.concatenate((zero, y)),
                      np.concatenate((zero, th)))


def single_segment(run: Run) -> None:
    """Raise CalibrationError unless ``run`` is one segment of at least 2 readings."""
    if len(run.steps) < 2:
        raise CalibrationError(f"{run.name}: fewer than 2 usable readings")
    if run.steps.segments > 1:
        raise CalibrationError(
            f"{run.name}: the stamps jump back ({run.steps.segments} segments); "
            "calibrate each part as its own run")
