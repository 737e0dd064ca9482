"""UMBmark: wheelbase and wheel diameter ratio from where two driven squares end.

Pure Python + numpy. Borenstein and Feng, "Measurement and correction of systematic
odometry errors in mobile robots" (1996), from the end positions of one clockwise and
one counter-clockwise square of side ``L``: the paper's Type A (wheelbase, ``E_b``)
and Type B (wheel diameter ratio, ``E_d``) corrections. The paper applies them once;
its formulas are first order, so here they are applied again on the recorded wheel
increments re-integrated with the corrected geometry until the end errors vanish (the
first pass is reported as the paper's figure). Like the paper, it keeps the mean
wheel radius: the scale of the wheels is not observable from where a closed square ends.
A run decoded with the gyro and read with its reference has its slip events bridged
by the reference's motion (:mod:`~diffdrive_odom.core.evaluation.leftout`), as the
least-squares fit leaves them out; typed end positions have no reference to bridge with.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from diffdrive_odom.core.bulk.batch import final_pose
from diffdrive_odom.core.evaluation import leftout
from diffdrive_odom.core.evaluation.metrics import Trajectory, covered, interpolate
from diffdrive_odom.core.evaluation.recorded_run import (
    CalibrationError,
    Run,
    single_segment,
    start_stamp,
    with_values,
)
from diffdrive_odom.core.geometry.kinematics import Geometry
from diffdrive_odom.core.geometry.mount import AXLE, Mount
from diffdrive_odom.core.geometry.se2 import between


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

# What is left of alpha and beta [rad] when the iteration stops shrinking it is accepted
# below FLOOR: 1e-5 rad a square moves the separation by 6 ppm (about a micrometre on a
# 0.2 m track), far below what two squares measure. STALL_PASSES passes in a row that do
# not halve it make a stall.
FLOOR = 1e-5
STALL_PASSES = 3


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


def _end_error(run: Run, geometry: Geometry, truth_end: EndPoint,
               mount: Mount = AXLE) -> EndPoint:
    """Measured minus odometric end position, in the start frame [m] (slips bridged)."""
    spans = leftout.bridges(run)
    if not spans:
        end = final_pose(run.steps, geometry)
        return truth_end[0] - end.x, truth_end[1] - end.y
    x, y, _ = leftout.integrate(run.steps, geometry, spans, mount)
    if not (math.isfinite(x[-1]) and math.isfinite(y[-1])):
        raise CalibrationError(f"{run.name}: a slip at its end the reference does not cover")
    return truth_end[0] - float(x[-1]), truth_end[1] - float(y[-1])


def umbmark(
    cw: Run, ccw: Run, cw_end: EndPoint, ccw_end: EndPoint, *, side: float,
    nominal: Geometry, tolerance: float = 1e-9, max_passes: int = 200, mount: Mount = AXLE,
) -> Umbmark:
    """UMBmark from one square each way: ``*_end`` is where the robot really stopped.

    The end positions are relative to the start pose, in its frame (x forward,
    y left), as a tape measure gives them (base_link's: a reference's moved there by
    ``mount``, :func:`reference_end`, which also bridges its slips with it). The paper's
    correction is applied to the
    nominal geometry, then again to the corrected one with the same recorded wheel
    increments, until ``alpha`` and ``beta`` are below ``tolerance`` rad, or until
    passes stop shrinking them while they are below :data:`FLOOR` (its floor).
    """
    if not (math.isfinite(side) and side > 0.0):
        raise CalibrationError(f"--side must be > 0 m, got {side!r}")
    for run in (cw, ccw):
        single_segment(run)

    def one(g: Geometry) -> UmbmarkPass:
        return umbmark_pass(_end_error(cw, g, cw_end, mount), _end_error(ccw, g, ccw_end, mount),
                            side, nominal.separation)

    first = one(nominal)
    geometry, p, passes = umbmark_correct(nominal, first), first, 1
    best, stalled = math.inf, 0
    while passes < max_passes:
        p = one(geometry)
        left = max(abs(p.alpha), abs(p.beta))
        if left < tolerance:
            break
        # At its floor a pass no longer halves what is left; below FLOOR that is the
        # answer (a demo run stalled at 1.2e-6 rad after shrinking x0.1 a pass), above
        # it the iteration is not converging and says so.
        stalled = stalled + 1 if left > 0.5 * best else 0
        best = min(best, left)
        if stalled >= STALL_PASSES and left < FLOOR:
            break
        geometry = umbmark_correct(geometry, p)
        passes += 1
    else:
        raise CalibrationError(
            f"UMBmark: no convergence in {max_passes} passes (alpha {p.alpha:.3g}, "
            f"beta {p.beta:.3g} rad)")

    def errors(g: Geometry) -> tuple[float, float]:
        e1, e2 = _end_error(cw, g, cw_end, mount), _end_error(ccw, g, ccw_end, mount)
        return math.hypot(*e1), math.hypot(*e2)

    return Umbmark(nominal, side, first, geometry, passes, errors(nominal), errors(geometry),
                   umbmark_correct(nominal, first))


def reference_end(run: Run, reference: Trajectory, mount: Mount = AXLE) -> EndPoint:
    """base_link's end position relative to its pose at the run's start, in that frame.

    As UMBmark wants it (so a reference in any world frame works): the reference's
    motion moved onto base_link by ``mount``; the start is the stamp of the run's first
    reading, where the odometry starts at the origin.
    """
    single_segment(run)
    ends = np.array([start_stamp(run.steps), int(run.steps.stamp_ns[-1])], dtype=np.int64)
    if not covered(reference, ends, math.inf).all():
        raise CalibrationError(f"{run.name}: the reference does not cover the whole run")
    poses = interpolate(reference, ends)
    x, y, _ = mount.base_motions(between(poses[:1], poses[1:]))[0]
    return float(x), float(y)
