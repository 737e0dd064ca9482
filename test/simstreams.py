"""The simulator's base driven along a route, its wheels and gyro each on its own clock.

Shared by the online calibration tests and ``bench/bench_online.py`` (issue 25): the
core's :class:`~diffdrive_odom.core.sim.model.DiffDriveSim` with a true geometry that
is not the configured one, its gyro's bias and white noise, random ground slip and
scripted wheel spins, a motor lag (no twist jumps). The route is
:mod:`gyrostreams`'s (segments of constant twist), commanded through the TRUE
geometry's inverse kinematics (a robot that drives the route). The wheels are read
at ``timing.wheel_hz``, the gyro (the mean rate over each of its periods, as an
integrating gyro) at ``timing.imu_hz`` with its own phase, header
stamps off by ``imu_offset`` plus jitter, its own latency: the messages come in
receive-time order, as a node sees them (:mod:`gyrostreams`' timings). The truth is
the sim's own pose at each wheel reading (its physics, not the odometry's).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from gyrostreams import NAMES, T0, Message, Route, Timing

from diffdrive_odom.core.geometry.kinematics import Geometry, wheel_rates
from diffdrive_odom.core.sim.model import DiffDriveSim, SimConfig, SlipEvent

R, B = 0.05, 0.3
# The robot: 0.5 % on the right radius, 1 % on the separation.
TRUE = Geometry(R, B, right_wheel_radius_multiplier=1.005, wheel_separation_multiplier=1.01)
BIAS = math.radians(0.3)  # rad/s
DENSITY = 3.0e-4  # rad/s/sqrt(Hz)
# m after 1 m rolled: random ground slip, the ground's own scatter of the ratios (0.2 mm:
# about 0.03 % of them over 50 m; the demo's robot has 0.5 mm, about 0.07 %).
SLIP_STDDEV = 0.0002
TAU = 0.1  # s: motor time constant
SIM_TIMING = Timing("173 Hz jittered, 2 ms early", imu_hz=173.0, imu_phase=1.7e-3,
                    imu_offset=-2e-3, imu_stamp_jitter=0.5e-3, imu_latency=3e-3,
                    imu_latency_jitter=2.5e-3, wheel_latency_jitter=1e-3)

__all__ = ["NAMES", "SimStream", "sim_stream", "spins", "true_ratios"]


@dataclass
class SimStream:
    """The messages (``gyrostreams.Message``) and the truth at each wheel stamp."""

    messages: list[Message]
    truth: dict[int, tuple[float, float, float]]  # wheel stamp -> true x, y, heading unwrapped
    distance: dict[int, float]  # wheel stamp -> distance driven [m]


def true_ratios(g: Geometry = TRUE) -> tuple[float, float]:
    """``(r_R / b, r_L / b)`` of the true geometry."""
    return g.right_radius / g.separation, g.left_radius / g.separation


def spins(route: Route, every: float = 17.0) -> tuple[SlipEvent, ...]:
    """A wheel spinning 1.5 rad/s more than it rolls for 0.4 s every ``every`` s, sides
    alternating (0.1 rad of wrong heading each, which the slip test must leave out)."""
    count = int((route.seconds - route.stand - route.stand_end) // every)
    return tuple(SlipEvent("right" if k % 2 else "left", route.stand + every * (k + 0.5),
                           0.4, 1.5) for k in range(count))


def _twist(route: Route, t: float) -> tuple[float, float]:
    """The commanded twist at ``t`` (segments after ``stand`` s; zero outside)."""
    t -= route.stand
    if t < 0.0:
        return 0.0, 0.0
    for seconds, v, w in route.segments:
        if t < seconds:
            return v, w
        t -= seconds
    return 0.0, 0.0


def sim_stream(route: Route, seed: int, timing: Timing = SIM_TIMING, true: Geometry = TRUE,
               slips: bool = True, bias: float = BIAS, density: float = DENSITY,
               slip_stddev: float = SLIP_STDDEV) -> SimStream:
    """Drive ``route`` in the sim; the messages in receive order and the truth (module)."""
    sim = DiffDriveSim(SimConfig(
        true, motor_time_constant=TAU, command_timeout=0.0, seed=seed,
        slip_stddev=slip_stddev if slips else 0.0, slip_events=spins(route) if slips else (),
        gyro_bias=bias, gyro_noise_density=density))
    rng = np.random.default_rng([seed, 7])
    end = route.seconds
    tw = np.arange(0.0, end + 1e-9, 1.0 / timing.wheel_hz)
    ti = np.arange(timing.imu_phase, end, 1.0 / timing.imu_hz)
    events = sorted([(round(t * 1e9), 0) for t in tw] + [(round(t * 1e9), 1) for t in ti])
    wlat = timing.wheel_latency + rng.uniform(-1, 1, tw.size) * timing.wheel_latency_jitter
    jit = rng.uniform(-1, 1, ti.size) * timing.imu_stamp_jitter
    ilat = timing.imu_latency + rng.uniform(-1, 1, ti.size) * timing.imu_latency_jitter
    out: list[Message] = []
    truth: dict[int, tuple[float, float, float]] = {}
    distance: dict[int, float] = {}
    kw = ki = 0
    heading = 0.0  # the true heading unwrapped (the sim's pose wraps it)
    last = 0  # the previous gyro sample's time [ns]
    for t_ns, kind in events:
        sim.advance(t_ns - sim.time_ns)
        rl, rr = wheel_rates(true, *_twist(route, t_ns * 1e-9))
        sim.command([rl, rr])
        p = sim.pose
        heading += math.remainder(p.theta - heading, 2.0 * math.pi)
        if kind == 0:
            left, right = sim.joint_angles
            stamp = T0 + t_ns
            out.append(("j", stamp + round(wlat[kw] * 1e9), stamp, float(left), float(right)))
            truth[stamp] = (p.x, p.y, heading)
            distance[stamp] = sim.distance
            kw += 1
        else:
            # The sim's gyro integrates: the mean true rate since its previous read (this
            # sample's period) times its scale, plus its bias and white noise; stamped at
            # the period's middle.
            t0 = last
            rate = sim.gyro(timing.imu_hz)
            last = t_ns
            stamp = T0 + (t0 + t_ns) // 2 + round((timing.imu_offset + jit[ki]) * 1e9)
            out.append(("i", T0 + t_ns + round(ilat[ki] * 1e9), stamp, float(rate), 0.0))
            ki += 1
    out.sort(key=lambda m: (m[1], m[0]))
    return SimStream(out, truth, distance)
