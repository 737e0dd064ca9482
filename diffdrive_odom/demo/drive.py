"""The route on simulated time: settle, then each square driven and settled, in lockstep.

:meth:`Drive.step` runs at each ``/clock`` of the loop, inside the recorder's answer to it
(:mod:`.recorder`), so a path is sent, and a square ends, at the same simulated instant on
every run: the follower takes the path before the sim steps on. Pure: it only asks the
recorder what was heard and tells it to send a path.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Protocol

from diffdrive_odom.core.motion.paths import Point

from .report import Square
from .settings import SETTLE_S, START_REST_S

SETTLE_NS = round(SETTLE_S * 1e9)
REST_NS = round(START_REST_S * 1e9)


class Heard(Protocol):
    """What the driver asks of the recorder."""

    done_true: int  # times the follower said its path is done

    def send_path(self, points: Sequence[Point]) -> None:
        """Publish a path for the follower."""


@dataclass(frozen=True)
class Leg:
    """A square to drive: its direction and the points sent."""

    clockwise: bool
    points: tuple[Point, ...]


class Drive:
    """Rest ``START_REST_S``; each square: its path sent, driven until done, settled.

    ``finished`` once the odometry and the truth of the last square's end are heard;
    ``squares`` the squares as driven, ``doing`` what it waits for (for error messages).
    """

    def __init__(self, heard: Heard, legs: Sequence[Leg]) -> None:
        self._heard = heard
        self._legs = list(legs)
        self.squares: list[Square] = []
        self.finished = False
        self.doing = "waiting for the loop's first step"
        self._until: int | None = None  # end of the settling under way
        self._start: int | None = None  # start of the square being driven
        self._done = 0  # the follower's done count when the path was sent

    def step(self, now_ns: int) -> None:
        """One /clock of the loop: send, finish or settle, as its time says."""
        h = self._heard
        if self.finished:
            return
        if self._until is None:
            if self._start is None:  # the first step: rest first
                self._until, self.doing = now_ns + REST_NS, "waiting at the start"
            elif h.done_true > self._done:  # the follower says done: settle
                self._until, self.doing = now_ns + SETTLE_NS, "letting the robot settle"
            return
        if now_ns < self._until:
            return
        if self._start is not None:  # a square settled: it ends here
            leg = self._legs[len(self.squares)]
            self.squares.append(Square(leg.clockwise, leg.points, self._start, self._until))
            self._start = None
        if len(self.squares) < len(self._legs):
            leg = self._legs[len(self.squares)]
            self._start, self._done, self._until = now_ns, h.done_true, None
            self.doing = f"driving the {'CW' if leg.clockwise else 'CCW'} square"
            h.send_path(leg.points)
            return
        # The odometry and truth of the last square's end came with that step's readings:
        # heard once the next /clock comes.
        self.doing = "waiting for the last odometry and ground truth"
        self.finished = now_ns > self.squares[-1].end_ns
