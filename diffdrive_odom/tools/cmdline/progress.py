"""replay's progress line on stderr: a plain ``done/total`` line, no progress-bar library.

One dependency fewer on a robot, and all a replay at ~10-50 k readings/s needs.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable, Iterable, Iterator
from typing import TypeVar

MIN_ITEMS = 20_000  # below this a bar is noise

T = TypeVar("T")


def wanted(requested: bool | None, total: int) -> bool:
    """``--progress``/``--no-progress`` as given, else on a terminal for long inputs."""
    if requested is not None:
        return requested
    return sys.stderr.isatty() and total >= MIN_ITEMS


def progress(items: Iterable[T], total: int, prefix: str = "[replay]",
             unit: str = "readings", weight: Callable[[T], int] | None = None) -> Iterator[T]:
    """Pass ``items`` through, redrawing one ``done/total`` line on stderr twice a second.

    ``weight``: how many units an item stands for (a block of readings); else one.
    """
    def line(n: int, elapsed: float) -> str:
        rate = n / elapsed if elapsed > 0 else 0.0
        share = f" ({100 * n / total:3.0f} %)" if total else ""
        return f"\r{prefix} {_si(n)}/{_si(total)} {unit}{share} {_si(int(rate))}/s"

    start = last = time.monotonic()
    n = 0
    for item in items:
        n += 1 if weight is None else weight(item)
        now = time.monotonic()
        if now - last >= 0.5:
            sys.stderr.write(line(n, now - start))
            sys.stderr.flush()
            last = now
        yield item
    sys.stderr.write(line(n, time.monotonic() - start) + "\n")
    sys.stderr.flush()


def _si(n: int) -> str:
    return f"{n / 1e6:.2f}M" if n >= 10**6 else f"{n / 1e3:.2f}k" if n >= 1000 else str(n)
