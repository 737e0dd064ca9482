"""Integration accuracy on fast turns: the package's exact CIR step against the
textbook Euler and midpoint steps, at the usual encoder rates, in one run.

    .venv/bin/python bench/bench_accuracy.py [--quick]

Model: the wheel speeds are constant over each sample interval (what a motor
controller updating at the sample rate does), so between two readings the robot
drives an exact arc. The true pose is then the composition of exact arcs, computed
here independently of the package in the complex plane:

    z_{k+1} = z_k + v_k dt e^{i theta_k} (e^{i w_k dt} - 1) / (i w_k dt),
    theta_{k+1} = theta_k + w_k dt,

with ``expm1`` so a tiny turn loses no digits. A constant-curvature route is
additionally checked against the single-arc closed form ``(v/w)(e^{i w T} - 1)/i``.

Methods, each fed the same ``(ds, dtheta) = (v dt, w dt)`` per interval:
- Euler: heading of the previous pose (Caltech ME/CS 133 notes, wheel odometry by
  backward differences, eq. 27),
- midpoint: heading halfway through the step (ELEC6530 homework, the midpoint
  discrete model, eq. 4),
- ours: the package's ``integration.compose`` (Furlan, Marzorati, Sorrenti: the
  odometric update as a composition of 2D roto-translations about the CIR).
Euler and midpoint are written out here for comparison only; the package's step is
called, not copied. All three sum the same heading increments, so heading errors
are the round-off of that sum: the methods differ in position.
"""

from __future__ import annotations

import argparse
import cmath
import math
import sys
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from diffdrive_odom.core.geometry.integration import Pose2D, compose

Pose = tuple[float, float, float]
Step = Callable[[Pose, float, float], Pose]
Profile = Callable[[float], tuple[float, float]]  # t [s] -> (v [m/s], w [rad/s])


def euler(p: Pose, ds: float, dth: float) -> Pose:
    """Caltech ME/CS 133 eq. 27: advance along the previous heading."""
    x, y, th = p
    return x + ds * math.cos(th), y + ds * math.sin(th), th + dth


def midpoint(p: Pose, ds: float, dth: float) -> Pose:
    """ELEC6530 eq. 4: advance along the heading halfway through the step."""
    x, y, th = p
    h = th + 0.5 * dth
    return x + ds * math.cos(h), y + ds * math.sin(h), th + dth


def ours(p: Pose, ds: float, dth: float) -> Pose:
    """The package's CIR step."""
    q = compose(Pose2D(*p), ds, dth)
    return q.x, q.y, q.theta


METHODS: dict[str, Step] = {"Euler": euler, "midpoint": midpoint, "ours": ours}


@dataclass(frozen=True)
class Route:
    """A body-velocity profile sampled piecewise constant at the encoder rate."""

    name: str
    duration: float
    profile: Profile
    constant: bool = False  # constant (v, w): the single-arc closed form applies too
    substeps: int = 1  # > 1: speeds vary within an interval, the truth uses finer arcs


ROUTES = (
    # Durations avoid whole turns: over a full circle Euler's errors cancel by symmetry.
    Route("fast turn r=0.17 m (0.5 m/s, 3 rad/s, 4 s)", 4.0, lambda t: (0.5, 3.0), True),
    Route("figure eight (0.5 m/s, w=3 sin(pi t/2), 7 s)", 7.0,
          lambda t: (0.5, 3.0 * math.sin(0.5 * math.pi * t))),
    # The same figure eight with speeds varying *within* each interval: no method is
    # exact any more; the truth composes exact arcs at 400x the encoder rate.
    Route("figure eight, speeds varying within intervals", 7.0,
          lambda t: (0.5, 3.0 * math.sin(0.5 * math.pi * t)), substeps=400),
    Route("spin + forward (0.2 m/s, 6 rad/s, 5.3 s)", 5.3, lambda t: (0.2, 6.0), True),
)
RATES = (10.0, 20.0, 50.0, 100.0)


def sampled(route: Route, rate: float) -> tuple[np.ndarray, np.ndarray, float]:
    """Per-interval (v, w), each held over its interval (taken at the interval's middle)."""
    n = round(route.duration * rate)
    dt = 1.0 / rate
    vw = np.array([route.profile((k + 0.5) * dt) for k in range(n)], dtype=np.float64)
    return vw[:, 0], vw[:, 1], dt


def readings(route: Route, rate: float) -> tuple[np.ndarray, np.ndarray, float, Pose]:
    """What the encoders report per interval (mean v, w over it) and the exact pose."""
    m = route.substeps
    v, w, dt = sampled(route, rate * m)
    ref = truth(v, w, dt)
    if m > 1:
        v, w = v.reshape(-1, m).mean(axis=1), w.reshape(-1, m).mean(axis=1)
    return v, w, dt * m, ref


def truth(v: np.ndarray, w: np.ndarray, dt: float) -> Pose:
    """Composition of exact arcs in the complex plane (independent of the package)."""
    z = 0j
    th = 0.0
    for vk, wk in zip(v.tolist(), w.tolist(), strict=True):
        a = wk * dt
        chord = 1.0 + 0j if a == 0.0 else complex(np.expm1(1j * a)) / (1j * a)
        z += vk * dt * cmath.exp(1j * th) * chord
        th += a
    return z.real, z.imag, th


def single_arc(v: float, w: float, duration: float) -> complex:
    """Closed form of one constant-curvature arc from the origin."""
    return (v / w) * (cmath.exp(1j * w * duration) - 1.0) / 1j


def heading_error(a: float, b: float) -> float:
    return abs(math.remainder(a - b, 2.0 * math.pi))


def errors(step: Step, v: np.ndarray, w: np.ndarray, dt: float, ref: Pose) -> tuple[float, float]:
    p: Pose = (0.0, 0.0, 0.0)
    for vk, wk in zip(v.tolist(), w.tolist(), strict=True):
        p = step(p, vk * dt, wk * dt)
    return math.hypot(p[0] - ref[0], p[1] - ref[1]), heading_error(p[2], ref[2])


def ratio(num: float, den: float) -> str:
    """``num / den``; ours may be exactly 0, then the bound against one ulp of 1 m."""
    floor = 2.0**-52
    return f"{num / den:9.1e}" if den >= floor else f">{num / floor:8.1e}"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="two rates, for the smoke test")
    args = ap.parse_args(argv)
    rates = RATES[:2] if args.quick else RATES
    print("Final position error [m] and heading error [rad] against the exact pose;")
    print("wheel speeds held constant over each sample interval (see the module docstring).")
    head = (f"{'route':46s} {'Hz':>4s} {'Euler m':>9s} {'midpt m':>9s} {'ours m':>9s}"
            f" {'Eul/ours':>9s} {'mid/ours':>9s} {'heading rad (E, m, o)':>29s}")
    print(head)
    print("-" * len(head))
    for route in ROUTES:
        for rate in rates:
            v, w, dt, ref = readings(route, rate)
            if route.constant:
                z = single_arc(float(v[0]), float(w[0]), route.duration)
                gap = abs(z - complex(ref[0], ref[1]))
                assert gap < 1e-12, f"{route.name}: arc composition vs closed form {gap:.1e} m"
            res = {name: errors(step, v, w, dt, ref) for name, step in METHODS.items()}
            (pe, he), (pm, hm), (po, ho) = res["Euler"], res["midpoint"], res["ours"]
            print(f"{route.name:46s} {rate:4.0f} {pe:9.1e} {pm:9.1e} {po:9.1e}"
                  f" {ratio(pe, po)} {ratio(pm, po)}   {he:9.1e} {hm:9.1e} {ho:9.1e}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
