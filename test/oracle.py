"""Independent references for the tests: closed forms written from the geometry.

Nothing here calls the package's step (``integration.compose``, ``kinematics``,
``routes.arc``): the expected values of a test must not come from the code under test.
The package integrates with the chord form ``ds sinc(dtheta / 2)`` at the mid-step
heading (Furlan, Marzorati and Sorrenti); this file uses the textbook form instead:
a constant twist is a circle of radius ``R = ds / dtheta`` about the instantaneous
centre of rotation, so from heading ``th``

    x' = x + R (sin(th + dtheta) - sin th),   y' = y - R (cos(th + dtheta) - cos th),

and a straight line when ``dtheta`` is 0 (Carroll and Jha, "Differential Drive
Kinematics", integrate x' = v cos th, y' = v sin th, th' = w the same way).
Headings are not wrapped: compare them with ``math.remainder(a - b, 2 pi)``.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable
from typing import Protocol

Pose = tuple[float, float, float]
ORIGIN: Pose = (0.0, 0.0, 0.0)

# Below this turn [rad] the R form loses digits (R (sin - sin) cancels, relative error
# about 1e-16 / dtheta); there the same arc comes from its Taylor series in dtheta,
# whose first dropped term is ds dtheta^4 / 120 < 1e-18 ds.
SERIES_BELOW = 1e-4


def arc(ds: float, dtheta: float, start: Pose = ORIGIN) -> Pose:
    """Where an arc of length ``ds`` turning by ``dtheta`` ends, starting from ``start``."""
    x, y, th = start
    if dtheta == 0.0:
        return x + ds * math.cos(th), y + ds * math.sin(th), th
    if abs(dtheta) < SERIES_BELOW:
        # R sin a = ds (1 - a^2/6), R (1 - cos a) = ds (a/2 - a^3/24) in the start's frame.
        fwd = ds * (1.0 - dtheta * dtheta / 6.0)
        left = ds * (0.5 * dtheta - dtheta**3 / 24.0)
        c, s = math.cos(th), math.sin(th)
        return x + c * fwd - s * left, y + s * fwd + c * left, th + dtheta
    radius = ds / dtheta
    return (x + radius * (math.sin(th + dtheta) - math.sin(th)),
            y - radius * (math.cos(th + dtheta) - math.cos(th)), th + dtheta)


def wheel_arc(s_left: float, s_right: float, separation: float,
              start: Pose = ORIGIN) -> Pose:
    """The arc the wheels' arcs ``s_left``, ``s_right`` [m] make: mean and difference / b."""
    return arc(0.5 * (s_left + s_right), (s_right - s_left) / separation, start)


def integrate(steps: Iterable[tuple[float, float]], start: Pose = ORIGIN) -> Pose:
    """Each ``(ds, dtheta)`` step an arc, one after the other."""
    pose = start
    for ds, dtheta in steps:
        pose = arc(ds, dtheta, pose)
    return pose


def integrate_wheels(arcs: Iterable[tuple[float, float]], separation: float,
                     start: Pose = ORIGIN) -> Pose:
    """Each step's wheel arcs ``(s_left, s_right)`` [m] an arc, one after the other."""
    pose = start
    for s_left, s_right in arcs:
        pose = wheel_arc(s_left, s_right, separation, pose)
    return pose


class SegmentLike(Protocol):
    """A route segment: a twist held for a while (``routes.Segment`` is one)."""

    @property
    def duration(self) -> float: ...
    @property
    def linear(self) -> float: ...
    @property
    def angular(self) -> float: ...


def route_end(segments: Iterable[SegmentLike], start: Pose = ORIGIN,
              twist_map: Callable[[float, float], tuple[float, float]] | None = None) -> Pose:
    """Where a route's segments end: each held twist ``(v, w)`` for ``t`` an arc ``v t, w t``.

    ``twist_map`` turns a commanded twist into the one really executed (a robot whose
    geometry differs from the nominal one).
    """
    pose = start
    for seg in segments:
        v, w = (seg.linear, seg.angular) if twist_map is None else twist_map(
            seg.linear, seg.angular)
        pose = arc(v * seg.duration, w * seg.duration, pose)
    return pose


def sensor_clock(rate_hz: float, seconds: float, jitter_s: float = 0.0, phase_s: float = 0.0,
                 seed: int = 0, t0_ns: int = 1_700_000_000 * 10**9) -> list[int]:
    """Header stamps [ns] of a driver on its own clock: ``rate_hz`` with a phase and a
    uniform jitter of +-``jitter_s`` on each stamp (a driver's timer, not a clean grid)."""
    import random

    rng = random.Random(seed)
    period = 1.0 / rate_hz
    count = int(seconds * rate_hz) + 1
    return [t0_ns + round((phase_s + k * period + rng.uniform(-jitter_s, jitter_s)) * 1e9)
            for k in range(count)]


def mean_rate(stamps_ns: list[int]) -> float:
    """Average rate [Hz] of a stream: intervals over the time they span."""
    return (len(stamps_ns) - 1) / ((stamps_ns[-1] - stamps_ns[0]) * 1e-9)


def mahalanobis2(value: tuple[float, float], covariance: tuple[float, float, float, float],
                 truth: tuple[float, float]) -> float:
    """``truth``'s squared Mahalanobis distance from a 2-vector estimate with its
    row-major 2x2 covariance (the online estimate's ratios), by the 2x2 inverse."""
    du, dv = value[0] - truth[0], value[1] - truth[1]
    a, c, _, d = covariance
    return (d * du * du - 2 * c * du * dv + a * dv * dv) / (a * d - c * c)
