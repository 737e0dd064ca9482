"""Cases timed side by side, message by message: how the CPU benches compare configurations.

This machine's CPU time varies by tens of percent from one second to the next (a
virtual machine's neighbours), so whole runs timed back to back give ratios that move
by 0.5x between rounds. Here every case has its own pipeline, each message goes to all
of them in an order rotated at every message, and each call is timed: a burst of noise
falls on every case alike, and the ratios hold to about 0.01 from round to round.
"""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable, Mapping, Sequence
from typing import TypeVar

P = TypeVar("P")
M = TypeVar("M")


def interleaved(cases: Mapping[str, Callable[[], P]], feed: Callable[[P, M], object],
                messages: Sequence[M], rounds: int) -> dict[str, list[float]]:
    """Seconds each case spent in ``feed`` per round (fresh pipelines every round)."""
    names = list(cases)
    n = len(names)
    times: dict[str, list[float]] = {k: [] for k in names}
    clock = time.perf_counter_ns
    for _ in range(rounds):
        pipes = [cases[k]() for k in names]
        spent = [0] * n
        for k, msg in enumerate(messages):
            for j in range(n):
                i = (j + k) % n
                t0 = clock()
                feed(pipes[i], msg)
                spent[i] += clock() - t0
        for name, ns in zip(names, spent, strict=True):
            times[name].append(ns * 1e-9)
    return times


def ratio_rows(times: Mapping[str, list[float]], base: str, per: int) -> list[str]:
    """Per case: the median time per ``per`` readings and its ratio to ``base``'s."""
    rows = []
    for name, values in times.items():
        ratios = [v / b for v, b in zip(values, times[base], strict=True)]
        rows.append(f"  {name:20s} median {statistics.median(values) / per * 1e6:6.1f} us; "
                    f"x {base}: median {statistics.median(ratios):.2f} "
                    f"(range {min(ratios):.2f}-{max(ratios):.2f})")
    return rows
