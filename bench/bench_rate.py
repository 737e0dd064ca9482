"""The rate users get from ``publish_rate``: the schedule against the old gate.

    .venv/bin/python bench/bench_rate.py [--seconds S]

Drivers on their own clocks (a phase, a uniform jitter on each stamp, seeded) feed the
odometry pipeline (``core.estimation.pipeline``, the node's and replay's path) for S
seconds of stamp time (default 60); the rate of the published stamps is printed beside
the input rate and the one promised, min(publish_rate, input rate). The "old" column is
the gate before the schedule (a pose published when one period less 1 us had passed
since the last published one), written out here as it was.
"""

from __future__ import annotations

import argparse
import random

from diffdrive_odom.core.estimation.gate import PublishGate

CASES = [(150.0, 1e-3, 50.0), (100.0, 0.0, 30.0), (49.0, 1e-3, 50.0), (1000.0, 0.0, 50.0),
         (1000.0, 1e-4, 50.0), (60.0, 1e-3, 25.0)]


def clock(hz: float, seconds: float, jitter: float, seed: int) -> list[int]:
    """Header stamps [ns]: ``hz`` with a 3.7 ms phase and +-``jitter`` s on each."""
    rng = random.Random(seed)
    return [10**18 + round((0.0037 + k / hz + rng.uniform(-jitter, jitter)) * 1e9)
            for k in range(int(seconds * hz) + 1)]


def old_gate(rate: float, stamps: list[int]) -> list[int]:
    """The gate before the schedule: one period less 1 us since the last published pose."""
    period, last, out = 1e9 / rate - 1e3, None, []
    for s in stamps:
        if last is None or s < last or s - last >= period:
            last = s
            out.append(s)
    return out


def rate_of(stamps: list[int]) -> float:
    """Intervals over the time they span [Hz]."""
    return (len(stamps) - 1) / ((stamps[-1] - stamps[0]) * 1e-9)


def main() -> None:
    """Print the table (markdown)."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=60.0)
    args = ap.parse_args()
    print("| input | publish_rate | promised | old gate | schedule | error |")
    print("|---|---|---|---|---|---|")
    for hz, jitter, rate in CASES:
        stamps = clock(hz, args.seconds, jitter, seed=int(hz))  # same stamps for both
        gate = PublishGate(rate)
        new = [s for s in stamps if gate.due(s)]
        want = min(rate, rate_of(stamps))
        jit = f" +-{jitter * 1e3:g} ms" if jitter else ""
        print(f"| {hz:g} Hz{jit} | {rate:g} | {want:.2f} | {rate_of(old_gate(rate, stamps)):.2f} "
              f"| {rate_of(new):.2f} | {100 * (rate_of(new) / want - 1):+.2f} % |")


if __name__ == "__main__":
    main()
