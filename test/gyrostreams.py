"""Realistic gyro and wheel streams with their truth: each sensor on its own clock.

Shared by the gyrodometry tests (core, replay, node). A robot drives a route of
segments of constant twist, each reached by a linear ramp (no robot jumps from one
twist to another), with scripted slips: a wheel spins faster than it rolls for a
while, so the wheels see heading the robot never turned. Its truth (pose, heading,
the wheels' joint angles) is integrated here on a 0.1 ms grid, independently of the
package: heading and joint angles are exact (the twist is piecewise linear and the
grid holds its knots; trapezoids are exact on it), the position by the midpoint rule
(error about 1e-9 m over a minute).

The wheels (``wheel_hz``) stamp with the receiver's clock at their measurement time
and arrive ``wheel_latency`` later; the IMU runs on its own clock: its own rate
(``imu_hz``, no multiple of the wheels' needed) and phase, its header stamps
``imu_offset`` off the true measurement time (its device clock, or a driver stamping
late or early), a stamp jitter, a transport latency and jitter of its own, and
optionally a dropout. :func:`stream` gives the messages in receive-time order, as a
node sees them (and as a bag's log time records them). Nothing here calls the
package.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

R, B = 0.05, 0.3  # the wheels' radius and separation [m]
NAMES = ("left_wheel_joint", "right_wheel_joint")
T0 = 1_700_000_000_000_000_000  # ns: a wall-clock epoch, as a live robot's stamps
GRID = 1e-4  # s: the truth's integration grid
RAMP = 0.4  # s: every change of twist takes this long


@dataclass(frozen=True)
class Slip:
    """A wheel (``right``: the right one) spinning ``rate`` rad/s faster than it rolls
    from ``start`` for ``seconds`` (no ground motion): the wheels' heading goes wrong
    by ``R * rate * seconds / B`` (right) or its negative (left)."""

    start: float
    seconds: float
    rate: float
    right: bool = True

    @property
    def heading_error(self) -> float:
        """The wheels' heading minus the truth's after the slip [rad]."""
        return (1.0 if self.right else -1.0) * R * self.rate * self.seconds / B


@dataclass(frozen=True)
class Route:
    """Segments ``(seconds, v, w)`` after ``stand`` s still, ending ``stand_end`` s still."""

    segments: tuple[tuple[float, float, float], ...]
    slips: tuple[Slip, ...] = ()
    stand: float = 3.0
    stand_end: float = 3.0

    @property
    def seconds(self) -> float:
        return self.stand + sum(s[0] for s in self.segments) + self.stand_end


# The issue's run: 3 s standing, 70 s of lines and arcs with four short slips, standing.
ISSUE_ROUTE = Route(
    segments=((8.0, 0.4, 0.0), (7.0, 0.3, 0.4), (10.0, 0.5, 0.0), (6.0, 0.3, -0.5),
              (9.0, 0.4, 0.0), (8.0, 0.2, 0.6), (10.0, 0.5, 0.0), (6.0, 0.3, -0.3),
              (6.0, 0.4, 0.0)),
    slips=(Slip(10.0, 0.5, 1.2), Slip(24.0, 0.4, 1.5),
           Slip(42.0, 0.5, 1.0), Slip(60.0, 0.3, 2.0)),
)


@dataclass(frozen=True)
class Timing:
    """How the IMU's clock and transport relate to the wheels' (see the module)."""

    name: str
    wheel_hz: float = 50.0
    imu_hz: float = 200.0
    imu_phase: float = 0.0  # s: the IMU's first sample after the wheels' first
    imu_offset: float = 0.0  # s: IMU header stamp minus the true measurement time
    imu_stamp_jitter: float = 0.0  # s: uniform +- of each IMU stamp
    imu_latency: float = 0.5e-3  # s: IMU measurement to arrival
    imu_latency_jitter: float = 0.0  # s: uniform +- on it
    wheel_latency: float = 1e-3
    wheel_latency_jitter: float = 0.0
    dropout: tuple[float, float] | None = None  # s: the IMU silent over this span


# One case per ordering of IMU samples about each wheel reading.
TIMINGS = (
    # Samples at the wheel stamps, the IMU's arriving first (the old tests' order).
    Timing("aligned, IMU first", imu_latency=0.2e-3, wheel_latency=1e-3),
    # Each sample stamped just after the wheel reading of the same instant (the issue).
    Timing("stamped just after", imu_offset=0.3e-3),
    # Stamped 5 ms early (the issue's live case that gave no update at all).
    Timing("stamped 5 ms early", imu_offset=-5e-3),
    # Lagging up to an IMU period: the covering sample arrives after the wheels'.
    Timing("one period late", imu_latency=5e-3, imu_latency_jitter=1e-3),
    # A fixed latency of 20 ms (a USB IMU behind a driver's buffer).
    Timing("20 ms latency", imu_latency=20e-3),
    # Stamped 15 ms early and arriving 15 ms late: each sample 30 ms behind, more than a
    # wheel period (the wheels' steps go on before any sample of them has come).
    Timing("30 ms behind", imu_hz=186.0, imu_phase=9.8e-3, imu_offset=-15e-3,
           imu_latency=15e-3, imu_latency_jitter=0.5e-3),
    # Jittered stamps and transport, 173 Hz (no multiple of 50), its own phase.
    Timing("173 Hz jittered", imu_hz=173.0, imu_phase=1.7e-3, imu_stamp_jitter=0.5e-3,
           imu_latency=3e-3, imu_latency_jitter=2.5e-3, wheel_latency_jitter=1e-3),
    # The IMU silent for 1.5 s while driving (over imu_timeout): wheels only meanwhile.
    Timing("dropout", imu_hz=190.0, imu_latency=2e-3, dropout=(30.0, 31.5)),
)


@dataclass
class Truth:
    """The route's truth on the grid: time [s], pose, yaw rate, joint angles."""

    t: npt.NDArray[np.float64]
    x: npt.NDArray[np.float64]
    y: npt.NDArray[np.float64]
    theta: npt.NDArray[np.float64]
    w: npt.NDArray[np.float64]
    left: npt.NDArray[np.float64]
    right: npt.NDArray[np.float64]
    slips: tuple[Slip, ...] = field(default=())

    def at(self, t: float) -> tuple[float, float, float]:
        return (float(np.interp(t, self.t, self.x)), float(np.interp(t, self.t, self.y)),
                float(np.interp(t, self.t, self.theta)))


