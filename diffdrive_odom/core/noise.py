"""Wheel noise constants k from the fit's window residuals (a method of moments).

Pure Python + numpy/scipy. The noise model of Chong and Kleeman ("Accurate odometry
and error modelling for a mobile robot": wheel-travel variance ``k |s|`` per side):
each window's residual covariance (:mod:`diffdrive_odom.core.windows`) is predicted as
``k_left A + k_right B`` by propagating unit wheel noise through the step's Jacobians
(``integration.compose_jacobians``), and ``k`` is the non-negative least-squares match
of those predictions to the residuals' outer products.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import numpy.typing as npt
from scipy import optimize

from diffdrive_odom.core import windows
from diffdrive_odom.core.integration import Pose2D, compose
from diffdrive_odom.core.kinematics import Geometry, body_increment
from diffdrive_odom.core.uncertainty import NoiseModel, PoseUncertainty

FloatArray = npt.NDArray[np.float64]


def _unit_noise(w: windows.Windows, geometry: Geometry, heading_length: float
                ) -> tuple[FloatArray, FloatArray]:
    """Per window, the residual covariance for k_left = 1 and for k_right = 1: (w, 3, 3) each.

    The covariance is linear in each k, so the node's own propagation
    (:class:`~diffdrive_odom.core.uncertainty.PoseUncertainty`) with a unit k on one side
    and none on the other gives each side's share, from the window's first pose.
    """
    steps = w.run.steps
    scale = np.diag([1.0, 1.0, heading_length])
    out_l, out_r = np.zeros((len(w.start), 3, 3)), np.zeros((len(w.start), 3, 3))
    for k, (a, e) in enumerate(zip(w.index[w.start], w.index[w.end], strict=True)):
        pose = Pose2D()
        unit_l = PoseUncertainty(NoiseModel(k_left=1.0, k_right=0.0))
        unit_r = PoseUncertainty(NoiseModel(k_left=0.0, k_right=1.0))
        for i in range(a + 1, e + 1):
            d_l, d_r, dt = float(steps.d_left[i]), float(steps.d_right[i]), float(steps.dt[i])
            ds, dth = body_increment(geometry, d_l, d_r)
            for unit in (unit_l, unit_r):
                unit.propagate(pose, geometry, ds=ds, dtheta=dth, d_left=d_l, d_right=d_r, dt=dt)
            pose = compose(pose, ds, dth)
        out_l[k] = scale @ np.array(unit_l.covariance) @ scale
        out_r[k] = scale @ np.array(unit_r.covariance) @ scale
    return out_l, out_r


def noise_constants(prepared: Sequence[windows.Windows], geometry: Geometry,
                    heading_length: float, mount: FloatArray, free: int
                    ) -> tuple[float, float]:
    """Non-negative ``(k_left, k_right)`` whose predicted window covariances match r r'.

    ``free`` is the number of fitted parameters (the residuals' small-sample factor).
    """
    rows_l, rows_r, target = [], [], []
    for w in prepared:
        r = windows.residuals(w, geometry, heading_length, mount)
        unit_l, unit_r = _unit_noise(w, geometry, heading_length)
        rows_l.append(unit_l.reshape(len(r), 9))
        rows_r.append(unit_r.reshape(len(r), 9))
        target.append(np.einsum("ki,kj->kij", r, r).reshape(len(r), 9))
    a = np.column_stack((np.concatenate(rows_l).ravel(), np.concatenate(rows_r).ravel()))
    m = 3 * sum(len(w.start) for w in prepared)
    t = np.concatenate(target).ravel() * (m / max(m - free, 1))
    norm = np.linalg.norm(a, axis=0)
    norm[norm == 0.0] = 1.0
    k, _ = optimize.nnls(a / norm, t)
    return float(k[0] / norm[0]), float(k[1] / norm[1])
