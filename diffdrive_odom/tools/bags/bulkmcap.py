"""MCAP message records for many rows at once, packed by numpy; a file written by a thread.

Why: rosbags' :class:`~rosbags.rosbag2.storage_mcap.McapWriter` costs ~9 us of Python
per message (a BytesIO and four ``to_bytes`` per record, then two per message-index
entry), more than the whole odometry of a reading, and replay writes two messages
(odom and /tf) per reading. A stretch of the fast lane has fixed-size payloads, so its
MCAP message records (opcode 0x05, uint64 length, uint16 channel, uint32 sequence 0,
uint64 log and publish time, the CDR bytes) are one numpy structured array, and a
chunk's message index is packed by numpy too.

This module is MCAP's own record layout (its specification) and nothing of rosbags:
:mod:`~diffdrive_odom.tools.bags.rosbagsinternals` puts these records into rosbags'
writer, where its chunks and counts live; the file is byte for byte the one rosbags
writes one message at a time (test/tools/bags/test_bulkmcap.py compares them).
"""

from __future__ import annotations

import queue
import threading
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, BinaryIO

import numpy as np
import numpy.typing as npt

HEAD = 1 + 8 + 2 + 4 + 8 + 8  # opcode, length, channel, sequence, log and publish time


@dataclass(frozen=True)
class Records:
    """Message records of many rows, each row one record per channel, in that order."""

    raw: memoryview  # the records' bytes, back to back
    ends: npt.NDArray[np.int64]  # where each record ends within ``raw``
    sizes: npt.NDArray[np.int64]  # the record size of each channel of a row
    stamps: npt.NDArray[np.int64]  # each record's log time
    channels: npt.NDArray[np.int64]  # each record's channel id
    kinds: int  # channels a row holds


def pack(channel_ids: Sequence[int], log_ns: npt.NDArray[np.int64],
         payloads: Sequence[npt.NDArray[np.uint8]]) -> Records:
    """Per row ``k``: ``payloads[j][k]`` on channel ``channel_ids[j]`` at ``log_ns[k]``."""
    n = len(log_ns)
    fields: list[tuple[Any, ...]] = []
    for j, data in enumerate(payloads):
        fields += [(f"op{j}", "u1"), (f"len{j}", "<u8"), (f"ch{j}", "<u2"), (f"seq{j}", "<u4"),
                   (f"log{j}", "<u8"), (f"pub{j}", "<u8"), (f"data{j}", "u1", data.shape[1])]
    table = np.zeros(n, dtype=np.dtype(fields))
    for j, (cid, data) in enumerate(zip(channel_ids, payloads, strict=True)):
        table[f"op{j}"] = 0x05
        table[f"len{j}"] = HEAD - 9 + data.shape[1]
        table[f"ch{j}"] = cid
        table[f"log{j}"] = log_ns
        table[f"pub{j}"] = log_ns
        table[f"data{j}"] = data
    sizes = np.array([HEAD + d.shape[1] for d in payloads], dtype=np.int64)
    return Records(raw=memoryview(table.tobytes()), ends=np.cumsum(np.tile(sizes, n)),
                   sizes=sizes, stamps=np.repeat(np.asarray(log_ns, dtype=np.int64),
                                                 len(channel_ids)),
                   channels=np.tile(np.array(channel_ids, dtype=np.int64), n),
                   kinds=len(channel_ids))


def chunk_index(records: Records, first: int, last: int, tell: int, base: int
                ) -> list[tuple[int, npt.NDArray[np.uint64]]]:
    """The (log time, offset in the chunk) rows of records ``first..last`` per channel.

    ``tell``: where record ``first`` starts in the chunk; ``base``: where it starts in
    ``records.raw``. Channels first seen first, as one message at a time.
    """
    ends = records.ends[first:last + 1]
    starts = tell + ends - base - records.sizes[(np.arange(len(ends)) + first) % records.kinds]
    stamps, cids = records.stamps[first:last + 1], records.channels[first:last + 1]
    rows = []
    for cid in dict.fromkeys(cids[:records.kinds].tolist()):
        pick = cids == cid
        rows.append((int(cid), np.column_stack((stamps[pick], starts[pick])).astype("<u8")))
    return rows


def index(entries: list[Any]) -> npt.NDArray[np.uint64]:
    """A channel's (log time, offset) index rows, from rosbags' tuples and our arrays."""
    parts: list[npt.NDArray[np.uint64]] = []
    single: list[tuple[int, int]] = []
    for entry in entries:
        if isinstance(entry, np.ndarray):
            if single:
                parts.append(np.array(single, dtype="<u8").reshape(-1, 2))
                single = []
            parts.append(entry)
        else:
            single.append(entry)
    if single or not parts:
        parts.append(np.array(single, dtype="<u8").reshape(-1, 2))
    return np.concatenate(parts) if len(parts) > 1 else parts[0]


class BackgroundFile:
    """A binary file whose writes are done by a thread, in order; ``tell`` is immediate.

    Why: writing replay's output (~1 kB a reading) costs the kernel about as much time
    as the odometry; ``write`` releases the GIL, so on a thread it overlaps the next
    readings' work. Small writes are gathered into blocks; at most :data:`QUEUED` blocks
    wait, so memory stays flat. A failed write is raised by the next call here.
    """

    QUEUED = 4
    GATHER = 1 << 16

    def __init__(self, raw: BinaryIO) -> None:
        self._raw = raw
        self._pos = raw.tell()
        self._small = bytearray()
        self._queue: queue.Queue[bytes | None] = queue.Queue(self.QUEUED)
        self._error: BaseException | None = None
        self._thread = threading.Thread(target=self._run, name="mcap-writer", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while (data := self._queue.get()) is not None:
            if self._error is None:
                try:
                    self._raw.write(data)
                except BaseException as exc:  # raised again in the caller
                    self._error = exc

    def _raise(self) -> None:
        if self._error is not None:
            raise self._error

    def write(self, data: bytes | bytearray | memoryview) -> int:
        """Queue ``data`` (copied unless it is immutable bytes)."""
        self._raise()
        size = len(data)
        if size < self.GATHER:
            self._small += data
            if len(self._small) >= self.GATHER:
                self._queue.put(bytes(self._small))
                self._small.clear()
        else:
            if self._small:
                self._queue.put(bytes(self._small))
                self._small.clear()
            self._queue.put(data if isinstance(data, bytes) else bytes(data))
        self._pos += size
        return size

    def tell(self) -> int:
        """Where the next byte goes (written or still queued)."""
        return self._pos

    def close(self) -> None:
        """Write what is queued, stop the thread, close the file; raise a failed write."""
        if self._thread.is_alive():
            if self._small:
                self._queue.put(bytes(self._small))
                self._small.clear()
            self._queue.put(None)
            self._thread.join()
        self._raw.close()
        self._raise()