def _knots(route: Route) -> tuple[list[float], list[float], list[float]]:
    """The twist's knots: each segment's value reached by a ramp of RAMP s."""
    ts, vs, ws = [0.0, route.stand], [0.0, 0.0], [0.0, 0.0]
    t = route.stand
    for seconds, v, w in (*route.segments, (route.stand_end, 0.0, 0.0)):
        ts += [t + RAMP, t + seconds]
        vs += [v, v]
        ws += [w, w]
        t += seconds
    return ts, vs, ws


def truth(route: Route, r_left: float = R, r_right: float = R, sep: float = B) -> Truth:
    """Integrate the route on the grid (see the module for how exact).

    ``r_left``, ``r_right``, ``sep``: the robot's true geometry, which its joint angles
    follow (the nominal R, R, B by default).
    """
    n = round(route.seconds / GRID)
    t = np.arange(n + 1) * GRID
    ts, vs, ws = _knots(route)
    v, w = np.interp(t, ts, vs), np.interp(t, ts, ws)

    def cumulative(f: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
        return np.concatenate(([0.0], np.cumsum(0.5 * (f[1:] + f[:-1]) * GRID)))

    theta = cumulative(w)
    mid = 0.5 * (theta[1:] + theta[:-1])
    vm = 0.5 * (v[1:] + v[:-1])
    x = np.concatenate(([0.0], np.cumsum(vm * np.cos(mid) * GRID)))
    y = np.concatenate(([0.0], np.cumsum(vm * np.sin(mid) * GRID)))
    left = cumulative((v - 0.5 * sep * w) / r_left)
    right = cumulative((v + 0.5 * sep * w) / r_right)
    for s in route.slips:
        extra = s.rate * np.clip(t - s.start, 0.0, s.seconds)
        if s.right:
            right = right + extra
        else:
            left = left + extra
    return Truth(t.astype(np.float64), x, y, theta, w, left, right, route.slips)


# (kind, receive_ns, stamp_ns, a, b): joint ('j', left, right) or imu ('i', wz, 0).
Message = tuple[str, int, int, float, float]


def stream(route: Route, timing: Timing, bias: float = 0.0, noise_density: float = 3e-4,
           seed: int = 1, tru: Truth | None = None, scale: float = 1.0) -> list[Message]:
    """The messages of ``route`` under ``timing`` in receive-time order.

    ``bias`` [rad/s] is added to every gyro sample, white noise of density
    ``noise_density`` [rad/s/sqrt(Hz)] too (each sample's sigma: density times the
    square root of the rate); ``scale``: the gyro reads that times the true yaw rate.
    """
    rng = np.random.default_rng(seed)
    tr = tru or truth(route)
    end = route.seconds
    out: list[Message] = []
    tw = np.arange(0.0, end + 1e-9, 1.0 / timing.wheel_hz)
    lw, rw = np.interp(tw, tr.t, tr.left), np.interp(tw, tr.t, tr.right)
    lat = timing.wheel_latency + rng.uniform(-1, 1, tw.size) * timing.wheel_latency_jitter
    for k in range(tw.size):
        stamp = T0 + round(tw[k] * 1e9)
        out.append(("j", stamp + round(lat[k] * 1e9), stamp, float(lw[k]), float(rw[k])))
    ti = np.arange(timing.imu_phase, end, 1.0 / timing.imu_hz)
    if timing.dropout is not None:
        a, b = timing.dropout
        ti = ti[(ti < a) | (ti > b)]
    sigma = noise_density * math.sqrt(timing.imu_hz)
    wz = scale * np.interp(ti, tr.t, tr.w) + bias + sigma * rng.standard_normal(ti.size)
    jit = rng.uniform(-1, 1, ti.size) * timing.imu_stamp_jitter
    lat = timing.imu_latency + rng.uniform(-1, 1, ti.size) * timing.imu_latency_jitter
    for k in range(ti.size):
        stamp = T0 + round((ti[k] + timing.imu_offset + jit[k]) * 1e9)
        out.append(("i", T0 + round((ti[k] + lat[k]) * 1e9), stamp, float(wz[k]), 0.0))
    out.sort(key=lambda m: (m[1], m[0]))
    return out


def stood_until(route: Route) -> float:
    """When the first standstill ends [s]."""
    return route.stand
