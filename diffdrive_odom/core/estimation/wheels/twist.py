"""The twist the estimator publishes: each step's body rates, averaged over recent steps.

Apart from the estimator because it is its own rule: ``velocity_rolling_window_size``
steps' rates averaged (never the pose), summed afresh each time so rounding never
accumulates, and handed over whole to a bulk integrator and back
(:mod:`diffdrive_odom.core.bulk.fastlane`, which computes the same means in array form).
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Sequence

__all__ = ["RollingTwist"]


class RollingTwist:
    """The mean linear and angular rate of the last ``size`` steps."""

    def __init__(self, size: int) -> None:
        self._linear: deque[float] = deque(maxlen=size)
        self._angular: deque[float] = deque(maxlen=size)

    def push(self, linear: float, angular: float) -> tuple[float, float]:
        """Add one step's rates; the means after it."""
        lin, ang = self._linear, self._angular
        lin.append(linear)
        ang.append(angular)
        return math.fsum(lin) / len(lin), math.fsum(ang) / len(ang)

    def clear(self) -> None:
        """Forget every step (a reset, a gap): the next step's rates are the twist."""
        self._linear.clear()
        self._angular.clear()

    def windows(self) -> tuple[tuple[float, ...], tuple[float, ...]]:
        """The rates in the windows (linear, angular), oldest first."""
        return tuple(self._linear), tuple(self._angular)

    def install(self, windows: tuple[Sequence[float], Sequence[float]]) -> tuple[float, float]:
        """Put windows a bulk integrator reached in place; their means."""
        for window, values in zip((self._linear, self._angular), windows, strict=True):
            window.clear()
            window.extend(values)
        return math.fsum(self._linear) / len(self._linear), (
            math.fsum(self._angular) / len(self._angular))
