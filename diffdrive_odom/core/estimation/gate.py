"""The ``publish_rate`` rule: which readings' poses go out, on a schedule in stamp time.

Shared by the node, ``replay`` (both through
:class:`~diffdrive_odom.core.estimation.pipeline.ReadingPipeline`) and the fast lane
(:mod:`diffdrive_odom.core.bulk.fastlane`), which uses the array form
:meth:`PublishGate.passed` beside the scalar :meth:`PublishGate.due`: one rule, two forms.

Why a schedule: a gate that counts one period from the last publication rounds every
interval up to the next reading, so a 150 Hz driver with 1 ms of jitter at 50 Hz gave
about 42 Hz and a 100 Hz driver at 30 Hz gave 25 Hz. Here the poses are due one period
apart in stamp time; the first reading at or after its due time is published (only real
readings are) and the next pose is due one period after the last due time, not after
the reading, so each reading's lateness is not added to the interval and the average
rate is ``min(publish_rate, input rate)``. The schedule lags the readings by at most a
period: when the next due time would already be behind this reading (input slower than
the rate, jitter) it is re-anchored at the reading, so the next reading is due as soon
as it comes and none is lost to an early stamp. A reading over :data:`PAUSE` periods
late (the driver paused) starts a new schedule one period after it, so a pause is never
followed by a catch-up burst nor by two poses a reading apart. A stamp before the last
published one (time went back) starts a new schedule at once. Pure Python for the
scalar form, numpy for the array form.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

SLACK_NS = 1e3  # a stamp this early still meets its due time (stamps rounded to the ns)
PAUSE = 3  # periods of lateness that make a pause: a new schedule, one period on
# passed() tests due times in arrays where a period holds at least this many readings on
# average; with fewer, most readings are published and due() one by one is quicker.
ARRAY_FROM = 4.0


def publish_period_ns(rate: float) -> float:
    """Spacing [ns] of the due times at ``rate`` [Hz]; -inf: no limit (rate <= 0)."""
    return 1e9 / rate if rate > 0.0 else -math.inf


@dataclass(frozen=True, slots=True)
class GateState:
    """Where the schedule stands: the next pose is due ``slot`` periods after ``anchor_ns``.

    ``anchor_ns`` None: nothing published yet (or forgotten: the next pose goes out).
    ``last_ns``: the stamp of the last published pose.
    """

    anchor_ns: int | None = None
    slot: int = 0
    last_ns: int = 0


class PublishGate:
    """The ``publish_rate`` rule (see the module text), in its two forms.

    :meth:`due` takes one pose at a time, :meth:`passed` a stretch of them, with the same
    outcome to the last pose and the same state after.
    """

    def __init__(self, rate: float, state: GateState | None = None) -> None:
        self.rate = rate
        self.state = state or GateState()

    @property
    def rate(self) -> float:
        """Poses per second of measurement time (<= 0: every pose)."""
        return self._rate

    @rate.setter
    def rate(self, rate: float) -> None:
        """A new rate starts a new schedule at the next pose (which is published)."""
        self._rate = rate
        self._period = publish_period_ns(rate)
        self.forget()

    @property
    def state(self) -> GateState:
        """The schedule, to hand over to another gate (the fast lane's and back)."""
        return GateState(self._anchor, self._slot, self._last)

    @state.setter
    def state(self, state: GateState) -> None:
        self._anchor, self._slot, self._last = state.anchor_ns, state.slot, state.last_ns

    def forget(self) -> None:
        """The next pose is published and starts the schedule (reset, new rate, set pose)."""
        self._anchor, self._slot, self._last = None, 0, 0

    def due(self, stamp_ns: int) -> bool:
        """Tell whether the pose stamped ``stamp_ns`` is published (and move on if so)."""
        anchor = self._anchor
        if anchor is None or stamp_ns < self._last or self._period < 0.0:
            self._anchor, self._slot, self._last = stamp_ns, 1, stamp_ns
            return True
        offset = stamp_ns - anchor
        slot = self._slot
        if offset < slot * self._period - SLACK_NS:
            return False
        slot += 1
        period = self._period
        if slot * period <= offset:  # the next due time is behind this reading already
            late = offset - (slot - 1) * period > PAUSE * period
            self._anchor, slot = stamp_ns, 1 if late else 0
        self._slot, self._last = slot, stamp_ns
        return True

    def passed(self, stamps: Sequence[int] | npt.NDArray[np.int64]) -> npt.NDArray[np.int64]:
        """The indices of ``stamps`` (in order) that :meth:`due` publishes, in array form.

        Over each run of non-decreasing stamps the due times are tested all at once
        (``searchsorted``); where a reading re-anchors the schedule, meets two due times
        or goes back in time, the run restarts after it.
        """
        s = np.asarray(stamps, dtype=np.int64)
        n = len(s)
        if self._period < 0.0:
            if n:
                self.due(int(s[-1]))
            return np.arange(n, dtype=np.int64)
        if n < 2 or (s[-1] - s[0]) * ARRAY_FROM >= (n - 1) * self._period:
            due = self.due
            return np.array([k for k, stamp in enumerate(s.tolist()) if due(stamp)],
                            dtype=np.int64)
        back = np.flatnonzero(s[1:] < s[:-1]) + 1  # where a run of non-decreasing stamps ends
        out: list[npt.NDArray[np.int64]] = []
        i = 0
        while i < n:
            k = int(np.searchsorted(back, i, side="right"))
            end = int(back[k]) if k < len(back) else n
            if self._anchor is None or int(s[i]) < self._last:
                self.due(int(s[i]))
                out.append(np.array([i], dtype=np.int64))
                i += 1
                continue
            i = self._run(s, i, end, out)
        return np.concatenate(out) if out else np.zeros(0, dtype=np.int64)

    def _run(self, s: npt.NDArray[np.int64], i: int, end: int,
             out: list[npt.NDArray[np.int64]]) -> int:
        """Publish from ``s[i:end]`` until a reading needs :meth:`due`'s own step.

        ``s[i:end]`` is non-decreasing and none is before the last published stamp.
        Returns the index to go on from.
        """
        assert self._anchor is not None
        offsets = s[i:end] - self._anchor
        period, slot = self._period, self._slot
        # Up to the last reading's due time, and no more than readings (each takes one).
        top = min(max(int(offsets[-1] // period) + 2, slot + 1), slot + len(offsets) + 1)
        slots = np.arange(slot, top, dtype=np.int64)
        at = np.searchsorted(offsets, slots * period - SLACK_NS, side="left")
        at = at[at < len(offsets)]
        if not len(at):
            return end
        late = (slots[:len(at)] + 1) * period <= offsets[at]  # due() re-anchors there
        twice = np.zeros(len(at), dtype=np.bool_)
        twice[:-1] = at[1:] == at[:-1]  # meets the next due time too
        stop = np.flatnonzero(late | twice)
        m = int(stop[0]) + 1 if len(stop) else len(at)
        taken = at[:m]
        last = int(taken[-1])
        self._slot = slot + m - 1  # due() takes the last one: the same state as the loop
        if m > 1:
            self._last = int(s[i + int(taken[-2])])
        self.due(int(s[i + last]))
        out.append(taken + i)
        return i + last + 1
