"""Accuracy and cost of the CIR step against the usual alternatives, side by side.

Accuracy: a constant-curvature drive has a closed form, so the error of each
integrator is measured against it over the same encoder steps:
- Euler (Caltech ME/CS 133 notes eq. 27: heading of the previous pose),
- midpoint / RK2 (ELEC6530 homework eq. 4; diff_drive_controller's fallback below
  1e-6 rad),
- diff_drive_controller's "exact" form ``r (sin h1 - sin h0)`` with its 1e-6 switch
  (re-derived here from its published math for comparison only),
- this package's CIR chord (integration.compose).
Cost: the node's per-reading update, and whole-bag vectorised integration.

Run: .venv/bin/python bench/bench_integration.py
(bench/bench_accuracy.py compares the steps on fast-turning routes at encoder rates.)
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable

import numpy as np

from diffdrive_odom.core.estimation.wheels.encoders import EncoderConfig
from diffdrive_odom.core.estimation.wheels.estimator import OdometryEstimator
from diffdrive_odom.core.geometry.integration import Pose2D, compose, integrate_batch
from diffdrive_odom.core.geometry.kinematics import Geometry

Step = Callable[[tuple[float, float, float], float, float], tuple[float, float, float]]


def euler(p: tuple[float, float, float], ds: float, dth: float) -> tuple[float, float, float]:
    x, y, th = p
    return x + ds * math.cos(th), y + ds * math.sin(th), th + dth


def rk2(p: tuple[float, float, float], ds: float, dth: float) -> tuple[float, float, float]:
    x, y, th = p
    h = th + 0.5 * dth
    return x + ds * math.cos(h), y + ds * math.sin(h), th + dth


def ddc_exact(p: tuple[float, float, float], ds: float, dth: float) -> tuple[float, float, float]:
    x, y, th = p
    if abs(dth) < 1e-6:
        return rk2(p, ds, dth)
    r = ds / dth
    th1 = th + dth
    return x + r * (math.sin(th1) - math.sin(th)), y - r * (math.cos(th1) - math.cos(th)), th1


def cir(p: tuple[float, float, float], ds: float, dth: float) -> tuple[float, float, float]:
    q = compose(Pose2D(*p), ds, dth)
    return q.x, q.y, q.theta


METHODS: dict[str, Step] = {
    "Euler (ME/CS 133)": euler,
    "RK2 (ELEC6530)": rk2,
    "ddc exact+switch": ddc_exact,
    "CIR chord (ours)": cir,
}


def run(step: Step, n: int, ds: float, dth: float) -> tuple[float, float, float]:
    p = (0.0, 0.0, 0.0)
    for _ in range(n):
        p = step(p, ds, dth)
    return p


def closed_form(total_s: float, total_th: float) -> tuple[float, float]:
    if total_th == 0.0:
        return total_s, 0.0
    r = total_s / total_th
    return r * math.sin(total_th), r * (1.0 - math.cos(total_th))


def accuracy() -> None:
    print("Position error after driving a constant arc, against the closed form [m]")
    cases = [
        # (label, steps, arc per step [m], heading per step [rad])
        # A fraction of a turn: a whole turn would let Euler's errors cancel by symmetry.
        ("quarter circle r=1 m, 20 steps", 20, math.pi / 2 / 20, math.pi / 2 / 20),
        ("quarter circle r=1 m, 200 steps", 200, math.pi / 2 / 200, math.pi / 2 / 200),
        ("tight turn r=0.1 m, 1 rad, 10 steps", 10, 0.01, 0.1),
        ("100 m, near-straight 2e-6 rad/step", 10000, 0.01, 2e-6),
        ("100 m, near-straight 1e-5 rad/step", 10000, 0.01, 1e-5),
    ]
    names = list(METHODS)
    print(f"{'case':38s}" + "".join(f"{n:>20s}" for n in names))
    for label, n, ds, dth in cases:
        ex, ey = closed_form(n * ds, n * dth)
        errs = []
        for name in names:
            x, y, _ = run(METHODS[name], n, ds, dth)
            errs.append(math.hypot(x - ex, y - ey))
        print(f"{label:38s}" + "".join(f"{e:20.3e}" for e in errs))
    print()


def timing() -> None:
    geometry = Geometry(0.042, 0.2)
    enc = EncoderConfig(("left_wheel_joint",), ("right_wheel_joint",))
    n = 20000
    rng = np.random.default_rng(1)
    left = np.cumsum(rng.uniform(0.0, 0.1, n))
    right = np.cumsum(rng.uniform(0.0, 0.1, n))
    names = ["left_wheel_joint", "right_wheel_joint"]
    est = OdometryEstimator(geometry, enc)
    t0 = time.perf_counter()
    for k in range(n):
        est.update(k * 20_000_000 + 1, names, (float(left[k]), float(right[k])))
    t_scalar = time.perf_counter() - t0

    d_l = np.diff(left) * geometry.left_radius
    d_r = np.diff(right) * geometry.right_radius
    ds = 0.5 * (d_l + d_r)
    dth = (d_r - d_l) / geometry.separation
    t0 = time.perf_counter()
    reps = 20
    for _ in range(reps):
        x, y, _ = integrate_batch(ds, dth)
    t_batch = (time.perf_counter() - t0) / reps
    gap = math.hypot(x[-1] - est.pose.x, y[-1] - est.pose.y)
    print("Cost per reading (same 20000 readings, one run)")
    print(f"  estimator.update (node path):   {t_scalar / n * 1e6:8.2f} us  "
          f"({n / t_scalar:,.0f} readings/s)")
    print(f"  integrate_batch (vectorised):   {t_batch / n * 1e6:8.3f} us  "
          f"({n / t_batch:,.0f} readings/s)")
    print(f"  ratio node path / vectorised:   {t_scalar / t_batch:8.1f} x")
    print(f"  final poses agree to            {gap:8.1e} m")


if __name__ == "__main__":
    accuracy()
    timing()
