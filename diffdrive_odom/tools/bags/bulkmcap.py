"""Many messages into rosbags' MCAP writer at once, with the bytes it writes one by one.

Why: rosbags' :class:`~rosbags.rosbag2.storage_mcap.McapWriter` costs ~9 us of Python
per message (a BytesIO and four ``to_bytes`` per record, then two per message-index
entry), more than the whole odometry of a reading, and replay writes two messages
(odom and /tf) per reading. A stretch of the fast lane has fixed-size payloads, so its
MCAP message records (opcode 0x05, uint64 length, uint16 channel, uint32 sequence 0,
uint64 log and publish time, the CDR bytes) are one numpy structured array, written
with one call. The chunk is closed where the one-by-one writer closes it (after the
first record that takes it past 1 MiB), and the message index of a closed chunk is
packed by numpy too; the file is byte for byte the one rosbags writes
(test/tools/bags/test_bulkmcap.py compares them).

This leans on rosbags 0.11's writer internals (``storage.chunk``, ``channel_stats``,
``counts``): :func:`supported` checks they are there, and the caller falls back to
one message at a time otherwise (and for sqlite3).
"""

from __future__ import annotations

import queue
import threading
from collections import defaultdict
from collections.abc import Mapping, Sequence
from io import BytesIO
from pathlib import Path
from typing import Any, BinaryIO, ClassVar

import numpy as np
import numpy.typing as npt
from rosbags.interfaces import Connection
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.rosbag2.enums import CompressionMode
from rosbags.rosbag2.storage_mcap import McapWriter, PendingChunk, write_record, write_string

CHUNK_LIMIT = 2**20  # rosbags closes a chunk once its records pass this many bytes
_HEAD = 1 + 8 + 2 + 4 + 8 + 8  # opcode, length, channel, sequence, log and publish time


class FastMcapWriter(McapWriter):
    """rosbags' MCAP storage, a chunk's index packed by numpy, written by a thread."""

    def __init__(self, path: Path, compression: CompressionMode) -> None:
        super().__init__(path, compression)
        self.bio = BackgroundFile(self.bio)  # type: ignore[assignment,arg-type,has-type]

    def close_chunk(self) -> None:
        """Close the pending chunk: the same records as rosbags' ``close_chunk``."""
        chunk: PendingChunk = self.chunk  # type: ignore[has-type]
        size = chunk.bio.tell()
        compressed = self.compressor(chunk.bio.getvalue())
        head = BytesIO()
        head.write(np.array([chunk.message_start_time, chunk.message_end_time, size],
                            dtype="<u8").tobytes())
        head.write(b"\x00\x00\x00\x00")
        write_string(head, self.compression)
        head.write(len(compressed).to_bytes(8, "little"))
        chunk_start = self.bio.tell()
        # write_record(0x06) of head + compressed, without copying the chunk's bytes again
        self.bio.write(b"\x06" + (head.tell() + len(compressed)).to_bytes(8, "little")
                       + head.getvalue())
        self.bio.write(compressed)
        chunk_end = self.bio.tell()
        offsets: list[tuple[int, int]] = []
        for cid, msgs in chunk.msgs.items():
            offsets.append((cid, self.bio.tell()))
            index = _index(msgs)
            rec = BytesIO()
            rec.write(cid.to_bytes(2, "little"))
            rec.write(index.nbytes.to_bytes(4, "little"))
            rec.write(index.tobytes())
            write_record(self.bio, 0x07, rec)
        rec = BytesIO()
        rec.write(np.array([chunk.message_start_time, chunk.message_end_time, chunk_start,
                            chunk_end - chunk_start], dtype="<u8").tobytes())
        rec.write((len(offsets) * 10).to_bytes(4, "little"))
        for cid, offset in offsets:
            rec.write(cid.to_bytes(2, "little"))
            rec.write(offset.to_bytes(8, "little"))
        rec.write((self.bio.tell() - chunk_end).to_bytes(8, "little"))
        write_string(rec, self.compression)
        rec.write(len(compressed).to_bytes(8, "little"))
        rec.write(size.to_bytes(8, "little"))
        self.chunks.append(rec)
        self.chunk = PendingChunk(2**63 - 1, 0, BytesIO(), defaultdict(list))


def _index(entries: list[Any]) -> npt.NDArray[np.uint64]:
    """A channel's (log time, offset) index rows: rosbags' tuples and :func:`_append`'s arrays."""
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


