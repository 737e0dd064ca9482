"""The propagated covariance (:mod:`~.propagation`) over many steps at once.

The fast lane's (:mod:`diffdrive_odom.core.bulk.fastlane`) array form of
:meth:`~diffdrive_odom.core.uncertainty.propagation.PoseUncertainty.propagate` and
:meth:`~diffdrive_odom.core.uncertainty.propagation.PoseUncertainty.pose_covariance`, same model
(Chong and Kleeman's wheel noise and the turn's own noise, :mod:`~.noise`, through
the exact CIR step's Jacobians of Furlan, Marzorati and Sorrenti; Kelly's geometry
sensitivity), tested against the scalar recursion.

Why cumulative sums suffice: the step's Jacobian w.r.t. the previous pose is
``F_k = [[1, 0, a_k], [0, 1, b_k], [0, 0, 1]]`` with ``(a_k, b_k) = (-dy_k, dx_k)`` the
step's world displacement (``-chord sin(heading)``, ``chord cos(heading)``). Such
matrices add their corners when multiplied, so ``Phi(n, k) = F_n ... F_{k+1}`` has
corners ``(A_n - A_k, B_n - B_k)``, ``A``, ``B`` the cumulative sums of ``a``, ``b``:
they depend on position differences only. Unrolling ``P_n = F_n P_{n-1} F_n^T + N_n``
(``N_k = G_k Q_k G_k^T``, ``N_0 = P_0`` at ``A_0 = B_0 = 0``) gives
``P_n = sum_{k<=n} Phi(n, k) N_k Phi(n, k)^T``; with ``u = A_n - A_k``, ``v = B_n - B_k``

    (Phi N Phi^T)_00 = N00 + 2 u N02 + u^2 N22      _01 = N01 + u N12 + v N02 + u v N22
    (Phi N Phi^T)_02 = N02 + u N22                  _11 = N11 + 2 v N12 + v^2 N22
    (Phi N Phi^T)_12 = N12 + v N22                  _22 = N22

and expanding the powers of ``u`` and ``v`` leaves cumulative sums over ``k`` of
``N`` weighted by ``1, A_k, B_k, A_k^2, A_k B_k, B_k^2`` (:func:`propagated`). The
sensitivity ``J <- F_k J + F_step G`` is a sum already: its last row accumulates, and
its first two rows add ``a_k`` (``b_k``) times the last row before the step.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from diffdrive_odom.core.geometry.integration import sinc_derivative_array
from diffdrive_odom.core.geometry.kinematics import Geometry
from diffdrive_odom.core.geometry.mat3 import Matrix
from diffdrive_odom.core.uncertainty.noise import (
    NoiseModel,
    joint_variances,
    quantization_variance,
    rotation_variance,
)
from diffdrive_odom.core.uncertainty.propagation import wheel_jacobian

Array = npt.NDArray[np.float64]
SYM = ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))  # the 6 entries of a symmetric 3x3


def chain_sum(start: float, *terms: Array) -> Array:
    """``v_k = ((v_{k-1} + t1_k) + t2_k) + ...`` after each step: the scalar's order of sums."""
    m, t = len(terms[0]), len(terms)
    seq = np.empty(1 + m * t)
    seq[0] = start
    for i, term in enumerate(terms):
        seq[1 + i::t] = term
    return np.cumsum(seq)[t::t]


def propagated(p0: Matrix, a: Array, b: Array, noise: Array) -> Array:
    """``P`` after each step (rows of the 6 entries of :data:`SYM`), in closed form.

    ``p0``: the start covariance; ``a``, ``b``: each step's ``F_pose`` corners;
    ``noise``: (m, 6) each step's ``N_k``.
    """
    n = np.vstack(([p0[r][c] for r, c in SYM], noise))
    big_a = np.concatenate(([0.0], np.cumsum(a)))
    big_b = np.concatenate(([0.0], np.cumsum(b)))

    def s(w: Array) -> Array:
        return np.cumsum(w)[1:]

    n00, n01, n02, n11, n12, n22 = n.T
    s00, s01, s02, s11, s12, s22 = s(n00), s(n01), s(n02), s(n11), s(n12), s(n22)
    sa02, sa12, sa22 = s(big_a * n02), s(big_a * n12), s(big_a * n22)
    sb02, sb12, sb22 = s(big_b * n02), s(big_b * n12), s(big_b * n22)
    saa, sbb, sab = s(big_a * big_a * n22), s(big_b * big_b * n22), s(big_a * big_b * n22)
    an, bn = big_a[1:], big_b[1:]
    return np.column_stack((
        s00 + 2.0 * (an * s02 - sa02) + an * an * s22 - 2.0 * an * sa22 + saa,
        s01 + an * s12 - sa12 + bn * s02 - sb02 + an * bn * s22 - an * sb22 - bn * sa22 + sab,
        s02 + an * s22 - sa22,
        s11 + 2.0 * (bn * s12 - sb12) + bn * bn * s22 - 2.0 * bn * sb22 + sbb,
        s12 + bn * s22 - sb22,
        s22,
    ))


