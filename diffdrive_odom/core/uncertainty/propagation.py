"""Pose and twist covariance of wheel odometry, propagated through the CIR step.

Pure Python (no rclpy, no messages). The random part of odometry error
(:mod:`~.noise`): each wheel's ground travel over a step carries zero-mean noise of
variance ``k |d|`` (Chong and Kleeman, "Accurate odometry and error modelling for a
mobile robot"), ``d`` the arc that wheel rolled, ``k`` [m] per side, and the step's turn
its own of variance ``k_rot |dtheta|`` (slip while turning). Variances in proportion to
what the step did make the model independent of the reading rate and zero at rest.
Systematic error (wrong radii, separation) is not random: it is the geometry term below.

Each step the 3x3 pose covariance goes through the exact CIR step's Jacobians
(Furlan, Marzorati and Sorrenti, "2D transforms for the odometry of a differential
kinematics mobile robot"; :func:`integration.compose_jacobians`), chained with the
linear wheel -> body map of :func:`kinematics.body_increment`::

    P <- F_pose P F_pose^T + G Q G^T + k_rot |dtheta| u u^T,   G = F_step B,
    Q = diag(var_left, var_right),   u = F_step (0, 1)^T

with ``B`` the 2x2 Jacobian of ``(ds, dtheta)`` w.r.t. the joint angle increments and
``u`` the step's ``d pose / d dtheta`` (its last entry 1: a spin on the spot by ``a``
adds ``k_rot |a|`` to the heading variance, a straight line nothing).

Systematic error (the true radii and separation differ from the configured ones) is the
other part of odometry error (Kelly, "Linearized Error Propagation in Odometry"; Chong
and Kleeman): one draw per robot, not per step, so it is not added step by step. Beside
``P`` the state carries ``J``, the sensitivity of the pose to the relative errors of
``(left radius, right radius, separation)``:

    J <- F_pose J + F_step G,   G = [[s_l / 2, s_r / 2, 0], [-s_l / b, s_r / b, -dtheta]]

(``s_l``, ``s_r`` the step's wheel arcs, ``G = d(ds, dtheta) / d(ln r_l, ln r_r, ln b)``),
and the published pose covariance adds ``J S J^T`` with ``S = diag(sr^2, sr^2, sb^2)``,
``sr`` / ``sb`` = ``wheel_radius_stddev_ratio`` / ``wheel_separation_stddev_ratio``
(each radius independent). That term grows with distance squared where ``P`` grows with
distance. Reset sets both ``P`` and ``J`` back to zero. When the steps go on with
another geometry (``online_calibration: apply``), ``S`` is that geometry's own
(:mod:`~.ratios`) and the stretch before is folded into ``P`` at the switch
(:meth:`PoseUncertainty.switch_geometry`).

Encoder quantization (the Caltech ME/CS 133 notes, "Kinematics and Odometry for a
Differential Drive Vehicle", list it among the four sources of drift) is *not*
noise per step: the increments of consecutive readings telescope, so the sum of
the wheel travels is off by the quantization of only two readings, the reference
and the current one, however many steps lie between. It is therefore a floor added
to the published pose covariance (``2 * tick^2 / 12`` per wheel joint, divided by
the wheels averaged per side, mapped at the current heading), never accumulated
into ``P``, so the covariance does not grow with the reading rate. The floor
neglects how the reference reading's heading error swings the rest of the path
(a lever of ``tick * r / b`` rad times the distance), which is far below the
``k`` terms for any real encoder and any ``k`` > 0.

The twist is the rolling mean of per-step rates ``ds / dt``, ``dtheta / dt``; its
covariance comes from the same model over the same ``dt``: the wheel noise of each
step plus the quantization of the step's two readings (here the difference of two
readings is all there is, so both count), averaged over the window as independent
steps (slightly pessimistic for a window > 1, exact for the default window of 1).

Messages carry 6x6 row-major matrices over (x, y, z, roll, pitch, yaw) and
(vx, vy, vz, wx, wy, wz). A planar sensor says nothing of z, roll and pitch and
their rates: those get :data:`UNOBSERVED_VARIANCE` (large and finite, as
robot_localization expects of a 2D sensor). Lateral velocity ``vy`` is zero by the
rolling constraint, which holds only as well as the tyres grip: it gets
:data:`ROLLING_CONSTRAINT_VARIANCE` (the static model's default, 1 mm/s), so that no
message matrix is singular (robot_localization and any Cholesky of it need positive
definite ones). For the same reason the observed block gets :data:`COVARIANCE_FLOOR` on its
diagonal: the propagated 3x3 is zero at the start and of rank 2 after the first step.
The twist covariance has no geometry
term (not modelled: at the default ratios it is a few tenths of a percent of the speed).
With a gyro (``use_imu``, :mod:`~.estimation.gyro.gyrodometry`) a step goes through
propagate_gyro, which has no rotation term: there the heading is the gyro's (fused with
the wheels' by their white variances), not the wheels' alone.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass
from itertools import islice

from diffdrive_odom.core.geometry.integration import Pose2D, compose_jacobians
from diffdrive_odom.core.geometry.kinematics import Geometry, body_increment
from diffdrive_odom.core.geometry.mat3 import (
    Matrix,
    add3,
    congruence3,
    outer3,
    rotate_sensitivity,
    symmetric,
    times2x2,
    times_vec,
    wheel_noise2,
    wheel_noise3,
)
from diffdrive_odom.core.uncertainty.noise import (
    NoiseModel,
    joint_variances,
    quantization_variance,
    rotation_variance,
)

UNOBSERVED_VARIANCE = 1.0e6
# vy [(m/s)^2]: the rolling constraint's slack, 1 mm/s (1 sigma), as the static default.
ROLLING_CONSTRAINT_VARIANCE = 1.0e-6
# Added to the diagonal of the observed block (x, y, yaw; vx, wz) [m^2, rad^2, per s^2 for
# rates]: (1 um)^2, far below any real term, enough to make the matrices positive definite.
COVARIANCE_FLOOR = 1.0e-12
ZERO3: Matrix = ((0.0, 0.0, 0.0), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0))


ZERO_VEC = (0.0, 0.0, 0.0)


@dataclass(frozen=True, slots=True, kw_only=True)
class GyroStep:
    """One gyrodometry step (:mod:`~.estimation.gyro.gyrodometry`) and how its errors enter.

    ``(ds, dtheta) = B d + c g``: ``d`` the joint increments (the wheel model's
    variance), ``g`` the gyro's angle (white variance ``var_gyro``, plus ``dt`` times
    the bias error). Built by keyword only: nine fields, three of them matrices.
    ``merged``: the turn readings held before it took for now (``ds`` 0); the step's arc
    starts before them and turns by ``dtheta + merged``.
    """

    ds: float  # m: the step's distance
    dtheta: float  # rad: its heading change
    b: Matrix  # 2x2: d(ds, dtheta) / d(joint increments left, right)
    c: tuple[float, float]  # d(ds, dtheta) / d(gyro angle)
    var_gyro: float  # rad^2: the gyro angle's white-noise variance over the step
    dt: float  # s: the step's interval
    geometry: Matrix  # 2x3: d(ds, dtheta) / d(ln r_left, ln r_right, ln separation)
    slip: bool  # a wheel slipped: the heading is the gyro's
    merged: float = 0.0  # rad: handed out by the held readings before it


def _sensitivity_step(j: Matrix, f_pose: Matrix, f_step: Matrix, ds: float, dtheta: float,
                      separation: float) -> Matrix:
    """``F_pose J + F_step G``: the pose's sensitivity to the relative geometry errors."""
    (j00, j01, j02), (j10, j11, j12), (j20, j21, j22) = j
    a, b = f_pose[0][2], f_pose[1][2]  # F_pose = [[1, 0, a], [0, 1, b], [0, 0, 1]]
    (f00, f01), (f10, f11), (_, f21) = f_step
    half = 0.5 * dtheta * separation
    s_l, s_r = ds - half, ds + half  # the wheels' arcs
    g00, g01 = 0.5 * s_l, 0.5 * s_r
    g10, g11, g12 = -s_l / separation, s_r / separation, -dtheta
    return ((j00 + a * j20 + f00 * g00 + f01 * g10, j01 + a * j21 + f00 * g01 + f01 * g11,
             j02 + a * j22 + f01 * g12),
            (j10 + b * j20 + f10 * g00 + f11 * g10, j11 + b * j21 + f10 * g01 + f11 * g11,
             j12 + b * j22 + f11 * g12),
            (j20 + f21 * g10, j21 + f21 * g11, j22 + f21 * g12))


