"""Per-reading cost of the pure core: ``ReadingPipeline.feed`` and ``covariances()``.

The odometry node calls exactly these two for every JointState, so at 1 kHz their
sum is the part of the node's CPU that does not depend on rclpy. A steady drive (a
slow left turn, 1 kHz stamps) is fed to a fresh pipeline per run; inputs are built
beforehand (a new name list and position array per reading, as a message brings),
so only the core is timed.

    .venv/bin/python bench/bench_core.py [--readings 20000] [--repeat 5] [--quick]

Rows (microseconds per reading, best of ``--repeat`` runs, time.perf_counter):
  feed         ReadingPipeline.feed alone
  feed+cov     feed followed by covariances(), as the node does
  cov          the difference: what covariances() adds
for the defaults (radians, one wheel per side, covariance_model propagated) and for
raw ticks on a wrapping 16-bit counter, two wheels per side, and static covariance.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from diffdrive_odom.core.estimation.pipeline import ReadingPipeline  # noqa: E402
from diffdrive_odom.settings.odometry import odometry_settings  # noqa: E402
from diffdrive_odom.settings.params import ParamValue  # noqa: E402

RATE_HZ = 1000
LEFT_RAD_S, RIGHT_RAD_S = 10.0, 11.0  # joint speeds: a slow left turn
TICKS = 4096.0
BASE: dict[str, ParamValue] = {"wheel_radius": 0.05, "wheel_separation": 0.3}


@dataclass(frozen=True)
class Case:
    """One configuration: how many wheels, what the driver reports, the covariance model."""

    wheels_per_side: int = 1
    ticks: float = 0.0  # 0: radians
    counter_bits: int = 0
    covariance_model: str = "propagated"

    def names(self) -> tuple[list[str], list[str]]:
        """Joint names per side (the defaults' names for one wheel)."""
        if self.wheels_per_side == 1:
            return ["left_wheel_joint"], ["right_wheel_joint"]
        return ([f"left_{i}" for i in range(self.wheels_per_side)],
                [f"right_{i}" for i in range(self.wheels_per_side)])

    def parameters(self) -> dict[str, ParamValue]:
        """The node parameters of this case."""
        left, right = self.names()
        return {**BASE, "left_wheel_names": left, "right_wheel_names": right,
                "ticks_per_revolution": self.ticks, "encoder_counter_bits": self.counter_bits,
                "covariance_model": self.covariance_model}


CASES = {
    "defaults": Case(),
    "ticks, 16-bit counter": Case(ticks=TICKS, counter_bits=16),
    "2 wheels per side": Case(wheels_per_side=2),
    "static covariance": Case(covariance_model="static"),
}

Reading = tuple[int, list[str], list[float]]


def readings(case: Case, n: int) -> list[Reading]:
    """``n`` readings of the steady drive in the units the case's driver reports."""
    left, right = case.names()
    out: list[Reading] = []
    for k in range(n):
        t = k / RATE_HZ
        angles = [LEFT_RAD_S * t] * len(left) + [RIGHT_RAD_S * t] * len(right)
        if case.ticks > 0.0:
            counts = [math.floor(a / (2.0 * math.pi) * case.ticks) for a in angles]
            angles = [float(c % (1 << case.counter_bits)) for c in counts]
        out.append((10**9 + k * 10**9 // RATE_HZ, left + right, angles))
    return out


def per_reading_us(case: Case, data: list[Reading], repeat: int,
                   with_covariances: bool) -> float:
    """Best time per reading [us] of feeding ``data`` to a fresh pipeline."""
    settings = odometry_settings(case.parameters())
    best = math.inf
    for _ in range(repeat):
        pipe = ReadingPipeline(settings)
        feed, cov = pipe.feed, pipe.covariances
        t0 = time.perf_counter()
        if with_covariances:
            for stamp, names, position in data:
                feed(stamp, names, position)
                cov()
        else:
            for stamp, names, position in data:
                feed(stamp, names, position)
        best = min(best, time.perf_counter() - t0)
        stats = pipe.stats
        assert stats.published == len(data) and stats.dropped_total == 0, stats
    return best / len(data) * 1e6


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0] if __doc__ else None)
    ap.add_argument("--readings", type=int, default=20_000, help="readings per run")
    ap.add_argument("--repeat", type=int, default=5, help="runs per row; the best counts")
    ap.add_argument("--quick", action="store_true", help="smoke run: 2000 readings, 1 run")
    args = ap.parse_args()
    n, repeat = (2000, 1) if args.quick else (args.readings, args.repeat)
    print(f"Core cost per reading [us], {n} readings at {RATE_HZ} Hz, best of {repeat}")
    print(f"{'case':24s}{'feed':>10s}{'feed+cov':>10s}{'cov':>10s}")
    for label, case in CASES.items():
        data = readings(case, n)
        feed = per_reading_us(case, data, repeat, with_covariances=False)
        total = per_reading_us(case, data, repeat, with_covariances=True)
        print(f"{label:24s}{feed:10.2f}{total:10.2f}{total - feed:10.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