def _noise3(g: Sequence[Array], var_l: Array, var_r: Array) -> Array:
    """``G diag(var_l, var_r) G^T`` for each step's 3x2 ``G`` (rows ``g[0..5]``): (m, 6)."""
    g00, g01, g10, g11, g20, g21 = g
    rows = ((g00, g01), (g10, g11), (g20, g21))
    return np.column_stack([rows[r][0] * rows[c][0] * var_l + rows[r][1] * rows[c][1] * var_r
                            for r, c in SYM])


def _outer3(u: Sequence[Array], var: Array) -> Array:
    """``var u u^T`` for each step's 3-vector ``u``: (m, 6)."""
    return np.column_stack([u[r] * u[c] * var for r, c in SYM])


@dataclass(frozen=True)
class CovarianceState:
    """What :class:`PoseUncertainty` carries from step to step: ``P``, ``J``, twist window."""

    covariance: Matrix
    sensitivity: Matrix
    rates: tuple[Matrix, ...]


@dataclass(frozen=True)
class BulkModel:
    """The covariance model of :class:`PoseUncertainty`, as its constructor takes it."""

    noise: NoiseModel
    geometry: Geometry
    ticks_per_revolution: float
    wheels_per_side: int
    window: int  # the twist's rolling window (velocity_rolling_window_size)


@dataclass(frozen=True)
class BulkSteps:
    """Many steps (arrays of one length), as the fast lane integrated them.

    ``sinc_half`` and ``chord`` are the step's ``sinc(dtheta / 2)`` and chord length
    (:func:`~diffdrive_odom.core.geometry.integration.chord_array`), computed once for
    the pose and the covariance alike; ``before`` / ``after``: the wrapped headings
    before and after each step.
    """

    dt: Array
    ds: Array
    dtheta: Array
    d_left: Array
    d_right: Array
    sinc_half: Array
    chord: Array
    before: Array
    after: Array


@dataclass(frozen=True)
class BulkCovariance:
    """What is published after each step and the state after the last one.

    ``pose``: (m, 6) the pose covariance's entries of :data:`SYM`; ``twist``: (m, 3)
    ``vv, vw, ww``.
    """

    pose: Array
    twist: Array
    end: CovarianceState


def bulk_covariance(
    model: BulkModel, start: CovarianceState, steps: BulkSteps
) -> BulkCovariance | None:
    """:func:`_bulk_covariance` with numpy's overflow warnings off.

    A covariance that overflows is an outcome here (None: not finite, refused as the
    scalar path refuses its inf), not a fault.
    """
    with np.errstate(over="ignore", invalid="ignore"):
        return _bulk_covariance(model, start, steps)


