"""The CIR elementary transform and its composition with the pose.

After Furlan, Marzorati and Sorrenti, "2D transforms for the odometry of a
differential kinematics mobile robot" (see doc/references.md).

Between two encoder readings the robot turns by ``dtheta`` about the instantaneous
centre of rotation (CIR), a distance ``R = ds / dtheta`` to its left. Composing the
three primitive transforms (to the CIR, rotate by ``dtheta``, back) gives the
elementary transform

    T = [[cos dtheta, -sin dtheta, R sin dtheta        ],
         [sin dtheta,  cos dtheta, R (1 - cos dtheta)  ],
         [0,           0,          1                   ]]

Written that way it divides by a vanishing angle on straight lines. The same
translation is the chord of the arc: length ``ds * sinc(dtheta / 2)`` at the
mid-step heading ``dtheta / 2``, because ``R sin a = ds sinc(a)`` and
``R (1 - cos a) = ds sin(a/2) sinc(a/2)``. ``sinc(x) = sin(x) / x`` is accurate to
the last bit for every non-zero float (``sin`` is correctly rounded near zero) and
is exactly 1 at zero, so the straight-line limit is the same formula, not a switch
to an approximation. The midpoint (RK2) step of Carroll and Jha ("Differential Drive
Kinematics", ELEC6530) is this chord with ``sinc`` replaced by 1.

Every function here takes a float or a numpy array (the batch form used by replay
and calibration), so the step's math lives in this one place, together with its
Jacobian for covariance propagation.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from diffdrive_odom.core.geometry.se2 import wrap_angle

Array = npt.NDArray[np.float64]


def sinc(x: float) -> float:
    """Unnormalised sinc ``sin(x)/x``, exactly 1 at 0."""
    return math.sin(x) / x if x != 0.0 else 1.0


def sinc_array(x: Array) -> Array:
    """Element-wise :func:`sinc` for arrays."""
    out = np.ones_like(x)
    np.divide(np.sin(x), x, out=out, where=x != 0.0)
    return out


def chord_array(ds: Array, dtheta: Array) -> tuple[Array, Array]:
    """``sinc(dtheta / 2)`` and the chord ``ds * sinc(dtheta / 2)`` of many steps.

    The array form of the chord in :func:`cir_increment`, computed once by a caller that
    needs it for the pose and for its Jacobians (the fast lane).
    """
    sinc_half = sinc_array(0.5 * dtheta)
    return sinc_half, ds * sinc_half


def sinc_derivative(x: float) -> float:
    """``d sinc / dx``; only for Jacobians, where a series below 1e-3 is exact to 1e-22."""
    if abs(x) < 1e-3:
        x2 = x * x
        return x * (-1.0 / 3.0 + x2 * (1.0 / 30.0 - x2 / 840.0))
    return (math.cos(x) - math.sin(x) / x) / x


def sinc_derivative_array(x: Array) -> Array:
    """Element-wise :func:`sinc_derivative` for arrays (the same series near 0)."""
    x2 = x * x
    series = x * (-1.0 / 3.0 + x2 * (1.0 / 30.0 - x2 / 840.0))
    safe = np.where(np.abs(x) < 1e-3, 1.0, x)
    return np.where(np.abs(x) < 1e-3, series, (np.cos(safe) - np.sin(safe) / safe) / safe)


@dataclass(frozen=True)
class Pose2D:
    """Planar pose; ``theta`` is kept in (-pi, pi] so precision never decays."""

    x: float = 0.0
    y: float = 0.0
    theta: float = 0.0


def cir_increment(ds: float, dtheta: float) -> tuple[float, float]:
    """Translation ``(dx, dy)`` of the elementary transform, in the previous robot frame."""
    half = 0.5 * dtheta
    chord = ds * sinc(half)
    return chord * math.cos(half), chord * math.sin(half)


def compose(pose: Pose2D, ds: float, dtheta: float) -> Pose2D:
    """``T_t^W = T_{t-1}^W . T_t^{t-1}`` (Furlan, Marzorati, Sorrenti, section V)."""
    dx, dy = cir_increment(ds, dtheta)
    c, s = math.cos(pose.theta), math.sin(pose.theta)
    return Pose2D(
        pose.x + c * dx - s * dy,
        pose.y + s * dx + c * dy,
        wrap_angle(pose.theta + dtheta),
    )


def compose_jacobians(
    pose: Pose2D, ds: float, dtheta: float
) -> tuple[tuple[tuple[float, ...], ...], tuple[tuple[float, ...], ...]]:
    """Jacobians of :func:`compose` w.r.t. the pose (3x3) and the step ``(ds, dtheta)`` (3x2).

    Exact derivatives of the same chord form, for propagating covariance through the
    step without re-deriving (and possibly contradicting) its math elsewhere.
    """
    half = 0.5 * dtheta
    sh = sinc(half)
    chord = ds * sh
    heading = pose.theta + half
    ch, shd = math.cos(heading), math.sin(heading)
    f_pose = (
        (1.0, 0.0, -chord * shd),
        (0.0, 1.0, chord * ch),
        (0.0, 0.0, 1.0),
    )
    dchord_dtheta = 0.5 * ds * sinc_derivative(half)
    f_step = (
        (sh * ch, dchord_dtheta * ch - 0.5 * chord * shd),
        (sh * shd, dchord_dtheta * shd + 0.5 * chord * ch),
        (0.0, 1.0),
    )
    return f_pose, f_step


def integrate_batch(
    ds: Array, dtheta: Array, start: Pose2D = Pose2D()
) -> tuple[Array, Array, Array]:
    """Poses after each of many steps at once (headings by cumulative sum).

    The vectorised twin of calling :func:`compose` in a loop, used to replay whole
    bags and inside calibration's fitting loop. Returns ``x, y, theta`` (theta
    unwrapped, i.e. continuous, as a plot or an error metric wants it).
    """
    ds = np.asarray(ds, dtype=np.float64)
    dtheta = np.asarray(dtheta, dtype=np.float64)
    theta_after = start.theta + np.cumsum(dtheta)
    theta_before = np.concatenate(([start.theta], theta_after[:-1]))
    half = 0.5 * dtheta
    _, chord = chord_array(ds, dtheta)
    heading = theta_before + half
    x = start.x + np.cumsum(chord * np.cos(heading))
    y = start.y + np.cumsum(chord * np.sin(heading))
    return x, y, theta_after
