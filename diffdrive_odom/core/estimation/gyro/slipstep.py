"""A slipping step's distance: the other wheel and the gyro, or the wheels' mean.

Why a rule of its own: it decides what a flagged step does to the position, and on a
real robot it can make the position worse. When a wheel spins it reads more than it
rolled, so the wheel with the shorter arc and the gyro's turn give the distance
(Borenstein and Feng keep the gyro's heading; the distance is this package's). That
holds for a spin, which goes on step after step (the simulated spins, the TurtleBot3
sim bag's slips: there the wheels' mean ends 0.070 m and 0.10 m off). On recordings of a
real base the steps flagged at a start, a stop or a jolt are the two streams' timing:
a Kobuki's driver reads its counters up to a period late, its IMU's stamps are up to
0.2 s after the wheels', and a wheel speeding up turns the robot on the wheels before
the gyro says so. There the other wheel made the position worse (phil_train run 0: ATE
0.0223 m against 0.0198 m with the wheels' mean). So the other wheel is taken once the
run of flagged steps, this one included, disagrees in distance (what the wheel that
spun read against what the other wheel and the gyro say it rolled, summed) by more than
the wheels' speed difference times :data:`SPIN_SIGMAS` of how far the two streams'
stamps may be apart (the jitter at both ends and the measured IMU lag): a spin's excess
adds up, a timing error's does not; and a wheel that read nothing did not spin. Else
the distance is the wheels' mean, as the wheels alone have it. The heading is the
gyro's either way. Run 0 as decided: 0.0195 m.
"""

from __future__ import annotations

from diffdrive_odom.core.geometry.kinematics import Geometry
from diffdrive_odom.core.uncertainty.propagation import GyroStep

Matrix = tuple[tuple[float, ...], ...]

__all__ = ["SPIN_SIGMAS", "slip_step"]

# Sigmas of the streams' timing a run's excess must pass (at the wheels' speed difference)
# to be a spin: 3 keeps the simulated spins from their second step on and the TurtleBot3
# bag's slips, and drops the Kobuki's flagged starts and stops.
SPIN_SIGMAS = 3.0


def slip_step(geometry: Geometry, ratios: tuple[float, float], arcs: tuple[float, float],
              g: float, dt: float, b: Matrix, var_gyro: float, spun: float,
              timing: float, other_wheel: bool) -> tuple[GyroStep, float]:
    """A flagged interval's step and the spinning wheel's excess over what it rolled [m].

    The step: the gyro's heading ``g``, the distance as above; the excess 0 for none.
    ``ratios``: ``(u, v) = (r_R/b, r_L/b)`` the wheels' turn was judged with;
    ``b``: the wheels' Jacobian; ``spun``: the excess of the run's steps before this one;
    ``timing``: :data:`SPIN_SIGMAS` times how far the two streams' stamps may be apart [s];
    ``other_wheel``: ``slip_distance_from_other_wheel``.
    """
    s_l, s_r = arcs
    u, v = ratios
    left_rolled = abs(s_l) <= abs(s_r)  # the right wheel spun: the left one is trusted
    half = 0.5 * (geometry.left_radius / v if left_rolled else geometry.right_radius / u)
    spun_arc, rolled = ((s_r, s_l + 2.0 * half * g) if left_rolled
                        else (s_l, s_r - 2.0 * half * g))
    late = timing * abs(s_r - s_l) / dt
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