def geometry_term(j: Matrix, radius_ratio: float, separation_ratio: float) -> Matrix:
    """``J S J^T`` with ``S = diag(radius_ratio^2, radius_ratio^2, separation_ratio^2)``."""
    vr, vb = radius_ratio * radius_ratio, separation_ratio * separation_ratio
    (j00, j01, j02), (j10, j11, j12), (j20, j21, j22) = j
    return symmetric(
        vr * (j00 * j00 + j01 * j01) + vb * j02 * j02,
        vr * (j00 * j10 + j01 * j11) + vb * j02 * j12,
        vr * (j00 * j20 + j01 * j21) + vb * j02 * j22,
        vr * (j10 * j10 + j11 * j11) + vb * j12 * j12,
        vr * (j10 * j20 + j11 * j21) + vb * j12 * j22,
        vr * (j20 * j20 + j21 * j21) + vb * j22 * j22,
    )


def wheel_jacobian(geometry: Geometry) -> Matrix:
    """``d(ds, dtheta) / d(joint increments)``: the columns of the linear map itself."""
    left = body_increment(geometry, 1.0, 0.0)
    right = body_increment(geometry, 0.0, 1.0)
    return ((left[0], right[0]), (left[1], right[1]))


def rotation_column(f_step: Matrix) -> tuple[float, float, float]:
    """``d pose / d dtheta`` of a step: how its turn's noise enters the pose."""
    return (f_step[0][1], f_step[1][1], f_step[2][1])


