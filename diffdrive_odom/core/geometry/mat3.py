"""Small matrices written out: the 3x3 and 3x2 products covariance propagation needs.

Pure Python. They run once per reading (or several times, with the gyro), and on
matrices this small numpy's or a loop's overhead costs several times the arithmetic;
each product keeps a symmetric result symmetric by construction.
"""

from __future__ import annotations

from collections.abc import Sequence

Matrix = tuple[tuple[float, ...], ...]


def outer3(u: Sequence[float], scale: float) -> Matrix:
    """``scale u u^T`` for a 3-vector."""
    u0, u1, u2 = u[0] * scale, u[1] * scale, u[2] * scale
    return symmetric(u0 * u[0], u0 * u[1], u0 * u[2], u1 * u[1], u1 * u[2], u2 * u[2])


def times_vec(a: Matrix, v: tuple[float, float]) -> tuple[float, float, float]:
    """``A v`` for a 3x2 ``A``."""
    return (a[0][0] * v[0] + a[0][1] * v[1], a[1][0] * v[0] + a[1][1] * v[1],
            a[2][0] * v[0] + a[2][1] * v[1])


def rotate_sensitivity(f_pose: Matrix, j: tuple[float, float, float]
                        ) -> tuple[float, float, float]:
    """``F_pose j`` for ``F_pose = [[1, 0, a], [0, 1, b], [0, 0, 1]]``."""
    return (j[0] + f_pose[0][2] * j[2], j[1] + f_pose[1][2] * j[2], j[2])


def add3(a: Matrix, b: Matrix) -> Matrix:
    """``A + B`` for 3x3 matrices (written out, as :func:`congruence3`)."""
    (a00, a01, a02), (a10, a11, a12), (a20, a21, a22) = a
    (b00, b01, b02), (b10, b11, b12), (b20, b21, b22) = b
    return ((a00 + b00, a01 + b01, a02 + b02),
            (a10 + b10, a11 + b11, a12 + b12),
            (a20 + b20, a21 + b21, a22 + b22))


def times2x2(a: Matrix, b: Matrix) -> Matrix:
    """``A B`` for a 3x2 ``A`` and a 2x2 ``B``."""
    (a00, a01), (a10, a11), (a20, a21) = a
    (b00, b01), (b10, b11) = b
    return ((a00 * b00 + a01 * b10, a00 * b01 + a01 * b11),
            (a10 * b00 + a11 * b10, a10 * b01 + a11 * b11),
            (a20 * b00 + a21 * b10, a20 * b01 + a21 * b11))


def symmetric(m00: float, m01: float, m02: float, m11: float, m12: float,
               m22: float) -> Matrix:
    """The symmetric 3x3 matrix with these upper-triangle entries."""
    return ((m00, m01, m02), (m01, m11, m12), (m02, m12, m22))


def congruence3(j: Matrix, m: Matrix) -> Matrix:
    """``J M J^T`` for 3x3 ``J`` and symmetric ``M``, symmetric by construction.

    Written out: it runs once per reading, and on 3x3 matrices numpy's or a loop's
    overhead costs several times the arithmetic.
    """
    (j00, j01, j02), (j10, j11, j12), (j20, j21, j22) = j
    (m00, m01, m02), (_, m11, m12), (_, _, m22) = m
    # rows of J M
    a00 = j00 * m00 + j01 * m01 + j02 * m02
    a01 = j00 * m01 + j01 * m11 + j02 * m12
    a02 = j00 * m02 + j01 * m12 + j02 * m22
    a10 = j10 * m00 + j11 * m01 + j12 * m02
    a11 = j10 * m01 + j11 * m11 + j12 * m12
    a12 = j10 * m02 + j11 * m12 + j12 * m22
    a20 = j20 * m00 + j21 * m01 + j22 * m02
    a21 = j20 * m01 + j21 * m11 + j22 * m12
    a22 = j20 * m02 + j21 * m12 + j22 * m22
    return symmetric(
        a00 * j00 + a01 * j01 + a02 * j02,
        a00 * j10 + a01 * j11 + a02 * j12,
        a00 * j20 + a01 * j21 + a02 * j22,
        a10 * j10 + a11 * j11 + a12 * j12,
        a10 * j20 + a11 * j21 + a12 * j22,
        a20 * j20 + a21 * j21 + a22 * j22,
    )


def wheel_noise3(g: Matrix, var_l: float, var_r: float) -> Matrix:
    """``G diag(var_l, var_r) G^T`` for a 3x2 ``G``."""
    (g00, g01), (g10, g11), (g20, g21) = g
    return symmetric(
        g00 * g00 * var_l + g01 * g01 * var_r,
        g00 * g10 * var_l + g01 * g11 * var_r,
        g00 * g20 * var_l + g01 * g21 * var_r,
        g10 * g10 * var_l + g11 * g11 * var_r,
        g10 * g20 * var_l + g11 * g21 * var_r,
        g20 * g20 * var_l + g21 * g21 * var_r,
    )


def wheel_noise2(b: Matrix, var_l: float, var_r: float) -> Matrix:
    """``B diag(var_l, var_r) B^T`` for a 2x2 ``B``."""
    (b00, b01), (b10, b11) = b
    cross = b00 * b10 * var_l + b01 * b11 * var_r
    return ((b00 * b00 * var_l + b01 * b01 * var_r, cross),
            (cross, b10 * b10 * var_l + b11 * b11 * var_r))
