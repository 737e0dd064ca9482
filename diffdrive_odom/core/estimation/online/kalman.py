"""One scalar Kalman update, the online filters' (the gyro's ratios, the reference's scale).

Pure Python on lists: the states are small (3 and 8) and the measurement vectors
sparse, where numpy's per-call cost would be most of the work.
"""

from __future__ import annotations

__all__ = ["kalman_update", "quadratic"]


def quadratic(p: list[list[float]], h: list[float]) -> float:
    """``h' P h``."""
    n = len(h)
    return sum(h[i] * p[i][j] * h[j] for i in range(n) for j in range(n) if h[i] and h[j])


def kalman_update(x: list[float], p: list[list[float]], h: list[float], e: float,
                  r: float) -> None:
    """One scalar update in place, P kept symmetric: both online filters' (ratios, scale)."""
    n = len(x)
    ph = [sum(p[i][j] * h[j] for j in range(n) if h[j]) for i in range(n)]
    s = sum(h[i] * ph[i] for i in range(n)) + r
    if s <= 0.0:
        return
    k = [v / s for v in ph]
    for i in range(n):
        x[i] += k[i] * e
        for j in range(n):
            p[i][j] -= k[i] * ph[j]
    for i in range(n):  # symmetric, as it should be
        for j in range(i):
            p[i][j] = p[j][i] = 0.5 * (p[i][j] + p[j][i])
