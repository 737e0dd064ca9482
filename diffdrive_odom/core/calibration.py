"""Odometry calibration against a reference trajectory: wheel radii, separation, wheel noise.

Pure Python + numpy/scipy (no rclpy, no bag or message import); ``diffdrive-odom
calibrate`` reads the bags and calls this. Each run is decoded once into
geometry-free wheel increments (:mod:`diffdrive_odom.core.recorded_run`); every
evaluation of the fit re-integrates them with the estimator's own step
(``kinematics.body_increment`` + ``integration.integrate_batch``), so what is fitted
is exactly what the node will compute. Without a reference, Borenstein and Feng's
UMBmark (:mod:`diffdrive_odom.core.umbmark`) calibrates from two squares' end positions.

:func:`fit`, with a reference trajectory (motion capture, a simulator), is nonlinear
least squares on relative-pose residuals. The runs are cut into consecutive,
non-overlapping windows of ``window`` metres of wheel travel
(:mod:`diffdrive_odom.core.windows`); a residual is the odometry's motion across a
window, seen from its first pose, minus the reference's. Relative motion does not
care where the start alignment put the run, and it uses the whole trajectory, not
only the end pose, which can close a loop with a wrong scale. Consecutive windows
share no step, so with wheel noise that is independent from step to step their
residuals are independent: the parameters' covariance comes from the Jacobian at the
solution (the sandwich form, one cluster per window, which stays honest when residual
sizes differ). The wheel noise constants ``k`` are then estimated from the same
residuals (:mod:`diffdrive_odom.core.noise`).
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from scipy import optimize

from diffdrive_odom.core import windows
from diffdrive_odom.core.kinematics import Geometry
from diffdrive_odom.core.metrics import Metrics, evaluate
from diffdrive_odom.core.noise import noise_constants
from diffdrive_odom.core.recorded_run import (
    CalibrationError,
    Run,
    trajectory,
    values_of,
    with_values,
)

FloatArray = npt.NDArray[np.float64]

DEFAULT_WINDOW = 0.25  # m of wheel travel per residual window


@dataclass(frozen=True)
class RunFigures:
    """One run's error against its reference, before and after calibration."""

    name: str
    before: Metrics
    after: Metrics


@dataclass(frozen=True)
class Fit:
    """What :func:`fit` found.

    ``values`` / ``covariance`` are for ``(left radius, right radius, separation)``
    in metres; ``k_left`` / ``k_right`` are wheel-travel variance per metre rolled [m].
    """

    nominal: Geometry
    geometry: Geometry
    values: FloatArray
    covariance: FloatArray
    mount: FloatArray  # reference frame on the robot: x, y [m], yaw [rad]; clock lag [s]
    mount_std: FloatArray
    k_left: float
    k_right: float
    windows: int
    window: float
    rms_before: float  # RMS residual [m] at the nominal geometry
    rms_after: float
    runs: tuple[RunFigures, ...]
    seconds: float
    evaluations: int

    @property
    def std(self) -> FloatArray:
        """1-sigma uncertainty of ``values`` [m]."""
        return np.sqrt(np.diag(self.covariance))


def _run_figures(runs: Sequence[Run], nominal: Geometry, fitted: Geometry,
                 max_gap: float) -> tuple[RunFigures, ...]:
    out = []
    for run in runs:
        assert run.reference is not None
        out.append(RunFigures(
            run.name,
            evaluate(trajectory(run, nominal), run.reference, max_gap=max_gap),
            evaluate(trajectory(run, fitted), run.reference, max_gap=max_gap)))
    return tuple(out)


def fit(
    runs: Sequence[Run],
    nominal: Geometry,
    window: float = DEFAULT_WINDOW,
    max_gap: float = 0.5,
    fit_mount: bool = True,
) -> Fit:
    """Fit both wheel radii and the separation to the runs' references (see the module).

    ``nominal`` is the start (and keeps its signs and nominal values). With
    ``fit_mount`` the reference frame's pose on the robot (a motion-capture body is
    rarely centred on the axle or aligned with it) is fitted along as a nuisance:
    left out, a small yaw offset of the markers reads as a wheel radius ratio.
    Raises CalibrationError for a run that cannot be used.
    """
    if not runs:
        raise CalibrationError("no run to calibrate from")
    if not (math.isfinite(window) and window > 0.0):
        raise CalibrationError(f"window must be > 0 m, got {window!r}")
    start = time.perf_counter()
    prepared = [windows.cut(r, nominal, window, max_gap) for r in runs]
    x0 = values_of(nominal)
    heading_length = 0.5 * nominal.separation
    evaluations = 0
    free = 7 if fit_mount else 3

    def geometry_at(p: FloatArray) -> Geometry:
        v = x0 * p[:3]
        return with_values(nominal, float(v[0]), float(v[1]), float(v[2]))

    def mount_at(p: FloatArray) -> FloatArray:
        return p[3:7] if fit_mount else np.zeros(4)

    def residuals(p: FloatArray) -> FloatArray:
        nonlocal evaluations
        evaluations += 1
        if not np.all(p[:3] > 0.0):
            return np.full(sum(3 * len(w.start) for w in prepared), 1e3)
        g, m = geometry_at(p), mount_at(p)
        return np.concatenate(
            [windows.residuals(w, g, heading_length, m).ravel() for w in prepared])

    p0 = np.concatenate((np.ones(3), np.zeros(free - 3)))
    r0 = residuals(p0)
    sol = optimize.least_squares(residuals, p0, jac="3-point", method="lm",
                                 xtol=1e-14, ftol=1e-14, gtol=1e-14)
    p = np.asarray(sol.x, dtype=np.float64)
    fitted, mount = geometry_at(p), mount_at(p)
    r = np.asarray(sol.fun, dtype=np.float64)
    jac = np.asarray(sol.jac, dtype=np.float64).copy()
    jac[:, :3] /= x0  # d residual / d value [m/m]
    covariance = _sandwich(jac, r, cluster=3)
    k_left, k_right = noise_constants(prepared, fitted, heading_length, mount, free)
    return Fit(
        nominal=nominal,
        geometry=fitted,
        values=values_of(fitted),
        covariance=covariance[:3, :3],
        mount=mount,
        mount_std=np.sqrt(np.diag(covariance))[3:] if fit_mount else np.zeros(4),
        k_left=k_left,
        k_right=k_right,
        windows=len(r) // 3,
        window=window,
        rms_before=float(np.sqrt(np.mean(r0**2))),
        rms_after=float(np.sqrt(np.mean(r**2))),
        runs=_run_figures(runs, nominal, fitted, max_gap),
        seconds=time.perf_counter() - start,
        evaluations=evaluations,
    )


def _sandwich(jac: FloatArray, r: FloatArray, cluster: int) -> FloatArray:
    """Cluster-robust covariance ``(J'J)^-1 (sum_w J_w' r_w r_w' J_w) (J'J)^-1``.

    Each window's residuals are one cluster (they share steps); windows share none.
    A small-sample factor ``m / (m - n)`` undoes the fit's pull towards the data.
    """
    m, n = jac.shape
    bread = np.linalg.inv(jac.T @ jac)
    scores = (jac * r[:, None]).reshape(m // cluster, cluster, n).sum(axis=1)
    meat = scores.T @ scores
    return np.asarray(bread @ meat @ bread * (m / max(m - n, 1)), dtype=np.float64)
