"""A slipping step's distance: the other wheel and the gyro, or the wheels' mean.

Why a rule of its own: it decides what a flagged step does to the position, and on a
real robot it can make the position worse. When a wheel spins it reads more than it
rolled, so the wheel with the shorter arc and the gyro's turn give the distance
(Borenstein and Feng keep the gyro's heading; the distance is this package's). That
holds only for a spin: on recordings of a real base (a Kobuki's driver reading its
counters up to a period late) the steps flagged at a start, a stop or a jolt are no spin
of one wheel, and there the other wheel made the position worse than the wheels' mean
(phil_train run 0: ATE 0.0223 m against 0.0207 m). So the other wheel is taken only when
the spinning wheel read more than it rolled, the same way, by more than its stamps'
timing error explains (:data:`SPIN_SIGMAS` of it); else the distance is the wheels' mean,
as the wheels alone have it. The heading is the gyro's either way.
"""

from __future__ import annotations

import math

from diffdrive_odom.core.geometry.kinematics import Geometry
from diffdrive_odom.core.uncertainty.propagation import GyroStep

Matrix = tuple[tuple[float, ...], ...]

__all__ = ["SPIN_SIGMAS", "slip_step"]

# Sigmas of the spinning wheel's stamp timing error its excess must pass to be a spin:
# 2 keeps a simulated spin of 5 mm per step at 5 ms jitter, and drops the Kobuki's
# flagged starts and stops (2-3 mm of excess at 10 ms).
SPIN_SIGMAS = 2.0


def slip_step(geometry: Geometry, ratios: tuple[float, float], arcs: tuple[float, float],
              g: float, dt: float, b: Matrix, var_gyro: float, jitter_sigmas: float,
              other_wheel: bool) -> GyroStep:
    """The step of a flagged interval: the gyro's heading ``g``, the distance as above.

    ``ratios``: ``(u, v) = (r_R/b, r_L/b)`` the wheels' turn was judged with;
    ``b``: the wheels' Jacobian; ``jitter_sigmas``: :data:`SPIN_SIGMAS` times a stamp's
    timing error [s]; ``other_wheel``: ``slip_distance_from_other_wheel``.
    """
    s_l, s_r = arcs
    u, v = ratios
    left_rolled = abs(s_l) <= abs(s_r)  # the right wheel spun: the left one is trusted
    half = 0.5 * (geometry.left_radius / v if left_rolled else geometry.right_radius / u)
    spun, rolled = (s_r, s_l + 2.0 * half * g) if left_rolled else (s_l, s_r - 2.0 * half * g)
    late = jitter_sigmas * math.sqrt(2.0) * abs(rolled) / dt
    if not (other_wheel and spun * rolled >= 0.0 and abs(spun) - abs(rolled) > late):
        return GyroStep(ds=0.5 * (s_l + s_r), dtheta=g, b=(b[0], (0.0, 0.0)), c=(0.0, 1.0),
                        var_gyro=var_gyro, dt=dt,
                        geometry=((0.5 * s_l, 0.5 * s_r, 0.0), (0.0, 0.0, 0.0)), slip=True)
    if left_rolled:
        return GyroStep(ds=s_l + half * g, dtheta=g, b=((2.0 * b[0][0], 0.0), (0.0, 0.0)),
                        c=(half, 1.0), var_gyro=var_gyro, dt=dt,
                        geometry=((s_l, 0.0, half * g), (0.0, 0.0, 0.0)), slip=True)
    return GyroStep(ds=s_r - half * g, dtheta=g, b=((0.0, 2.0 * b[0][1]), (0.0, 0.0)),
                    c=(-half, 1.0), var_gyro=var_gyro, dt=dt,
                    geometry=((0.0, s_r, -half * g), (0.0, 0.0, 0.0)), slip=True)
