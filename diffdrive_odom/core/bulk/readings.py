"""Wheel readings as offline work carries them: one at a time, or a block of many alike.

Why: a bag's JointState messages from one driver share one byte layout (the same
names, the same array lengths), so a thousand of them can be decoded with a few numpy
views instead of a thousand Python calls
(:class:`~diffdrive_odom.wire.jointstate.JointBlockDecoder`).
A :class:`JointBlock` keeps them as arrays and is still a sequence of
:class:`JointReading`: the fast lane takes its arrays as they are, and whatever must go
through the one :class:`~diffdrive_odom.core.estimation.pipeline.ReadingPipeline` reading by
reading gets the same reading it would have had from a one-by-one decoder.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from typing import overload

import numpy as np
import numpy.typing as npt


@dataclass(frozen=True)
class JointReading:
    """One JointState as the estimator takes it, plus where it sat in the bag."""

    stamp_ns: int  # header stamp (measurement time)
    log_ns: int  # time the recorder logged it
    names: Sequence[str]
    position: Sequence[float]
    velocity: Sequence[float]


@dataclass(frozen=True, eq=False)
class JointBlock(Sequence[JointReading]):
    """Consecutive readings in stamp order with the same joint names and array lengths.

    ``position`` and ``velocity`` are (n, joints) arrays (``velocity`` may have no
    columns, as a JointState may leave it empty); row ``k`` is reading ``k``.
    """

    stamp_ns: npt.NDArray[np.int64]  # (n,) header stamps
    log_ns: npt.NDArray[np.int64]  # (n,) receive (log) times
    names: tuple[str, ...]
    position: npt.NDArray[np.float64]
    velocity: npt.NDArray[np.float64]

    def __len__(self) -> int:
        return len(self.stamp_ns)

    @overload
    def __getitem__(self, k: int) -> JointReading: ...

    @overload
    def __getitem__(self, k: slice) -> JointBlock: ...

    def __getitem__(self, k: int | slice) -> JointReading | JointBlock:
        if isinstance(k, slice):
            return JointBlock(self.stamp_ns[k], self.log_ns[k], self.names,
                              self.position[k], self.velocity[k])
        return JointReading(int(self.stamp_ns[k]), int(self.log_ns[k]), self.names,
                            tuple(self.position[k].tolist()), tuple(self.velocity[k].tolist()))

    def __iter__(self) -> Iterator[JointReading]:
        for k in range(len(self)):
            yield self[k]


def count(item: object) -> int:
    """Readings in ``item``: a block's length, else 1 (progress counts readings)."""
    return len(item) if isinstance(item, JointBlock) else 1
