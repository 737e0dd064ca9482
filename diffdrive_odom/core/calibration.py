"""Odometry calibration from recorded runs: wheel radii, separation and wheel noise.

Pure Python + numpy/scipy (no rclpy, no bag or message import); ``diffdrive-odom
calibrate`` reads the bags and calls this. Each run is decoded once into
geometry-free wheel increments (:mod:`diffdrive_odom.core.batch`); every evaluation of the
fit re-integrates them with the estimator's own step
(``kinematics.body_increment`` + ``integration.integrate_batch``), so what is fitted
is exactly what the node will compute.

Two methods:

- :func:`fit`, with a reference trajectory (motion capture, a simulator): nonlinear
  least squares on relative-pose residuals. The runs are cut into consecutive,
  non-overlapping windows of ``window`` metres of wheel travel; a residual is the
  odometry's motion across a window, seen from its first pose, minus the reference's
  (x, y and the heading error times half the separation: all three in metres of
  wheel travel). Relative motion does not care where the start alignment put the
  run, and it uses the whole trajectory, not only the end pose, which can close a
  loop with a wrong scale. Consecutive windows share no step, so with wheel noise
  that is independent from step to step their residuals are independent: the
  parameters' covariance comes from the Jacobian at the solution (the sandwich form,
  one cluster per window, which stays honest when residual sizes differ).
  The wheel noise constants ``k`` of Chong and Kleeman ("Accurate odometry and
  error modelling for a mobile robot": wheel-travel variance ``k |s|`` per side)
  are then estimated from the same residuals: each window's residual covariance is
  predicted as ``k_left A + k_right B`` by propagating unit wheel noise through the
  step's Jacobians (``integration.compose_jacobians``), and ``k`` is the
  non-negative least-squares match of those predictions to the residuals' outer
  products (a method of moments).
- :func:`umbmark`, Borenstein and Feng's UMBmark ("Measurement and correction of
  systematic odometry errors in mobile robots", 1996), from the end positions of one
  clockwise and one counter-clockwise square of side ``L``: the paper's Type A
  (wheelbase, ``E_b``) and Type B (wheel diameter ratio, ``E_d``) corrections. The
  paper applies them once; its formulas are first order, so here they are applied
  again on the recorded wheel increments re-integrated with the corrected geometry
  until the end errors vanish (the first pass is reported as the paper's figure).
  Like the paper, it keeps the mean wheel radius: the scale of the wheels is not
  observable from where a closed square ends.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from scipy import optimize

from diffdrive_odom.core.batch import WheelSteps, final_pose, integrate_steps
from diffdrive_odom.core.integration import Pose2D, compose
from diffdrive_odom.core.kinematics import Geometry, body_increment, wheel_arcs
from diffdrive_odom.core.metrics import Metrics, Trajectory, covered, evaluate, interpolate
from diffdrive_odom.core.se2 import between, conjugate, wrap_angles
from diffdrive_odom.core.uncertainty import NoiseModel, PoseUncertainty

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]

DEFAULT_WINDOW = 0.25  # m of wheel travel per residual window
PARAMETERS = ("left_radius", "right_radius", "separation")


class CalibrationError(ValueError):
    """A run that cannot be used for calibration (says which and why)."""


@dataclass(frozen=True)
class Run:
    """One recorded run: its wheel increments and, for :func:`fit`, a reference."""

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


def _single_segment(run: Run) -> None:
    if len(run.steps) < 2:
        raise CalibrationError(f"{run.name}: fewer than 2 usable readings")
    if run.steps.segments > 1:
        raise CalibrationError(
            f"{run.name}: the stamps jump back ({run.steps.segments} segments); "
            "calibrate each part as its own run")


# --- least squares on relative motion ------------------------------------------------


@dataclass(frozen=True)
class _Windows:
    """A run's fixed data for the fit: matched steps, reference there, window bounds."""

    run: Run
    reference: Trajectory
    index: IntArray  # step indices with a reference pose
    start: IntArray  # window k spans index[start[k]] .. index[end[k]]
    end: IntArray

    def ref_at(self, lag: float) -> FloatArray:
        """(len(index), 3) reference poses at the steps' stamps plus ``lag`` s."""
        return interpolate(self.reference, self.run.steps.stamp_ns[self.index], lag)


