"""Every use of rosbags beyond its public API, in this one module (rosbags 0.11, pinned).

Why one module: rosbags' public API (``Reader``, ``Writer``, ``AnyReader``,
``get_typestore`` and its ``Typestore``, ``rosbags.interfaces``) serves every tool, but
five jobs have no public way in, and a minor release may change what they lean on.
setup.py pins rosbags to the tested minor version, and test/tools/bags/
test_rosbagsinternals.py checks each name and attribute below, one test each, so an
upgrade fails there, naming what moved, before a tool misbehaves:

- MCAP in bulk (:class:`FastWriter`, :func:`write_rows`): rosbags' ``McapWriter``
  with its pending chunk (``PendingChunk``, ``chunk``, ``chunks``, ``channel_stats``,
  ``compressor``, ``close_chunk``), its record helpers (``write_record``,
  ``write_string``) and ``Writer``'s ``STORAGE_PLUGINS``, ``storage`` and ``counts``.
  Neither public writer serves: one message at a time, rosbags' ``Writer.write`` took
  5.1x and the mcap library's ``Writer.add_message`` 5.6x the bulk path's 1.7 us a
  message (replay's Odometry and /tf rows; ``bench/bench_replay.py --only-writers``,
  doc/benchmarks.md);
- a torn MCAP's compressed chunks (:func:`decompress`): ``storage_mcap.DECOMPRESSORS``;
- rosbag2's QoS text (``parse_qos``, ``dump_qos_v9``): a recovered connection's
  profiles, and the ``metadata.yaml`` reindex writes;
- ROS 1 bytes to CDR (``is_same_wireformat``, ``migrate_bytes``): what
  ``rosbags-convert`` does, message by message;
- ``AnyReader`` over storage readers of our own (:func:`adopt`): the attributes its
  ``__init__`` sets, and the sub-reader interface its ``open`` and ``messages`` use.
"""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Mapping, Sequence
from io import BytesIO
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
import numpy.typing as npt
from rosbags.convert.converter import is_same_wireformat, migrate_bytes
from rosbags.highlevel import AnyReader
from rosbags.interfaces import Connection
from rosbags.rosbag2 import CompressionMode, StoragePlugin, Writer
from rosbags.rosbag2.metadata import dump_qos_v9, parse_qos
from rosbags.rosbag2.storage_mcap import (
    DECOMPRESSORS,
    McapWriter,
    PendingChunk,
    write_record,
    write_string,
)
from rosbags.typesys import Stores, get_typestore
from rosbags.typesys.store import Typestore

from diffdrive_odom.tools.bags import bulkmcap

__all__ = ["ANY_READER_ATTRIBUTES", "CHUNK_LIMIT", "FastMcapWriter", "FastWriter", "adopt",
           "decompress", "dump_qos_v9", "is_same_wireformat", "migrate_bytes", "parse_qos",
           "supported", "write_rows"]

CHUNK_LIMIT = 2**20  # rosbags closes a chunk once its records pass this many bytes
# What AnyReader.__init__ sets, all of which its other methods read.
ANY_READER_ATTRIBUTES = ("paths", "is2", "stack", "connections", "default_typestore",
                         "typestore", "readers")


class FastMcapWriter(McapWriter):
    """rosbags' MCAP storage, a chunk's index packed by numpy, written by a thread."""

    def __init__(self, path: Path, compression: CompressionMode) -> None:
        super().__init__(path, compression)
        self.bio = bulkmcap.BackgroundFile(self.bio)  # type: ignore[assignment,arg-type,has-type]

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
            index = bulkmcap.index(msgs)
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

    The same records, chunks and counts as ``writer.write`` called once per message:
    a chunk is closed after the first record that takes it past :data:`CHUNK_LIMIT`.
    """
    n = len(log_ns)
    if n == 0:
        return
    storage: Any = writer.storage
    records = bulkmcap.pack([c.id for c in conns], log_ns, payloads)
    ends = records.ends
    first = 0
    while first < len(ends):
        base = int(ends[first - 1]) if first else 0
        chunk = storage.chunk
        tell = chunk.bio.tell()
        over = np.nonzero(tell + ends[first:] - base > CHUNK_LIMIT)[0]
        last = first + int(over[0]) if len(over) else len(ends) - 1
        chunk.bio.write(records.raw[base:int(ends[last])])
        stamps = records.stamps[first:last + 1]
        chunk.message_start_time = min(int(stamps.min()), chunk.message_start_time)
        chunk.message_end_time = max(int(stamps.max()), chunk.message_end_time)
        for cid, rows in bulkmcap.chunk_index(records, first, last, tell, base):
            chunk.msgs[cid].append(rows)  # close_chunk's bulkmcap.index reads both kinds
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


def decompress(compression: str, data: bytes, size: int) -> bytes:
    """An MCAP chunk's records, ``size`` bytes once decompressed; KeyError if unknown."""
    return bytes(DECOMPRESSORS[compression](data, size))


def adopt(reader: AnyReader, path: Path, readers: Sequence[Any],
          default_typestore: Typestore | None) -> None:
    """Set what ``AnyReader.__init__`` sets, over ``readers`` of our own, for ``path``.

    Why: ``AnyReader.__init__`` builds rosbags' readers, which refuse a recording cut
    short; with these attributes its ``open``, ``messages`` and ``topics`` run over
    readers that offer the sub-reader interface (``connections``, ``messages``,
    ``start_time``, ``end_time``, ``message_count``, ``topics``, a context manager).
    """
    reader.paths = [path]
    reader.is2 = True
    reader.stack = None
    reader.connections = []
    reader.default_typestore = default_typestore
    reader.typestore = get_typestore(Stores.EMPTY)
    reader.readers = list(readers)
