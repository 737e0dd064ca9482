"""The command timeout (``cmd_vel_timeout``): how long a velocity command stays in force.

One rule for the two places that hold a command: the cmd_vel node (zeros to the wheels
once it expired) and open-loop odometry (zero velocity integrated from then on,
:mod:`diffdrive_odom.core.estimation.open_loop`). Here, below both, so neither
imports the other. Pure Python.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Generic, TypeVar

C = TypeVar("C")


@dataclass(frozen=True)
class Held(Generic[C]):
    """A command with its arrival time (steady clock) and its own stamp (ROS time) if any."""

    command: C
    arrival_ns: int
    stamp_ns: int | None


class Watchdog(Generic[C]):
    """Holds the latest valid command until it is ``timeout`` old; ``timeout`` 0 = forever.

    Age counts from the arrival on a steady clock (immune to /clock pauses and jumps)
    and, for stamped commands, also from the stamp in ROS time, so a command delayed
    in transit expires no later than its sender intended.
    """

    def __init__(self, timeout_s: float) -> None:
        self.timeout_ns = round(timeout_s * 1e9)
        self._held: Held[C] | None = None

    def is_stale(self, stamp_ns: int, ros_now_ns: int) -> bool:
        """Tell whether a stamped command is older than the timeout already on arrival."""
        return self.timeout_ns > 0 and ros_now_ns - stamp_ns > self.timeout_ns

    def accept(self, command: C, arrival_ns: int, stamp_ns: int | None = None) -> None:
        """Take ``command`` as the one to follow from now on."""
        self._held = Held(command, arrival_ns, stamp_ns)

    def clear(self) -> None:
        """Drop the held command (stop)."""
        self._held = None

    @property
    def held(self) -> Held[C] | None:
        """The command held (expired or not: :meth:`current` and :meth:`deadline_ns` say)."""
        return self._held

    def deadline_ns(self) -> int | None:
        """The last instant the held command is in force, where both clocks are one.

        Open-loop odometry runs arrival and stamps on one clock (the node's ROS clock, or
        a bag's log time): there :meth:`current` expires the command exactly after this
        instant. None: nothing held, or no timeout.
        """
        held = self._held
        if held is None or self.timeout_ns <= 0:
            return None
        start = held.arrival_ns if held.stamp_ns is None else min(held.arrival_ns, held.stamp_ns)
        return start + self.timeout_ns

    def current(self, steady_now_ns: int, ros_now_ns: int) -> C | None:
        """Return the command to follow now, or None once it timed out (it stays dropped)."""
        held = self._held
        if held is None:
            return None
        if self.timeout_ns > 0 and (
            steady_now_ns - held.arrival_ns > self.timeout_ns
            or (held.stamp_ns is not None and ros_now_ns - held.stamp_ns > self.timeout_ns)
        ):
            self._held = None
            return None
        return held.command
