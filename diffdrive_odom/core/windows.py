"""A run cut into windows of wheel travel, and each window's relative-motion residual.

Pure Python + numpy: what the fit (:mod:`diffdrive_odom.core.calibration`) minimises
and the noise estimate (:mod:`diffdrive_odom.core.noise`) matches. Consecutive windows
share no step, so with wheel noise independent from step to step their residuals are
independent; a residual is the odometry's motion across a window, seen from its first
pose, minus the reference's (x, y and the heading error times half the separation:
all three in metres of wheel travel).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from diffdrive_odom.core.batch import integrate_steps
from diffdrive_odom.core.kinematics import Geometry, wheel_arcs
from diffdrive_odom.core.metrics import Trajectory, covered, interpolate
from diffdrive_odom.core.recorded_run import CalibrationError, Run, single_segment
from diffdrive_odom.core.se2 import between, conjugate, wrap_angles

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]


@dataclass(frozen=True)
class Windows:
    """A run's fixed data for the fit: matched steps, their reference, window bounds."""

    run: Run
    reference: Trajectory
    index: IntArray  # step indices with a reference pose
    start: IntArray  # window k spans index[start[k]] .. index[end[k]]
    end: IntArray

    def ref_at(self, lag: float) -> FloatArray:
        """(len(index), 3) reference poses at the steps' stamps plus ``lag`` s."""
        return interpolate(self.reference, self.run.steps.stamp_ns[self.index], lag)


def cut(run: Run, nominal: Geometry, window: float, max_gap: float) -> Windows:
    """Cut a run into consecutive windows of ``window`` m of wheel travel (nominal radii)."""
    single_segment(run)
    if run.reference is None:
        raise CalibrationError(f"{run.name}: no reference trajectory")
    index = np.flatnonzero(covered(run.reference, run.steps.stamp_ns, max_gap))
    if len(index) < 2:
        raise CalibrationError(f"{run.name}: the reference does not overlap the readings")
    s_left, s_right = wheel_arcs(nominal, run.steps.d_left, run.steps.d_right)
    travel = np.cumsum(0.5 * (np.abs(s_left) + np.abs(s_right)))[index]
    bounds = _quiet_bounds(travel - travel[0], window)
    if len(bounds) < 2:
        raise CalibrationError(
            f"{run.name}: the wheels rolled {travel[-1] - travel[0]:.3f} m, less than one "
            f"window ({window:g} m)")
    return Windows(run, run.reference, index, bounds[:-1], bounds[1:])


def _quiet_bounds(travel: FloatArray, window: float) -> IntArray:
    """Window bounds about every ``window`` m of travel, each moved to the stillest step.

    A bound is the step that moves least within half a window of its nominal place
    (the first such). At rest, a small offset between the reference's and the
    encoders' clocks changes no pose, so the residuals do not see it; in the middle
    of a turn it would.
    """
    step = np.diff(travel, prepend=travel[0])
    marks = np.arange(0.0, travel[-1], window)
    bounds: list[int] = []
    for mark in marks:
        lo = int(np.searchsorted(travel, mark - 0.5 * window, side="left"))
        hi = int(np.searchsorted(travel, mark + 0.5 * window, side="right"))
        lo = max(lo, bounds[-1] + 1 if bounds else 0)
        if lo >= hi:
            continue
        bounds.append(lo + int(np.argmin(step[lo:hi])))
    return np.asarray(bounds, dtype=np.int64)


def residuals(w: Windows, geometry: Geometry, heading_length: float,
              mount: FloatArray) -> FloatArray:
    """(windows, 3): odometry motion minus reference motion per window, in metres.

    ``mount`` is the reference frame's pose on the robot ``(x, y, yaw)`` in the base
    frame and its clock's lag ``[3]`` [s] (the reference at ``t + lag`` is the robot
    at ``t``): the reference's motion ``D`` is the base's ``M D M^-1``
    (:func:`~diffdrive_odom.core.se2.conjugate`).
    """
    x, y, th = integrate_steps(w.run.steps, geometry)
    est = np.column_stack((x[w.index], y[w.index], th[w.index]))
    ref = w.ref_at(float(mount[3]))
    mx, my, myaw = (float(v) for v in mount[:3])
    base = conjugate(between(ref[w.start], ref[w.end]), mx, my, myaw)
    diff = between(est[w.start], est[w.end]) - base
    diff[:, 2] = wrap_angles(diff[:, 2])
    diff[:, 2] *= heading_length
    return diff