def _windows(run: Run, nominal: Geometry, window: float, max_gap: float) -> _Windows:
    """Cut a run into consecutive windows of ``window`` m of wheel travel (nominal radii)."""
    _single_segment(run)
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
    return _Windows(run, run.reference, index, bounds[:-1], bounds[1:])


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


def _window_residuals(w: _Windows, geometry: Geometry, heading_length: float,
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
    prepared = [_windows(r, nominal, window, max_gap) for r in runs]
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
            [_window_residuals(w, g, heading_length, m).ravel() for w in prepared])

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
    k_left, k_right = _noise_constants(prepared, fitted, heading_length, mount, free)
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


def _unit_noise(w: _Windows, geometry: Geometry, heading_length: float
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


def _noise_constants(prepared: Sequence[_Windows], geometry: Geometry,
                     heading_length: float, mount: FloatArray, free: int
                     ) -> tuple[float, float]:
    """Non-negative ``(k_left, k_right)`` whose predicted window covariances match r r'."""
    rows_l, rows_r, target = [], [], []
    for w in prepared:
        r = _window_residuals(w, geometry, heading_length, mount)
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


# --- UMBmark ------------------------------------------------------------------------


@dataclass(frozen=True)
class UmbmarkPass:
    """One application of the paper's formulas to the end errors of both squares.

    ``alpha`` / ``beta`` [rad] are the Type A / Type B orientation errors, ``e_d`` the
    wheel diameter ratio right/left, ``e_b`` the wheelbase factor. ``alpha_y`` /
    ``beta_y`` are the same errors from the y coordinates, the paper's cross-check
    (they differ from ``alpha`` / ``beta`` by second-order effects and noise).
    """

    cw_error: tuple[float, float]
    ccw_error: tuple[float, float]
    alpha: float
    beta: float
    alpha_y: float
    beta_y: float
    e_d: float
    e_b: float


@dataclass(frozen=True)
class Umbmark:
    """UMBmark's result: the paper's single pass and the geometry it converges to."""

    nominal: Geometry
    side: float
    first: UmbmarkPass  # the paper's figures, from the nominal geometry
    geometry: Geometry  # after the correction is iterated to convergence
    passes: int
    before: tuple[float, float]  # end position error [m], (cw, ccw), nominal
    after: tuple[float, float]  # the same with ``geometry``
    one_pass: Geometry  # the paper's single correction applied to ``nominal``

    @property
    def e_max_before(self) -> float:
        """The paper's E_max,syst with one run per direction: the larger end error [m]."""
        return max(self.before)

    @property
    def e_max_after(self) -> float:
        """E_max,syst after calibration [m]."""
        return max(self.after)


EndPoint = tuple[float, float]


def umbmark_pass(cw_error: EndPoint, ccw_error: EndPoint, side: float,
                 separation: float) -> UmbmarkPass:
    """Borenstein and Feng's corrections from the end errors of the two squares.

    ``*_error`` is (x, y) of ``absolute - calculated`` end position [m] in the start
    frame (x forward, y left; the paper's frame for these signs). The formulas, with
    the orientation errors in radians:

        alpha = (x_cw + x_ccw) / (-4 L)                 Type A (wheelbase)
        beta  = (x_cw - x_ccw) / (-4 L)                 Type B (wheel diameters)
        R     = (L / 2) / sin(beta / 2)                 curvature radius of a leg
        E_d   = D_R / D_L = (R + b / 2) / (R - b / 2)
        E_b   = (pi / 2) / (pi / 2 - alpha)             b_actual = E_b b_nominal

    and from y: ``alpha_y = (y_cw - y_ccw) / (-4 L)``, ``beta_y = (y_cw + y_ccw) / (-4 L)``.
    """
    (xcw, ycw), (xccw, yccw) = cw_error, ccw_error
    alpha = (xcw + xccw) / (-4.0 * side)
    beta = (xcw - xccw) / (-4.0 * side)
    half_b = 0.5 * separation
    if beta == 0.0:
        e_d = 1.0
    else:
        radius = (0.5 * side) / math.sin(0.5 * beta)
        e_d = (radius + half_b) / (radius - half_b)
    e_b = (0.5 * math.pi) / (0.5 * math.pi - alpha)
    if not (math.isfinite(e_d) and e_d > 0.0 and math.isfinite(e_b) and e_b > 0.0):
        raise CalibrationError(
            f"UMBmark: end errors too large for its formulas (E_d {e_d:.4g}, E_b {e_b:.4g}); "
            "are the squares' side and direction right?")
    alpha_y = (ycw - yccw) / (-4.0 * side)
    beta_y = (ycw + yccw) / (-4.0 * side)
    return UmbmarkPass(cw_error, ccw_error, alpha, beta, alpha_y, beta_y, e_d, e_b)


def umbmark_correct(geometry: Geometry, p: UmbmarkPass) -> Geometry:
    """Apply E_d and E_b to ``geometry``; the mean wheel radius is kept (the paper's c_L, c_R).

    ``c_L = 2 / (E_d + 1)`` and ``c_R = 2 / (1 / E_d + 1)`` scale the left and right
    diameters (their ratio multiplies by E_d, their mean stays); the separation is
    multiplied by E_b.
    """
    mean = 0.5 * (geometry.left_radius + geometry.right_radius)
    ratio = geometry.right_radius / geometry.left_radius * p.e_d
    c_left, c_right = 2.0 / (ratio + 1.0), 2.0 / (1.0 / ratio + 1.0)
    return with_values(geometry, mean * c_left, mean * c_right,
                       geometry.separation * p.e_b)


def _end_error(run: Run, geometry: Geometry, truth_end: EndPoint) -> EndPoint:
    """Measured minus odometric end position, in the start frame [m]."""
    end = final_pose(run.steps, geometry)
    return truth_end[0] - end.x, truth_end[1] - end.y


def umbmark(
    cw: Run, ccw: Run, cw_end: EndPoint, ccw_end: EndPoint, *, side: float,
    nominal: Geometry, tolerance: float = 1e-9, max_passes: int = 200,
) -> Umbmark:
    """UMBmark from one square each way: ``*_end`` is where the robot really stopped.

    The end positions are relative to the start pose, in its frame (x forward,
    y left), as a tape measure gives them. The paper's correction is applied to the
    nominal geometry, then again to the corrected one with the same recorded wheel
    increments, until ``alpha`` and ``beta`` are below ``tolerance`` rad.
    """
    if not (math.isfinite(side) and side > 0.0):
        raise CalibrationError(f"--side must be > 0 m, got {side!r}")
    for run in (cw, ccw):
        _single_segment(run)

    def one(g: Geometry) -> UmbmarkPass:
        return umbmark_pass(_end_error(cw, g, cw_end), _end_error(ccw, g, ccw_end), side,
                            nominal.separation)

    first = one(nominal)
    geometry, p, passes = umbmark_correct(nominal, first), first, 1
    while passes < max_passes:
        p = one(geometry)
        if max(abs(p.alpha), abs(p.beta)) < tolerance:
            break
        geometry = umbmark_correct(geometry, p)
        passes += 1
    else:
        raise CalibrationError(
            f"UMBmark: no convergence in {max_passes} passes (alpha {p.alpha:.3g}, "
            f"beta {p.beta:.3g} rad)")

    def errors(g: Geometry) -> tuple[float, float]:
        e1, e2 = _end_error(cw, g, cw_end), _end_error(ccw, g, ccw_end)
        return math.hypot(*e1), math.hypot(*e2)

    return Umbmark(nominal, side, first, geometry, passes, errors(nominal), errors(geometry),
                   umbmark_correct(nominal, first))


def reference_end(run: Run, reference: Trajectory) -> EndPoint:
    """The reference's end position relative to its pose at the run's start, in that frame.

    As UMBmark wants it (so a reference in any world frame works): the start is the
    stamp of the run's first reading, where the odometry starts at the origin.
    """
    _single_segment(run)
    ends = np.array([start_stamp(run.steps), int(run.steps.stamp_ns[-1])], dtype=np.int64)
    if not covered(reference, ends, math.inf).all():
        raise CalibrationError(f"{run.name}: the reference does not cover the whole run")
    poses = interpolate(reference, ends)
    x, y, _ = between(poses[:1], poses[1:])[0]
    return float(x), float(y)
