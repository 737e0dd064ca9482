"""Odometry calibration against a reference trajectory: both wheel radii and the separation.

Pure Python + numpy/scipy (no rclpy, no bag or message import); ``diffdrive-odom
calibrate`` reads the bags and calls this. Each run is decoded once into
geometry-free wheel increments (:mod:`diffdrive_odom.core.evaluation.recorded_run`); every
evaluation of the fit re-integrates them with the estimator's own step
(``kinematics.body_increment`` + ``integration.integrate_batch``), so what is fitted
is exactly what the node will compute. Without a reference, Borenstein and Feng's
UMBmark (:mod:`diffdrive_odom.core.evaluation.umbmark`) calibrates from two squares' end positions.
Whether a fit generalises is checked on held-out runs
(:mod:`diffdrive_odom.core.evaluation.crossval`).

:func:`fit` minimises the pose error along the whole trajectory: at every
``STRIDE``-th step, the odometry (started at the origin) minus the reference seen from
its pose at the run's start (x, y and the heading error times half the separation, all
in metres); each run weighted by ``1 / sqrt(samples)`` so a long run does not outvote
the others. The loss is Cauchy's with its scale set to 1.4826 x the median absolute
deviation of a first least-squares fit's residuals, so one run that no geometry fits
(a slipping wheel) does not drag the rest. The only nuisance is one yaw of the
reference about the start (the motion-capture body's heading offset on the robot).

Chosen on held-out runs (bench/bench_calibration.py on 45 OptiOdom runs of Sousa et
al.): end poses alone are ill-posed on closed paths (a square or a circle ends in
place with a wrong scale, its path far off), short relative windows need the mount
offset as a nuisance and still do worse held out. Fixed, not fitted, because the data
cannot determine them: the reference's offset from the axle (whole-trajectory errors
keep it bounded, it does not accumulate) and the clock lag between reference and
encoders (well under one 50 ms cycle on those runs; fitted, it came out as noise
between -77 and +42 ms). See :data:`FIXED`.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt
from scipy import optimize

from diffdrive_odom.core.evaluation import leftout
from diffdrive_odom.core.evaluation.metrics import Metrics, covered, evaluate, interpolate
from diffdrive_odom.core.evaluation.recorded_run import (
    CalibrationError,
    Run,
    single_segment,
    start_stamp,
    trajectory,
    values_of,
    with_values,
)
from diffdrive_odom.core.geometry.kinematics import Geometry
from diffdrive_odom.core.geometry.se2 import between, wrap_angles

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]

STRIDE = 5  # steps between residual samples (20 Hz readings: every 0.25 s)
LOSSES = ("cauchy", "linear", "soft_l1", "huber")
# What the fit keeps at zero, and why (calibrate prints it).
FIXED = (
    ("reference offset from the axle", "0 m", "bounded along a whole trajectory, it does "
     "not accumulate; the data do not determine it"),
    ("clock lag of the reference", "0 s", "under one reading cycle on real runs; fitted, "
     "it comes out as noise"),
)


@dataclass(frozen=True)
class RunFigures:
    """One run's error against its reference, before and after calibration."""

    name: str
    before: Metrics
    after: Metrics


@dataclass(frozen=True)
class Fit:
    """What :func:`fit` found: ``values`` = (left radius, right radius, separation) [m]."""

    nominal: Geometry
    geometry: Geometry
    values: FloatArray
    start_yaw: float  # the reference's yaw about the start [rad] (0 when not fitted)
    loss: str
    samples: int
    rms_before: float  # RMS residual [m] at the nominal geometry
    rms_after: float
    runs: tuple[RunFigures, ...]
    seconds: float
    evaluations: int
    end_weight: float = 0.0  # see :func:`fit`
    ends_only: bool = False


@dataclass(frozen=True)
class _Prepared:
    """A run's fixed data: residual sample steps and the reference there, start-relative."""

    run: Run
    index: IntArray
    reference: FloatArray  # (len(index), 3) in the frame of the reference's start pose
    bridges: tuple[leftout.Bridge, ...] = ()  # the slip events left out (core.evaluation.leftout)


