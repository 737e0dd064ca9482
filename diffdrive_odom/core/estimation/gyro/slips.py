"""What counts as a slip event: the one rule for the node, ``replay`` and the demo.

The gyrodometry decision (:mod:`~diffdrive_odom.core.estimation.gyro.gyrodometry`) flags each
wheel step whose heading disagrees with the gyro's beyond the noise. A user calls a
slip something else: a wheel spinning for half a second is one slip, though the
per-step decision may find a few runs of slipping steps in it (steps whose spin is
within the noise are fused, not flagged); and a single encoder tick at a standstill
(a fraction of a milliradian) is no slip at all. So slipping steps less than
:data:`MERGE_S` apart are one run, and a run is a slip event once the heading the
wheels got wrong over it (the signed sum: a gyro noisier than declared flags steps
both ways, which cancel, where a spinning wheel errs one way) reaches
``slip_min_angle``. A run not yet an event starts afresh after :data:`MAX_RUN_S`, so
noise flagged step after step never adds up to one.
"""

from __future__ import annotations

from dataclasses import dataclass

# s of stamps between two slipping steps within which they are one slip.
MERGE_S = 0.5
# s a run may last before it is an event; longer, it starts afresh.
MAX_RUN_S = 2.0
# Slip events remembered (stamp of the first step, size) for the demo's table and plot.
MAX_EVENTS = 1000


@dataclass(frozen=True, slots=True)
class SlipStats:
    """Slip events so far (a snapshot).

    ``events``: runs of slipping steps whose size reached ``slip_min_angle``;
    ``steps``: steps the decision flagged, in an event or not; ``last_stamp_ns``: the
    last step of the last event (None: none yet); ``last_size``: the heading the wheels
    got wrong over it [rad]; ``total_size``: over all events.
    """

    events: int = 0
    steps: int = 0
    last_stamp_ns: int | None = None
    last_size: float = 0.0
    total_size: float = 0.0


class SlipEvents:
    """Slipping steps in, slip events out (``min_angle`` [rad]: the size threshold)."""

    def __init__(self, min_angle: float) -> None:
        self.min_angle = min_angle
        self.stats = SlipStats()
        # Each event's (stamp of its first step, size [rad]), oldest first.
        self.events: list[tuple[int, float]] = []
        # Each event's (stamp of its first step, stamp of its last step): the steps it
        # spans, which offline calibration leaves out (as many as ``events`` holds).
        self.spans: list[tuple[int, int]] = []
        self._start: int | None = None  # the current run's first step, its last, size
        self._last = 0
        self._size = 0.0
        self._named = False

    def step(self, slip: bool, stamp_ns: int, error: float) -> None:
        """One judged step (in stamp order): ``error`` the wheels' heading minus the gyro's."""
        if not slip:
            return
        s = self.stats
        start = self._start
        if (start is None or stamp_ns < self._last or stamp_ns - self._last > MERGE_S * 1e9
                or (not self._named and stamp_ns - start > MAX_RUN_S * 1e9)):
            self._start = start = stamp_ns
            self._size, self._named = 0.0, False
        self._last = stamp_ns
        before = abs(self._size)
        self._size += error
        size = abs(self._size)
        steps = s.steps + 1
        if self._named:
            self.events[-1] = (start, size)
            self.spans[-1] = (start, stamp_ns)
            self.stats = SlipStats(s.events, steps, stamp_ns, size,
                                   s.total_size + size - before)
        elif size >= self.min_angle:
            self._named = True
            self.events.append((start, size))
            self.spans.append((start, stamp_ns))
            del self.events[:-MAX_EVENTS], self.spans[:-MAX_EVENTS]
            self.stats = SlipStats(s.events + 1, steps, stamp_ns, size, s.total_size + size)
        else:
            self.stats = SlipStats(s.events, steps, s.last_stamp_ns, s.last_size,
                                   s.total_size)