# z, roll, pitch (or their rates): nothing known. Message rows 0, 1, 5: x (vx), y, yaw (wz).
# The rows' diagonals start at the floor; the model's values are added to it (the array
# form in tools/sinks.py adds them the same way, so both give the same floats).
_POSE = [UNOBSERVED_VARIANCE if i in (14, 21, 28) else COVARIANCE_FLOOR if i in (0, 7, 35)
         else 0.0 for i in range(36)]
_TWIST = [ROLLING_CONSTRAINT_VARIANCE if i == 7 else v for i, v in enumerate(_POSE)]


def pose_message_covariance(p: Matrix) -> list[float]:
    """3x3 (x, y, yaw) -> the 6x6 row-major pose covariance of an Odometry message."""
    (xx, xy, xt), (yx, yy, yt), (tx, ty, tt) = p
    cov = _POSE.copy()
    cov[0] += float(xx)
    cov[1], cov[5] = float(xy), float(xt)
    cov[7] += float(yy)
    cov[6], cov[11] = float(yx), float(yt)
    cov[30], cov[31] = float(tx), float(ty)
    cov[35] += float(tt)
    return cov


def twist_message_covariance(t: Matrix) -> list[float]:
    """2x2 (vx, wz) -> the 6x6 row-major twist covariance (vy: the rolling constraint's)."""
    (vv, vw), (wv, ww) = t
    cov = _TWIST.copy()
    cov[0] += float(vv)
    cov[5], cov[30] = float(vw), float(wv)
    cov[35] += float(ww)
    return cov