def prepare(run: Run, max_gap: float, stride: int = STRIDE,
            ends_only: bool = False) -> _Prepared:
    """The steps a run's residuals are taken at and the reference there (start frame)."""
    single_segment(run)
    ref = run.reference
    if ref is None:
        raise CalibrationError(f"{run.name}: no reference trajectory")
    start = np.array([start_stamp(run.steps)], dtype=np.int64)
    if not covered(ref, start, max_gap).all():
        raise CalibrationError(f"{run.name}: the reference does not cover the run's start")
    spans = leftout.bridges(run, max_gap)
    ok = np.flatnonzero(covered(ref, run.steps.stamp_ns, max_gap)
                        & ~leftout.inside(spans, len(run.steps)))
    if len(ok) == 0:
        raise CalibrationError(f"{run.name}: the reference does not overlap the readings")
    index = ok[-1:] if ends_only else np.unique(np.concatenate((ok[stride - 1::stride],
                                                                 ok[-1:])))
    poses = interpolate(ref, np.concatenate((start, run.steps.stamp_ns[index])))
    relative = between(np.repeat(poses[:1], len(index), axis=0), poses[1:])
    return _Prepared(run, index, relative, spans)


def residuals(p: _Prepared, geometry: Geometry, start_yaw: float,
              heading_length: float, end_weight: float = 0.0) -> FloatArray:
    """(samples, 3): odometry minus reference (turned by ``start_yaw``), in metres.

    ``end_weight`` > 0 appends one row: the end position's error in the reference's own
    start frame (not turned: the start-aligned final error users read), times it.
    """
    x, y, th = leftout.integrate(p.run.steps, geometry, p.bridges, start_yaw)
    i = p.index
    c, s = math.cos(start_yaw), math.sin(start_yaw)
    ref = p.reference
    d = np.column_stack((x[i] - (c * ref[:, 0] - s * ref[:, 1]),
                         y[i] - (s * ref[:, 0] + c * ref[:, 1]),
                         heading_length * wrap_angles(th[i] - ref[:, 2])))
    if end_weight <= 0.0:
        return d
    end = end_weight * np.array([[x[i[-1]] - ref[-1, 0], y[i[-1]] - ref[-1, 1], 0.0]])
    return np.concatenate((d, end))


def fit(
    runs: Sequence[Run],
    nominal: Geometry,
    *,
    loss: str = "cauchy",
    fit_start_yaw: bool = True,
    ends_only: bool = False,
    end_weight: float = 0.0,
    weights: Sequence[float] | None = None,
    max_gap: float = 0.5,
    figures: bool = True,
) -> Fit:
    """Fit both wheel radii and the separation to the runs' references (see the module).

    ``ends_only`` matches the end poses only (OptiOdom's objective, kept for the
    benchmark's comparison); ``end_weight`` W > 0 adds each run's end position error
    (start frame, not turned by the start yaw) so that its square counts W^2 times the
    run's mean squared residual, in plain squares beside the robust loss (measured on
    the OptiOdom runs, doc/incoming/verdict2.md: not the default, it overfits a free
    path fitted alone); ``weights`` repeat runs (a bootstrap); ``figures=False``
    skips the per-run metrics. Raises CalibrationError for a run that cannot be used.
    """
    if not runs:
        raise CalibrationError("no run to calibrate from")
    if loss not in LOSSES:
        raise CalibrationError(f"loss must be one of {', '.join(LOSSES)}, got {loss!r}")
    if not (math.isfinite(end_weight) and end_weight >= 0.0):
        raise CalibrationError(f"end_weight must be finite and >= 0, got {end_weight!r}")
    start = time.perf_counter()
    prepared = [prepare(r, max_gap, ends_only=ends_only) for r in runs]
    w = np.ones(len(runs)) if weights is None else np.asarray(weights, dtype=np.float64)
    used = [(p, math.sqrt(wi / n), n) for p, wi in zip(prepared, w, strict=True) if wi > 0.0
            for n in [1 if ends_only else len(p.index)]]
    x0 = values_of(nominal)
    heading_length = 0.5 * nominal.separation
    evaluations = 0

    def geometry_at(x: FloatArray) -> Geometry:
        v = x0 * x[:3]
        return with_values(nominal, float(v[0]), float(v[1]), float(v[2]))

    def res(x: FloatArray) -> FloatArray:
        nonlocal evaluations
        evaluations += 1
        g, yaw = geometry_at(x), float(x[3]) if fit_start_yaw else 0.0
        return np.concatenate([sw * residuals(p, g, yaw, heading_length,
                                              end_weight * math.sqrt(n)).ravel()
                               for p, sw, n in used])

    n = 4 if fit_start_yaw else 3
    start_x = np.concatenate((np.ones(3), np.zeros(n - 3)))
    bounds = (np.array([0.2, 0.2, 0.2, -math.pi][:n]), np.array([5.0, 5.0, 5.0, math.pi][:n]))
    x_scale = np.array([1e-3, 1e-3, 1e-3, 1e-2][:n])
    r0 = res(start_x)
    sol = optimize.least_squares(res, start_x, method="trf", bounds=bounds, x_scale=x_scale,
                                 xtol=1e-12, ftol=1e-12, gtol=1e-12)
    if loss != "linear":
        r = np.asarray(sol.fun)
        ends = _end_rows([len(p.index) + (end_weight > 0.0) for p, _, _ in used], end_weight)
        along = r[~ends]
        scale = 1.4826 * float(np.median(np.abs(along - np.median(along)))) or 1e-6
        sol = optimize.least_squares(res, sol.x, method="trf", bounds=bounds,
                                     loss=_robust_along(loss, ends), f_scale=scale,
                                     x_scale=x_scale, xtol=1e-12, ftol=1e-12, gtol=1e-12)
    xs = np.asarray(sol.x, dtype=np.float64)
    fitted = geometry_at(xs)
    r = np.asarray(sol.fun, dtype=np.float64)
    return Fit(
        nominal=nominal,
        geometry=fitted,
        values=values_of(fitted),
        start_yaw=float(xs[3]) if fit_start_yaw else 0.0,
        loss=loss,
        samples=sum(len(p.index) for p, _, _ in used),
        rms_before=float(np.sqrt(np.mean(r0**2))),
        rms_after=float(np.sqrt(np.mean(r**2))),
        runs=run_figures(runs, nominal, fitted, max_gap) if figures else (),
        seconds=time.perf_counter() - start,
        evaluations=evaluations,
        end_weight=end_weight,
        ends_only=ends_only,
    )