class FastWriter(Writer):
    """rosbags' rosbag2 :class:`Writer` whose MCAP storage is :class:`FastMcapWriter`."""

    STORAGE_PLUGINS: ClassVar[Mapping[StoragePlugin, type[Any]]] = {
                       **Writer.STORAGE_PLUGINS,
                       **{k: FastMcapWriter for k, v in Writer.STORAGE_PLUGINS.items()
                          if v is McapWriter}}


def supported(writer: Writer) -> bool:
    """Tell whether ``writer`` can take :func:`write_rows` (open, MCAP, uncompressed)."""
    return (isinstance(writer.storage, FastMcapWriter)
            and writer.compression_mode == CompressionMode.NONE)


def write_rows(writer: Writer, conns: Sequence[Connection], log_ns: npt.NDArray[np.int64],
               payloads: Sequence[npt.NDArray[np.uint8]]) -> None:
    """Per row ``k``: ``payloads[j][k]`` on ``conns[j]`` at ``log_ns[k]``, in that order.

    The same records, chunks and counts as ``writer.write`` called once per message.
    """
    n = len(log_ns)
    if n == 0:
        return
    storage: Any = writer.storage
    fields: list[tuple[Any, ...]] = []
    for j, data in enumerate(payloads):
        fields += [(f"op{j}", "u1"), (f"len{j}", "<u8"), (f"ch{j}", "<u2"), (f"seq{j}", "<u4"),
                   (f"log{j}", "<u8"), (f"pub{j}", "<u8"), (f"data{j}", "u1", data.shape[1])]
    table = np.zeros(n, dtype=np.dtype(fields))
    for j, (conn, data) in enumerate(zip(conns, payloads, strict=True)):
        table[f"op{j}"] = 0x05
        table[f"len{j}"] = _HEAD - 9 + data.shape[1]
        table[f"ch{j}"] = conn.id
        table[f"log{j}"] = log_ns
        table[f"pub{j}"] = log_ns
        table[f"data{j}"] = data
    raw = memoryview(table.tobytes())
    sizes = np.array([_HEAD + d.shape[1] for d in payloads], dtype=np.int64)
    ends = np.cumsum(np.tile(sizes, n))  # end of each message record within ``raw``
    stamps = np.repeat(np.asarray(log_ns, dtype=np.int64), len(conns))
    cids = np.tile(np.array([c.id for c in conns]), n)
    first = 0
    while first < len(ends):
        base = int(ends[first - 1]) if first else 0
        tell = storage.chunk.bio.tell()
        over = np.nonzero(tell + ends[first:] - base > CHUNK_LIMIT)[0]
        last = first + int(over[0]) if len(over) else len(ends) - 1
        _append(storage, raw[base:int(ends[last])], tell, base, ends[first:last + 1],
                sizes, stamps[first:last + 1], cids[first:last + 1], first, len(conns))
        if len(over):
            storage.close_chunk()
        first = last + 1
    for conn in conns:
        writer.counts[conn.id] += n
        storage.channel_stats[conn.id] += n
    low, high = int(np.min(log_ns)), int(np.max(log_ns))
    writer.min_timestamp = min(low, writer.min_timestamp)
    writer.max_timestamp = max(high, writer.max_timestamp)
    storage.message_start_time = min(low, storage.message_start_time)
    storage.message_end_time = max(high, storage.message_end_time)


def _append(storage: Any, data: memoryview, tell: int, base: int, ends: npt.NDArray[np.int64],
            sizes: npt.NDArray[np.int64], stamps: npt.NDArray[np.int64],
            cids: npt.NDArray[np.int64], first: int, kinds: int) -> None:
    """Records ``first..`` (their bytes ``data``) into the pending chunk, with its index."""
    chunk = storage.chunk
    starts = tell + ends - base - sizes[(np.arange(len(ends)) + first) % kinds]
    chunk.bio.write(data)
    chunk.message_start_time = min(int(stamps.min()), chunk.message_start_time)
    chunk.message_end_time = max(int(stamps.max()), chunk.message_end_time)
    for cid in dict.fromkeys(cids[:kinds].tolist()):  # first seen first, as one by one
        pick = cids == cid  # the index rows as one array (close_chunk's _index reads both)
        chunk.msgs[cid].append(np.column_stack((stamps[pick], starts[pick])).astype("<u8"))
