"""A slipping step's distance: the other wheel and the gyro, or the wheels' mean.

Why a rule of its own: it decides what a flagged step does to the position, and on a
real robot it can make the position worse. When a wheel spins it reads more than it
rolled, so the wheel with the shorter arc and the gyro's turn give the distance
(Borenstein and Feng keep the gyro's heading; the distance is this package's). That
holds for a spin, which goes on step after step (the simulated spins, the TurtleBot3
sim bag's slips: there the wheels' mean ends 0.098 m and 0.102 m off where the other
wheel ends 0.017 m and 0.057 m). On recordings of a real base (a Kobuki's driver reading
its counters up to a period late) the steps flagged at a start, a stop or a jolt are a
step or two of the stamps' timing, and there the other wheel made the position worse
(phil_train run 0: ATE 0.0223 m against 0.0198 m). So the other wheel is taken once the
run of flagged steps, this one included, disagrees in distance (what the wheel that
spun read against what the other wheel and the gyro say it rolled, summed) by more than
:data:`SPIN_SIGMAS` of the stamps' timing error at the speed it rolled: a spin's
excess adds up, a late reading's does not; and a wheel that read nothing did not spin
(the interval over which a stopped robot's gyro still turned, 0.2 s late). Else the
distance is the wheels' mean, as the wheels alone have it. The heading is the gyro's
either way. What is left on run 0 (ATE 0.0211 m as decided, 0.0198 m with the wheels'
mean on every flagged step) comes from its IMU stamps 0.2 s after the wheels' at starts
and stops (``imu_time_offset``).
"""

from __future__ import annotations

import math

from diffdrive_odom.core.geometry.kinematics import Geometry
from diffdrive_odom.core.uncertainty.propagation import GyroStep

Matrix = tuple[tuple[float, ...], ...]

__all__ = ["SPIN_SIGMAS", "slip_step"]

# Sigmas of the stamps' timing error (at the wheel's speed) a run's excess must pass to
# be a spin: 3 keeps every simulated spin and the TurtleBot3 bag's slips (a millimetre a
# step, adding up), and drops the Kobuki's flagged starts and stops (2-3 mm once, at
# 10 ms of jitter and 0.2 m/s: 8 mm).
SPIN_SIGMAS = 3.0


def slip_step(geometry: Geometry, ratios: tuple[float, float], arcs: tuple[float, float],
              g: float, dt: float, b: Matrix, var_gyro: float, spun: float,
              jitter_sigmas: float, other_wheel: bool) -> tuple[GyroStep, float]:
    """A flagged interval's step and the spinning wheel's excess over what it rolled [m].

    The step: the gyro's heading ``g``, the distance as above; the excess 0 for none.
    ``ratios``: ``(u, v) = (r_R/b, r_L/b)`` the wheels' turn was judged with;
    ``b``: the wheels' Jacobian; ``spun``: the excess of the run's steps before this one;
    ``jitter_sigmas``: :data:`SPIN_SIGMAS` times a stamp's timing error [s];
    ``other_wheel``: ``slip_distance_from_other_wheel``.
    """
    s_l, s_r = arcs
    u, v = ratios
    left_rolled = abs(s_l) <= abs(s_r)  # the right wheel spun: the left one is trusted
    half = 0.5 * (geometry.left_radius / v if left_rolled else geometry.right_radius / u)
    spun_arc, rolled = ((s_r, s_l + 2.0 * half * g) if left_rolled
                        else (s_l, s_r - 2.0 * half * g))
    late = jitter_sigmas * math.sqrt(2.0) * abs(rolled) / dt
    excess = abs(abs(spun_arc) - abs(rolled))
    if not (other_wheel and spun_arc != 0.0 and spun + excess > late):
        return GyroStep(ds=0.5 * (s_l + s_r), dtheta=g, b=(b[0], (0.0, 0.0)), c=(0.0, 1.0),
                        var_gyro=var_gyro, dt=dt,
                        geometry=((0.5 * s_l, 0.5 * s_r, 0.0), (0.0, 0.0, 0.0)),
                        slip=True), max(excess, 0.0)
    if left_rolled:
        return GyroStep(ds=s_l + half * g, dtheta=g, b=((2.0 * b[0][0], 0.0), (0.0, 0.0)),
                        c=(half, 1.0), var_gyro=var_gyro, dt=dt,
                        geometry=((s_l, 0.0, half * g), (0.0, 0.0, 0.0)), slip=True), excess
    return GyroStep(ds=s_r - half * g, dtheta=g, b=((0.0, 2.0 * b[0][1]), (0.0, 0.0)),
                    c=(-half, 1.0), var_gyro=var_gyro, dt=dt,
                    geometry=((0.0, s_r, -half * g), (0.0, 0.0, 0.0)), slip=True), excess
