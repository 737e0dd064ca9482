"""Online calibration's sigma against the package's own simulator, over seeds (issue 25).

    .venv/bin/python bench/bench_online_sim.py [--quick] [--seeds N]

The demo's robot (``diffdrive_odom/data/demo_params.yaml``: true right radius +0.2 %,
track +1 %, random slip, motor lag, 1 ms physics substeps, 4096-tick encoders at 50 Hz,
a gyro at 100 Hz with a bias of 0.004 rad/s and its four scripted slips) driven open
loop: 7 s standing, a 4 m square clockwise, 1 s standing, one counter-clockwise. The sim
is stepped and its gyro read as ``sim_node`` does (two 10 ms pieces per wheel reading,
each sample stamped at its piece's middle); everything goes through the node's
:class:`ReadingPipeline` gyro-aided with ``online_calibration: monitor``. Per seed: the
final multipliers against the sim's true ones (mean radius held) in units of the
printed sigma; a sigma that claims what it covers gives z of rms 1 (or less, if
conservative) and almost none beyond 3.
"""

from __future__ import annotations

import argparse
import math
from dataclasses import replace

import numpy as np

from diffdrive_odom.core.estimation.online.online_estimate import OnlineEstimate
from diffdrive_odom.core.estimation.pipeline import ReadingPipeline
from diffdrive_odom.core.sim.model import DiffDriveSim
from diffdrive_odom.demo.evaluation import true_multipliers
from diffdrive_odom.demo.settings import DemoOptions, Settings, load_settings

T0 = 1_700_000_000_000_000_000
STEP_NS = 20_000_000  # the wheels' 50 Hz; the gyro reads twice per step
NAMES = ("left_wheel_joint", "right_wheel_joint")


def route() -> list[tuple[float, float, float]]:
    """(seconds, v, w): standing, a square each way with 1.5 rad/s arcs at the corners."""
    segments = [(7.0, 0.0, 0.0)]
    for sign in (-1.0, 1.0):
        for _ in range(4):
            segments += [(9.0, 0.4, 0.0), (math.pi / 2 / 1.5, 0.15, sign * 1.5)]
        segments.append((1.0, 0.0, 0.0))
    return segments


def run(s: Settings, seed: int) -> OnlineEstimate:
    """One seed's final estimate."""
    sim = DiffDriveSim(replace(s.sim.config, seed=seed))
    pipe = ReadingPipeline(s.gyro_odometry)
    g = s.gyro_odometry.geometry
    half = STEP_NS // 2
    for seconds, v, w in route():
        rates = [(v - 0.5 * g.separation * w) / g.left_radius,
                 (v + 0.5 * g.separation * w) / g.right_radius]
        for _ in range(round(seconds * 1e9 / STEP_NS)):
            sim.command(rates)
            for _ in range(2):
                sim.advance(half)
                pipe.feed_imu(T0 + sim.time_ns - half // 2, 0.0, 0.0, sim.gyro(1e9 / half))
            counts = sim.encoder_counts()
            pipe.feed(T0 + sim.time_ns, NAMES, [float(counts[0]), float(counts[1])])
    online = pipe.online
    assert online is not None
    return online.estimate()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="3 seeds")
    ap.add_argument("--seeds", type=int, default=30)
    args = ap.parse_args()
    s = load_settings(DemoOptions())
    truth = np.array(true_multipliers(s.gyro_odometry.geometry, s.sim.config.geometry))
    print("seed  left (+- 1 sigma)     right (+- 1 sigma)    separation (+- 1 sigma)  "
          "z left/right/sep      excluded")
    zs = []
    for seed in range(3 if args.quick else args.seeds):
        e = run(s, seed)
        z = (np.array(e.multipliers) - truth) / np.array(e.stddevs)
        zs.append(z)
        cells = "  ".join(f"{m:.5f} +- {sd:.5f}" for m, sd in zip(e.multipliers, e.stddevs,
                                                                  strict=True))
        print(f"{seed:4d}  {cells}  {z[0]:+5.2f} {z[1]:+5.2f} {z[2]:+5.2f}  "
              f"{dict(sorted(e.excluded.items()))}", flush=True)
    z = np.array(zs)
    print("truth (mean radius held): " + ", ".join(f"{t:.5f}" for t in truth))
    print("z rms left/right/separation: " + "/".join(f"{v:.2f}" for v in np.sqrt((z * z).mean(0)))
          + "; beyond 2 sigma: " + "/".join(f"{v:.0%}" for v in (abs(z) > 2).mean(0))
          + "; beyond 3 sigma: " + "/".join(f"{v:.0%}" for v in (abs(z) > 3).mean(0)))


if __name__ == "__main__":
    main()