class PoseUncertainty:
    """The 3x3 pose covariance state of one estimator, and the twist covariance window."""

    def __init__(
        self,
        model: NoiseModel,
        ticks_per_revolution: float = 0.0,
        wheels_per_side: int = 1,
        window: int = 1,
        start: Matrix = ZERO3,
    ) -> None:
        self.model = model
        self.start = start
        self.covariance: Matrix = start
        # d pose / d(ln left radius, ln right radius, ln separation); zero at the start.
        self.sensitivity: Matrix = ZERO3
        self._quantum = quantization_variance(ticks_per_revolution, wheels_per_side)
        self._rates: deque[Matrix] = deque(maxlen=window)
        self._geometry: Geometry | None = None
        self._b: Matrix = ()
        # Gyro mode: d pose / d(gyro bias) since the bias variance last shrank, and that
        # variance (the bias is one draw over that stretch, as the geometry above).
        self.bias_sensitivity: tuple[float, float, float] = ZERO_VEC
        self.bias_variance = 0.0
        # S over (ln r_l, ln r_r, ln b) of the geometry in use when it is not the configured
        # one (online_calibration apply: :mod:`~.ratios`); None: the model's diagonal.
        self.geometry_covariance: Matrix | None = None

    def reset(self) -> None:
        """Back to the start value (a reset or restart of the odometry); twist forgotten."""
        self.covariance = self.start
        self.sensitivity = ZERO3
        self.bias_sensitivity = ZERO_VEC
        self.forget_twist()

    def carry_on_from(self, before: PoseUncertainty) -> None:
        """Take what ``before`` accumulated: covariance, sensitivities, bias variance.

        An estimator rebuilt for new settings goes on from the old one's state without a
        jump; the twist window (rates in the old units) starts empty.
        """
        self.covariance, self.sensitivity = before.covariance, before.sensitivity
        self.bias_sensitivity, self.bias_variance = before.bias_sensitivity, before.bias_variance
        self.geometry_covariance = before.geometry_covariance

    def switch_geometry(self, covariance: Matrix | None) -> None:
        """The steps from now on integrate with another geometry, whose ``S`` is ``covariance``.

        The pose's error from the geometry so far is done: it is folded into ``P`` with the
        ``S`` it had and the sensitivity starts over (as the gyro's bias does when its
        variance shrinks), so the published covariance never drops at the switch.
        """
        self.covariance = add3(self.covariance, self._geometry_term())
        self.sensitivity = ZERO3
        self.geometry_covariance = covariance

    def _geometry_term(self) -> Matrix:
        """``J S J^T``: the model's diagonal ``S``, or the geometry in use's own."""
        s = self.geometry_covariance
        if s is not None:
            return congruence3(self.sensitivity, s)
        model = self.model
        return geometry_term(self.sensitivity, model.radius_stddev_ratio,
                             model.separation_stddev_ratio)

    def forget_twist(self) -> None:
        """Empty the twist window (the estimator forgot its rates)."""
        self._rates.clear()

    @property
    def rates(self) -> tuple[Matrix, ...]:
        """The twist window: each step's rate covariance, oldest first."""
        return tuple(self._rates)

    def set_rates(self, rates: Sequence[Matrix]) -> None:
        """Replace the twist window (a bulk integrator hands its steps back)."""
        self._rates.clear()
        self._rates.extend(rates)

    def propagate(
        self,
        pose_before: Pose2D,
        geometry: Geometry,
        *,
        ds: float,
        dtheta: float,
        d_left: float,
        d_right: float,
        dt: float,
    ) -> None:
        """One CIR step from ``pose_before`` by joint increments ``d_left``, ``d_right``."""
        f_pose, f_step = compose_jacobians(pose_before, ds, dtheta)
        b = self._wheel_jacobian(geometry)
        var_l, var_r = joint_variances(self.model, geometry, d_left, d_right)
        var_rot = rotation_variance(self.model, dtheta)
        p = add3(congruence3(f_pose, self.covariance),
                 wheel_noise3(times2x2(f_step, b), var_l, var_r))
        self.covariance = add3(p, outer3(rotation_column(f_step), var_rot)) if var_rot else p
        self.sensitivity = _sensitivity_step(self.sensitivity, f_pose, f_step, ds, dtheta,
                                             geometry.separation)
        if self.bias_sensitivity is not ZERO_VEC:
            self.bias_sensitivity = rotate_sensitivity(f_pose, self.bias_sensitivity)
        q = 2.0 * self._quantum  # the step's two readings
        scale = 1.0 / (dt * dt)
        (t00, t01), (_, t11) = wheel_noise2(b, (var_l + q) * scale, (var_r + q) * scale)
        self._rates.append(((t00, t01), (t01, t11 + var_rot * scale)))

    def propagate_gyro(
        self,
        pose_before: Pose2D,
        step: GyroStep,
        *,
        d_left: float,
        d_right: float,
        geometry: Geometry,
        bias_variance: float,
    ) -> None:
        """One CIR step whose ``(ds, dtheta) = B d + c g`` (:mod:`~.estimation.gyro`).

        The wheels' noise enters through ``B``, the gyro's white noise through ``c``
        (heading variance ``noise_density^2 dt`` per step instead of the wheels'), its
        bias error through the sensitivity ``dt f_step c`` carried like the geometry's.
        When a zero-velocity update shrank the bias variance, the stretch before is
        folded into ``P`` with the variance it had (its error is done) and starts over.
        """
        if bias_variance < self.bias_variance:
            jb = self.bias_sensitivity
            self.covariance = add3(self.covariance, outer3(jb, self.bias_variance))
            self.bias_sensitivity = ZERO_VEC
        self.bias_variance = bias_variance
        f_pose, f_step = compose_jacobians(pose_before, step.ds, step.dtheta)
        var_l, var_r = joint_variances(self.model, geometry, d_left, d_right)
        fc = times_vec(f_step, step.c)
        self.covariance = add3(
            add3(congruence3(f_pose, self.covariance),
                  wheel_noise3(times2x2(f_step, step.b), var_l, var_r)),
            outer3(fc, step.var_gyro))
        (j0, j1, j2), ((g00, g01, g02), (g10, g11, g12)) = self.sensitivity, step.geometry
        a, b = f_pose[0][2], f_pose[1][2]
        (f00, f01), (f10, f11), (_, f21) = f_step
        self.sensitivity = (  # F_pose J + F_step G, written out as _sensitivity_step
            (j0[0] + a * j2[0] + f00 * g00 + f01 * g10, j0[1] + a * j2[1] + f00 * g01 + f01 * g11,
             j0[2] + a * j2[2] + f00 * g02 + f01 * g12),
            (j1[0] + b * j2[0] + f10 * g00 + f11 * g10, j1[1] + b * j2[1] + f10 * g01 + f11 * g11,
             j1[2] + b * j2[2] + f10 * g02 + f11 * g12),
            (j2[0] + f21 * g10, j2[1] + f21 * g11, j2[2] + f21 * g12))
        jb = rotate_sensitivity(f_pose, self.bias_sensitivity)
        self.bias_sensitivity = (jb[0] + step.dt * fc[0], jb[1] + step.dt * fc[1],
                                 jb[2] + step.dt * fc[2])
        q = 2.0 * self._quantum
        scale = 1.0 / (step.dt * step.dt)
        (c0, c1) = step.c
        (t00, t01), (_, t11) = wheel_noise2(step.b, (var_l + q) * scale, (var_r + q) * scale)
        vg = step.var_gyro * scale + bias_variance
        self._rates.append(((t00 + c0 * c0 * vg, t01 + c0 * c1 * vg),
                            (t01 + c0 * c1 * vg, t11 + c1 * c1 * vg)))

    def _wheel_jacobian(self, geometry: Geometry) -> Matrix:
        """:func:`wheel_jacobian`, kept while the geometry object stays the same."""
        if geometry is not self._geometry:
            self._geometry, self._b = geometry, wheel_jacobian(geometry)
        return self._b

    def pose_covariance(self, pose: Pose2D, geometry: Geometry) -> Matrix:
        """Covariance of ``pose``: wheel noise, geometry uncertainty, quantization floor."""
        model = self.model
        cov = self.covariance
        if (model.radius_stddev_ratio or model.separation_stddev_ratio
                or self.geometry_covariance is not None):
            cov = add3(cov, self._geometry_term())
        if self.bias_sensitivity is not ZERO_VEC:
            jb = self.bias_sensitivity
            cov = add3(cov, outer3(jb, self.bias_variance))
        if self._quantum == 0.0:
            return cov
        _, at_heading = compose_jacobians(Pose2D(0.0, 0.0, pose.theta), 0.0, 0.0)
        w = times2x2(at_heading, self._wheel_jacobian(geometry))
        q = 2.0 * self._quantum  # the reference and the current reading
        return add3(cov, wheel_noise3(w, q, q))

    def twist_covariance(self) -> Matrix:
        """Covariance of the rolling-mean twist (vx, wz); zero before a step is integrated."""
        rates = self._rates
        n = len(rates)
        if n == 0:
            return ((0.0, 0.0), (0.0, 0.0))
        if n == 1:
            return rates[0]  # the mean of one step is that step (``v / 1`` is ``v``)
        (t00, t01), (t10, t11) = rates[0]
        for (r00, r01), (r10, r11) in islice(rates, 1, None):
            t00, t01, t10, t11 = t00 + r00, t01 + r01, t10 + r10, t11 + r11
        nn = n * n
        return ((t00 / nn, t01 / nn), (t10 / nn, t11 / nn))


def covariance_matrix(diagonal: Sequence[float]) -> list[float]:
    """6x6 row-major covariance with the given diagonal (what Odometry messages carry)."""
    cov = [0.0] * 36
    for i, d in enumerate(diagonal):
        cov[7 * i] = float(d)
    return cov
