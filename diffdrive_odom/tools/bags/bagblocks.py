"""A bag's JointState messages as blocks: runs of alike messages decoded at once.

Why: a driver's messages share one byte layout, so a run of them is a few numpy views
(:class:`~diffdrive_odom.wire.jointstate.JointBlockDecoder`) instead of a Python call
each; replay's fast lane and calibration take the blocks as arrays. The readings and
their order are exactly those of :func:`~diffdrive_odom.tools.bags.bagreadings.iter_readings`:
what is not alike goes through its one-by-one decoder, and everything through the one
stamp-order rule (:class:`~diffdrive_odom.tools.bags.reorder.Reorder`).
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import numpy as np
from rosbags.highlevel import AnyReader

from diffdrive_odom.core.bulk.readings import JointBlock, JointReading
from diffdrive_odom.tools.bags.bagio import JOINT_STATE, connections_for, open_bag
from diffdrive_odom.tools.bags.bagreadings import JointStateReader, Stream, iter_readings
from diffdrive_odom.tools.bags.reorder import REORDER_WINDOW, Reorder
from diffdrive_odom.wire.jointstate import JointBlockDecoder

GROUP = 1024  # messages decoded into blocks at a time (memory stays flat)


def iter_joint_blocks(
    reader: AnyReader,
    topic: str = "/joint_states",
    window: int = REORDER_WINDOW,
    jump_back_ns: int = 1_000_000_000,
) -> Iterator[JointReading | JointBlock]:
    """:func:`iter_readings`, with runs of alike messages as :class:`JointBlock`s.

    The same readings in the same order (opening the blocks gives exactly what
    :func:`iter_readings` yields); a run of messages of one byte layout in stamp
    order is decoded at once. ROS 1 bags, whose bytes that decoder does not read, come
    one by one.
    """
    if not reader.is2:
        yield from iter_readings(reader, topic, stream=Stream(window=window,
                                                              jump_back_ns=jump_back_ns))
        return
    joints = connections_for(reader, topic, (JOINT_STATE,))
    decode, blocks = JointStateReader(reader), JointBlockDecoder()
    order = Reorder(window, jump_back_ns)
    raws: list[bytes] = []
    logs: list[int] = []
    for _, log_ns, raw in reader.messages(connections=joints):  # all of type JOINT_STATE
        raws.append(raw)
        logs.append(log_ns)
        if len(raws) == GROUP:
            yield from _group(raws, logs, decode, blocks, order)
            raws, logs = [], []
    yield from _group(raws, logs, decode, blocks, order)
    yield from order.flush()


def _group(raws: list[bytes], logs: list[int], decode: JointStateReader,
           blocks: JointBlockDecoder, order: Reorder) -> Iterator[JointReading | JointBlock]:
    """One group of raw messages into the reordering: blocks where they are alike."""
    i = 0
    while i < len(raws):
        n, arrays = blocks.decode(raws, i, min_run=order.window)
        if arrays is None:  # a run too short for a block (push_block's rule), or no layout
            for k in range(i, i + n):
                yield from order.push(decode(raws[k], JOINT_STATE, logs[k]))
        else:
            yield from order.push_block(JointBlock(
                arrays.stamp_ns, np.array(logs[i:i + n], dtype=np.int64), arrays.name,
                arrays.position, arrays.velocity))
        i += n


def read_joint_blocks(
    path: str | Path, topic: str = "/joint_states", jump_back_ns: int = 1_000_000_000
) -> Iterator[JointReading | JointBlock]:
    """Open ``path`` and stream its readings as :func:`iter_joint_blocks` gives them."""
    with open_bag(path) as reader:
        yield from iter_joint_blocks(reader, topic, jump_back_ns=jump_back_ns)
