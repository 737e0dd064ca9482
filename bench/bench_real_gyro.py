"""Gyro-aided odometry on a real robot (issue 31): the package against a ten-line anchor.

    .venv/bin/python bench/bench_real_gyro.py [--data DIR]

Data: ``../shared/data/phil_train`` (a TurtleBot2 / Kobuki base, raw 16-bit wheel
counters at ~40 Hz on its own clock, a navX gyro polled at ~100 Hz, Vicon on runs 0, 2
and 6; GPL-3.0, read in place, never copied). Nominal geometry: radius 0.035 m, track
0.23 m, 2578.33 ticks per revolution. Every run goes through the node's
``ReadingPipeline`` in receive order, defaults but for ``use_imu``.

Per run, side by side in one table:

- wheels: ``use_imu: false`` (the nominal geometry, as configured);
- gyro-aided: ``use_imu: true`` with every other parameter at its default (online
  calibration ``monitor``);
- anchor: the ten-line gyrodometry written here without the package: heading = the
  gyro's trapezoid integral less its mean rate over the first 2 s (the robot stands),
  distance = the wheels' mean arc per reading, poses by the midpoint heading;
- slip-flagged steps (and their share of the readings), slip events.

ATE is the RMSE after the best SE(2) fit (the Vicon marker's yaw and offset are not
the robot's: ``core.evaluation.metrics``). The issue's goals: gyro-aided within 10 %
of the anchor on every run with ground truth, at least 3x better than the wheels on
runs turning more than a radian, slip-flagged steps at most 5 % of readings.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "test"))

from phildata import DATA, RUNS, Judged, Run, anchor, load, package, turned, verdicts, vicon_ratios

from diffdrive_odom.core.evaluation.metrics import evaluate


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--data", type=Path, default=DATA)
    args = parser.parse_args()
    if not args.data.is_dir():
        print(f"no {args.data}: phil_train is read from ../shared/data", file=sys.stderr)
        return 1
    print(f"{'run':>4} {'readings':>8} {'turned':>7}  {'ATE wheels':>10} {'gyro-aided':>10} "
          f"{'anchor':>8} {'aided/anchor':>12} {'wheels/aided':>12}  {'slip steps':>12} "
          f"{'events':>6}  {'bias [rad/s]':>12}  {'jitter':>6}  IMU lag after the wheels'")
    ok = True
    for n in RUNS:
        path = args.data / f"phil_trial_{n}"
        if not path.is_dir():
            continue
        run = load(path)
        wheels, _ = package(run, {})
        aided, pipe = package(run, {"use_imu": True})
        base = anchor(run)
        g = pipe.stats.gyro
        assert g is not None
        readings = pipe.stats.readings
        share = g.slips.steps / readings
        line = (f"{n:>4} {readings:>8} {turned(base):>6.1f}r  ")
        if run.truth is not None:
            ate = [evaluate(t, run.truth).ate_rmse_best_fit_m for t in (wheels, aided, base)]
            line += (f"{ate[0]:>10.4f} {ate[1]:>10.4f} {ate[2]:>8.4f} {ate[1] / ate[2]:>12.2f} "
                     f"{ate[0] / ate[1]:>12.1f}  ")
            ok &= ate[1] <= 1.1 * ate[2] and (turned(base) < 1.0 or ate[0] >= 3.0 * ate[1])
        else:
            line += f"{'-':>10} {'-':>10} {'-':>8} {'-':>12} {'-':>12}  "
        ok &= share <= 0.05
        lag = "not measured" if g.lag is None else (
            f"{1e3 * g.lag.lag:+.0f} +- {1e3 * g.lag.sigma:.0f} ms")
        line += (f"{g.slips.steps:>5} ({100 * share:4.1f}%) {g.slips.events:>6}  {g.bias:>12.6f}"
                 f"  {1e3 * g.jitter:4.1f}ms  {lag}")
        print(line)
    print("goals (aided within 10 % of the anchor, 3x the wheels where turned > 1 rad, "
          f"slip steps <= 5 %): {'met' if ok else 'NOT met'}")
    print("\nVerdicts against the Vicon (its stamps aligned to the wheels' by the fit of "
          "test/phildata.py):")
    for n in (0, 2, 6):
        path = args.data / f"phil_trial_{n}"
        if path.is_dir():
            run, judged = load(path), list[Judged]()
            package(run, {"use_imu": True}, judged)
            f, c, s, m = verdicts(run, judged)
            print(f"  run {n}: {f} steps flagged as slip, the Vicon confirms {c} (the wheels' "
                  f"turn off its own); {s} standing steps, the Vicon moved on {m}")
    online(args.data)
    return 0


def online(data: Path) -> None:
    """Online calibration (monitor) on the runs turning both ways, against a Vicon fit."""
    print("\nSeparation multiplier (mean radius held), 1 sigma:")
    with_truth = [load(data / f"phil_trial_{n}") for n in (0, 2)
                  if (data / f"phil_trial_{n}").is_dir()]
    x, cov = vicon_ratios(with_truth)
    s, m = float(x[0] + x[1]), 0.035
    grad = 2 * m / s ** 2 / 0.23
    ref = (2 * m / s / 0.23, grad * math.sqrt(cov[0, 0] + 2 * cov[0, 1] + cov[1, 1]))
    jl = np.array([-2 * x[1] / s ** 2, 2 / s - 2 * x[1] / s ** 2])  # left multiplier 2v/s
    left = (float(2 * x[1] / s), math.sqrt(float(jl @ cov @ jl)))
    print(f"  Vicon fit, runs 0 + 2 (least squares of the Vicon's heading change over 0.5 s "
          f"windows on the joint increments, its lag behind the wheels taken out): "
          f"{ref[0]:.4f} +- {ref[1]:.4f}; left radius multiplier {left[0]:.4f} +- {left[1]:.4f}")
    for n in (4, 5, 9):
        path = data / f"phil_trial_{n}"
        if not path.is_dir():
            continue
        _, pipe = package(load(path), {"use_imu": True})
        assert pipe.online is not None
        est = pipe.online.estimate()
        mb, sb = est.multipliers[2], est.stddevs[2]
        apart = abs(mb - ref[0]) / math.hypot(sb, ref[1])
        ratio = abs(est.multipliers[0] - left[0]) / math.hypot(est.stddevs[0], left[1])
        print(f"  run {n}: {mb:.4f} +- {sb:.4f} ({'determined' if est.determined else 'not yet'}"
              f", {apart:.1f} sigma from the Vicon fit; its left radius {ratio:.1f} sigma); "
              f"{est.line()}")
        apply(data, n, est.multipliers, with_truth)


def apply(data: Path, n: int, mult: tuple[float, float, float], runs: list[Run]) -> None:
    """Wheels-only ATE of the runs with ground truth, nominal and with run n's estimate."""
    params = dict(zip(("left_wheel_radius_multiplier", "right_wheel_radius_multiplier",
                       "wheel_separation_multiplier"), mult, strict=True))
    cells = []
    for k, run in zip((0, 2), runs, strict=True):
        assert run.truth is not None
        before = evaluate(package(run, {})[0], run.truth).ate_rmse_best_fit_m
        after = evaluate(package(run, params)[0], run.truth).ate_rmse_best_fit_m
        cells.append(f"run {k} {before:.4f} -> {after:.4f} m")
    print(f"    its geometry, wheels only (ATE nominal -> estimated): {'; '.join(cells)}")


if __name__ == "__main__":
    sys.exit(main())
