"""Log throttling keyed by reason, so a frequent reason never hides a rare one (pure, no rclpy)."""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

WARN_THROTTLE_S = 5.0


class KeyedThrottle:
    """One throttle per key: the first line of each key at once, then one per period.

    rclpy's ``throttle_duration_sec`` is keyed by call site, so when every reason is
    logged from one place a frequent reason hides a rare one. Lines held back are
    counted and the count rides on the next line of that key. ``logger`` is anything
    with ``warning`` and ``info`` methods (rclpy's node logger in the nodes).
    """

    def __init__(
        self,
        logger: Any,
        period_s: float = WARN_THROTTLE_S,
        clock: Callable[[], float] | None = None,
    ) -> None:
        self._logger = logger
        self._period = period_s
        self._clock = clock if clock is not None else time.monotonic
        self._last: dict[str, float] = {}
        self._held: dict[str, int] = {}

    def warning(self, key: str, text: str) -> bool:
        """Log ``text`` as a warning unless ``key`` was logged within the period."""
        line = self._admit(key, text)
        if line is not None:
            self._logger.warning(line)  # its own call site: see _admit
        return line is not None

    def info(self, key: str, text: str) -> bool:
        """Log ``text`` as info unless ``key`` was logged within the period."""
        line = self._admit(key, text)
        if line is not None:
            self._logger.info(line)
        return line is not None

    def _admit(self, key: str, text: str) -> str | None:
        """The line to log now, or None if held back.

        The caller logs it: rclpy's logger refuses a call site that logs at two
        severities ("Logger severity cannot be changed between calls", a ValueError
        that would end the node), so info and warning lines never share one.
        """
        now = self._clock()
        last = self._last.get(key)
        if last is not None and now - last < self._period:
            self._held[key] = self._held.get(key, 0) + 1
            return None
        self._last[key] = now
        held = self._held.pop(key, 0)
        return f"{text} ({held} more like this since the last report)" if held else text
