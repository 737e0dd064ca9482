"""Readings in header stamp order: the one rule, for single readings and for blocks.

Why: the estimator works on measurement time, and a recorder logs in arrival order,
so a bag's readings are put back in stamp order while they stream (memory stays
constant whatever the bag's length). The one-by-one readers and the block reader go
through this one rule, so a block never changes the order a reading comes out in
(test/tools/bags/test_joint_blocks.py checks it against the heap written out).
"""

from __future__ import annotations

import heapq
import itertools
from collections.abc import Iterator
from typing import Any, Protocol

import numpy as np

from diffdrive_odom.core.bulk.readings import JointBlock

# Readings displaced further than this many messages from stamp order still come out,
# in arrival order (the estimator then drops the late one, as the node would).
REORDER_WINDOW = 64


class Stamped(Protocol):
    """What is put in order: a JointState reading or an Imu sample."""

    @property
    def stamp_ns(self) -> int:
        """The header stamp [ns]."""


class Reorder:
    """Items in header stamp order: the one rule, for single items and for blocks.

    A heap of ``window`` items: an item displaced further than that from stamp order
    comes out in arrival order (the estimator then drops the late one, as the node
    would). A stamp more than ``jump_back_ns`` behind the newest seen is a new run (a
    looped play, a restarted simulation): everything before it comes out first, so two
    runs are never merged.

    A block (:meth:`push_block`) whose stamps are in order and start at or after every
    stamp seen is held whole instead of going through the heap item by item: the heap
    would have let out everything queued before it, then all of it but its last
    ``window`` items, in this same order. When a single item follows, exactly that
    happens (:meth:`_release`); when another such block follows, the held one goes out.
    """

    def __init__(self, window: int, jump_back_ns: int) -> None:
        self.window, self._jump = window, jump_back_ns
        self._heap: list[tuple[int, int, Any]] = []
        self._order = itertools.count()
        self._newest: int | None = None
        self._held: JointBlock | None = None

    def push(self, item: Stamped) -> Iterator[Any]:
        """Queue one item; whatever the heap lets out."""
        yield from self._release()
        if self._newest is not None and item.stamp_ns < self._newest - self._jump:
            yield from self.flush()
        self._newest = item.stamp_ns if self._newest is None else max(self._newest, item.stamp_ns)
        heapq.heappush(self._heap, (item.stamp_ns, next(self._order), item))
        if len(self._heap) > self.window:
            yield heapq.heappop(self._heap)[2]

    def push_block(self, block: JointBlock) -> Iterator[Any]:
        """Queue a block of readings; whatever comes out (blocks and single readings)."""
        stamps = block.stamp_ns
        if (len(block) < max(self.window, 1) or (np.diff(stamps) < 0).any()
                or (self._newest is not None and int(stamps[0]) < self._newest)):
            for reading in block:
                yield from self.push(reading)
            return
        if self._held is not None:
            yield self._held
        while self._heap:
            yield heapq.heappop(self._heap)[2]
        self._held, self._newest = block, int(stamps[-1])

    def _release(self) -> Iterator[Any]:
        """The held block as the heap would have it: all but its last ``window`` out."""
        held, self._held = self._held, None
        if held is None:
            return
        cut = len(held) - self.window
        if cut > 0:
            yield held[:cut]
        for reading in held[max(cut, 0):]:
            heapq.heappush(self._heap, (reading.stamp_ns, next(self._order), reading))

    def flush(self) -> Iterator[Any]:
        """Everything queued, in order; the next item starts a new run."""
        if self._held is not None:
            yield self._held
            self._held = None
        while self._heap:
            yield heapq.heappop(self._heap)[2]
        self._newest = None
