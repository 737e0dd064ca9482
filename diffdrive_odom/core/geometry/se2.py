"""SE(2) helpers on planar poses: angle wrapping and relative motion, each written once.

Pure Python + numpy. Angles wrap to (-pi, pi] everywhere: :func:`wrap_angle` for one
float (exact), :func:`wrap_angles` for arrays. A pose array has rows ``(x, y, theta)``.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]


def wrap_angle(theta: float) -> float:
    """Angle to (-pi, pi]; ``math.remainder`` is exact, unlike ``atan2(sin, cos)``."""
    wrapped = math.remainder(theta, 2.0 * math.pi)
    return math.pi if wrapped == -math.pi else wrapped


def wrap_angles(theta: npt.ArrayLike) -> FloatArray:
    """Element-wise :func:`wrap_angle` for arrays: to (-pi, pi] as well.

    numpy's ``remainder`` of the angle shifted by pi (the shift rounds, so a result
    may differ from the scalar form's exact one in its last bits, never in range).
    """
    wrapped = np.remainder(np.asarray(theta, dtype=np.float64) + np.pi, 2.0 * np.pi) - np.pi
    return np.where(wrapped == -np.pi, np.pi, wrapped)


def between(a: FloatArray, b: FloatArray) -> FloatArray:
    """Motion from poses ``a`` to poses ``b`` seen in ``a``'s frame (``a^-1 b``): (n, 3).

    ``a`` and ``b`` are (n, 3) pose rows; the heading difference is not wrapped, so
    continuous headings stay continuous.
    """
    c, s = np.cos(a[:, 2]), np.sin(a[:, 2])
    dx, dy = b[:, 0] - a[:, 0], b[:, 1] - a[:, 1]
    return np.column_stack((c * dx + s * dy, -s * dx + c * dy, b[:, 2] - a[:, 2]))


def conjugate(motion: FloatArray, x: float, y: float, yaw: float) -> FloatArray:
    """Motions (n, 3) of a frame mounted at ``(x, y, yaw)`` on a body, as the body's: ``M D M^-1``.

    The rotation is the same; the translation is ``R_m t + (I - R_D) t_m``.
    """
    cm, sm = math.cos(yaw), math.sin(yaw)
    cd, sd = np.cos(motion[:, 2]), np.sin(motion[:, 2])
    return np.column_stack((
        cm * motion[:, 0] - sm * motion[:, 1] + (1.0 - cd) * x + sd * y,
        sm * motion[:, 0] + cm * motion[:, 1] - sd * x + (1.0 - cd) * y,
        motion[:, 2]))