def _bulk_covariance(
    model: BulkModel, start: CovarianceState, steps: BulkSteps
) -> BulkCovariance | None:
    """What :class:`PoseUncertainty` holds and publishes after each of many steps.

    None if anything is not finite.
    """
    dt, ds, dth, d_left, d_right = steps.dt, steps.ds, steps.dtheta, steps.d_left, steps.d_right
    sh, chord, before, after = steps.sinc_half, steps.chord, steps.before, steps.after
    geometry, noise, window = model.geometry, model.noise, model.window
    (b00, b01), (b10, b11) = wheel_jacobian(geometry)
    half = 0.5 * dth
    heading = before + half
    ch, shd = np.cos(heading), np.sin(heading)
    dcd = 0.5 * ds * sinc_derivative_array(half)
    f00, f01 = sh * ch, dcd * ch - 0.5 * chord * shd
    f10, f11 = sh * shd, dcd * shd + 0.5 * chord * ch
    g = (f00 * b00 + f01 * b10, f00 * b01 + f01 * b11, f10 * b00 + f11 * b10,
         f10 * b01 + f11 * b11, np.full_like(ds, b10), np.full_like(ds, b11))
    var_l, var_r = joint_variances(noise, geometry, d_left, d_right)
    var_rot = rotation_variance(noise, dth)
    p0, j0, rates0 = start.covariance, start.sensitivity, start.rates
    a, b = -chord * shd, chord * ch
    step_noise = _noise3(g, var_l, var_r)
    if noise.k_rotation:  # the turn's own noise, through the step's d pose / d dtheta
        step_noise = step_noise + _outer3((f01, f11, np.ones_like(ds)), var_rot)
    p = propagated(p0, a, b, step_noise)
    sep = geometry.separation
    hs = 0.5 * dth * sep
    s_l, s_r = ds - hs, ds + hs
    gg = ((0.5 * s_l, 0.5 * s_r, np.zeros_like(ds)), (-s_l / sep, s_r / sep, -dth))
    j2 = [chain_sum(j0[2][col], gg[1][col]) for col in range(3)]
    j2_before = [np.concatenate(([j0[2][col]], j2[col][:-1])) for col in range(3)]
    j0r = [chain_sum(j0[0][col], a * j2_before[col], f00 * gg[0][col], f01 * gg[1][col])
           for col in range(2)]
    j0r.append(chain_sum(j0[0][2], a * j2_before[2], f01 * gg[1][2]))
    j1r = [chain_sum(j0[1][col], b * j2_before[col], f10 * gg[0][col], f11 * gg[1][col])
           for col in range(2)]
    j1r.append(chain_sum(j0[1][2], b * j2_before[2], f11 * gg[1][2]))
    jac = (j0r, j1r, j2)
    published = p
    vr = noise.radius_stddev_ratio ** 2
    vb = noise.separation_stddev_ratio ** 2
    if noise.radius_stddev_ratio or noise.separation_stddev_ratio:
        published = published + np.column_stack([
            vr * (jac[r][0] * jac[c][0] + jac[r][1] * jac[c][1]) + vb * jac[r][2] * jac[c][2]
            for r, c in SYM])
    q = 2.0 * quantization_variance(model.ticks_per_revolution, model.wheels_per_side)
    if q != 0.0:
        c, s = np.cos(after), np.sin(after)
        w = (c * b00, c * b01, s * b00, s * b01, np.full_like(ds, b10), np.full_like(ds, b11))
        published = published + _noise3(w, np.full_like(ds, q), np.full_like(ds, q))
    scale = 1.0 / (dt * dt)
    rl, rr = (var_l + q) * scale, (var_r + q) * scale
    rate = np.column_stack((b00 * b00 * rl + b01 * b01 * rr, b00 * b10 * rl + b01 * b11 * rr,
                            b10 * b10 * rl + b11 * b11 * rr + var_rot * scale))
    prior = np.array([(m[0][0], m[0][1], m[1][1]) for m in rates0]).reshape(-1, 3)
    comb = np.vstack((prior, rate))
    m = len(ds)
    counts = np.minimum(np.arange(len(prior) + 1, len(prior) + m + 1), window).astype(float)
    padded = np.vstack((np.zeros((window - 1, 3)), comb))
    sums = np.lib.stride_tricks.sliding_window_view(padded, window, axis=0)[
        len(prior):len(prior) + m].sum(axis=2)
    twist = sums / (counts * counts)[:, None]
    if not (np.isfinite(published).all() and np.isfinite(twist).all()):
        return None
    end_p = p[-1].tolist()
    p_end = ((end_p[0], end_p[1], end_p[2]), (end_p[1], end_p[3], end_p[4]),
             (end_p[2], end_p[4], end_p[5]))
    j_end = tuple(tuple(float(jac[r][col][-1]) for col in range(3)) for r in range(3))
    rates_end = tuple(((float(r0), float(r1)), (float(r1), float(r2)))
                      for r0, r1, r2 in comb[-window:].tolist())
    return BulkCovariance(pose=published, twist=twist,
                          end=CovarianceState(covariance=p_end, sensitivity=j_end,
                                              rates=rates_end))