def _end_rows(rows: Sequence[int], end_weight: float) -> npt.NDArray[np.bool_]:
    """Mask of the residual vector's end-position entries (each run's last row)."""
    mask = [np.zeros(3 * n, dtype=bool) for n in rows]
    if end_weight > 0.0:
        for m in mask:
            m[-3:] = True
    return np.concatenate(mask)


def _robust_along(loss: str, ends: npt.NDArray[np.bool_]) -> Any:
    """``loss`` on the samples along the runs, plain squares on the end rows.

    The ends are what the user reads (the final error), not outliers to discount.
    """
    if not ends.any():
        return loss

    def rho(z: FloatArray) -> FloatArray:
        out = np.empty((3, z.size))
        if loss == "cauchy":
            out[0], out[1] = np.log1p(z), 1.0 / (1.0 + z)
            out[2] = -out[1] ** 2
        elif loss == "soft_l1":
            t = 1.0 + z
            out[0], out[1], out[2] = 2.0 * (np.sqrt(t) - 1.0), t ** -0.5, -0.5 * t ** -1.5
        else:  # huber
            small = z <= 1.0
            zs = np.where(small, 1.0, z)
            out[0] = np.where(small, z, 2.0 * np.sqrt(zs) - 1.0)
            out[1] = np.where(small, 1.0, zs ** -0.5)
            out[2] = np.where(small, 0.0, -0.5 * zs ** -1.5)
        out[0, ends], out[1, ends], out[2, ends] = z[ends], 1.0, 0.0
        return out

    return rho


def run_figures(runs: Sequence[Run], nominal: Geometry, fitted: Geometry,
                max_gap: float = 0.5) -> tuple[RunFigures, ...]:
    """Each run's metrics with the nominal and the fitted geometry."""
    return tuple(RunFigures(r.name, figures_of(r, nominal, max_gap),
                            figures_of(r, fitted, max_gap)) for r in runs)


def figures_of(run: Run, geometry: Geometry, max_gap: float = 0.5) -> Metrics:
    """``eval``'s figures of ``run`` integrated with ``geometry`` against its reference.

    Its slip events (when the gyro judged it) bridged by the reference, as the fit
    leaves them out (:mod:`~diffdrive_odom.core.evaluation.leftout`), so a geometry is
    judged by the steps a geometry explains.
    """
    if run.reference is None:
        raise CalibrationError(f"{run.name}: no reference trajectory")
    spans = leftout.bridges(run, max_gap)
    est = leftout.trajectory(run, geometry, spans) if spans else trajectory(run, geometry)
    return evaluate(est, run.reference, max_gap=max_gap)
