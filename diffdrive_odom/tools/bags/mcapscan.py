"""An MCAP file read record by record from its start, as far as it goes (no summary).

Why: an MCAP file is only indexed once its summary and footer are written, so the one
a recorder left behind when the power went holds whole records up to some byte and
then half of one. The records are length-prefixed (opcode, uint64 length), so walking
them from the magic needs nothing at the end of the file: every whole record before the
tear is read; a record cut short is dropped, never passed on short. A chunk the tear
cut gives the whole records it holds when it is stored uncompressed (they are plain
bytes up to the tear); a compressed one cannot be opened without its end, so the
recording stops at the last whole chunk. A whole chunk that fails its checksum or
does not decompress is dropped and said so.

The messages are located, not copied: each one's log time, channel, and where its
bytes are (the file for unchunked records and uncompressed chunks, else a chunk to
decompress again when read). Sorting that index by log time, stably, gives the order
rosbags reads an intact file in: log time, ties by position in the file.
"""

from __future__ import annotations

import mmap
import struct
from array import array
from collections import OrderedDict
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import numpy.typing as npt

from diffdrive_odom.tools.bags.rosbagsinternals import decompress

MAGIC = b"\x89MCAP0\r\n"
_RECORD = struct.Struct("<BQ")  # opcode, length of the body
_MESSAGE = struct.Struct("<HIQQ")  # channel, sequence, log time, publish time
_CHUNK = struct.Struct("<QQQI")  # start, end, uncompressed size, uncompressed crc
HEADER, FOOTER, SCHEMA, CHANNEL, MESSAGE, CHUNK, DATA_END = 1, 2, 3, 4, 5, 6, 0x0F
IN_FILE = -1  # a message's bytes are in the file itself (not in a compressed chunk)


class NotMcapError(ValueError):
    """The file does not start as an MCAP file does."""


@dataclass(frozen=True)
class Schema:
    """An MCAP schema record: a type name and its definition."""

    name: str
    encoding: str
    data: bytes


@dataclass(frozen=True)
class Channel:
    """An MCAP channel record: topic, schema and its metadata map (raw)."""

    id: int
    schema_id: int
    topic: str
    encoding: str
    metadata: bytes


@dataclass
class Scan:
    """What one pass over the file found; :meth:`order` is the reading order."""

    size: int
    schemas: dict[int, Schema] = field(default_factory=dict)
    channels: dict[int, Channel] = field(default_factory=dict)
    chunks: list[tuple[int, int, str, int]] = field(default_factory=list)
    located: array[int] = field(default_factory=lambda: array("q"))  # 5 numbers a message
    complete: bool = False  # the footer (or the summary's data end) was reached
    good_bytes: int = 0  # where the last whole record ends
    lost: list[str] = field(default_factory=list)

    def add(self, log: int, chan: int, source: int, start: int, length: int) -> None:
        """Locate one message."""
        self.located.extend((log, chan, source, start, length))

    def columns(self) -> npt.NDArray[np.int64]:
        """(log, channel, source, start, length) rows in reading order.

        Log time, ties by position in the file: a stable sort (none when in order).
        """
        rows = np.frombuffer(self.located, dtype=np.int64).reshape(-1, 5)
        log = rows[:, 0]
        if len(log) < 2 or bool((log[1:] >= log[:-1]).all()):
            return rows
        return rows[np.argsort(log, kind="stable")]


def _string(buf: bytes | mmap.mmap, pos: int) -> tuple[str, int]:
    (n,) = struct.unpack_from("<I", buf, pos)
    return bytes(buf[pos + 4:pos + 4 + n]).decode(), pos + 4 + n


def _schema_channel(scan: Scan, op: int, buf: bytes | mmap.mmap, pos: int) -> None:
    """Parse a schema or channel record body starting at ``pos`` (a damaged one: noted)."""
    try:
        _parse_schema_channel(scan, op, buf, pos)
    except (struct.error, UnicodeDecodeError):
        scan.lost.append(f"a damaged {'schema' if op == SCHEMA else 'channel'} record")


def _parse_schema_channel(scan: Scan, op: int, buf: bytes | mmap.mmap, pos: int) -> None:
    if op == SCHEMA:
        (sid,) = struct.unpack_from("<H", buf, pos)
        name, pos = _string(buf, pos + 2)
        encoding, pos = _string(buf, pos)
        (n,) = struct.unpack_from("<I", buf, pos)
        scan.schemas[sid] = Schema(name, encoding, bytes(buf[pos + 4:pos + 4 + n]))
    else:
        cid, sid = struct.unpack_from("<HH", buf, pos)
        topic, pos = _string(buf, pos + 4)
        encoding, pos = _string(buf, pos)
        (n,) = struct.unpack_from("<I", buf, pos)
        scan.channels[cid] = Channel(cid, sid, topic, encoding, bytes(buf[pos + 4:pos + 4 + n]))


def _records(scan: Scan, buf: bytes | mmap.mmap, begin: int, end: int, source: int) -> int:
    """The whole records of chunk data in ``buf[begin:end]``; where the last one ends.

    Message positions are noted in ``buf`` (the file itself for an uncompressed chunk,
    ``source`` :data:`IN_FILE`; else the decompressed chunk ``source``).
    """
    pos, unpack, head = begin, _RECORD.unpack_from, _RECORD.size
    while pos + head <= end:
        op, length = unpack(buf, pos)
        body, after = pos + head, pos + head + length
        if after > end or (op == MESSAGE and length < _MESSAGE.size):
            break
        if op == MESSAGE:
            chan, _, log, _ = _MESSAGE.unpack_from(buf, body)
            scan.add(log, chan, source, body + _MESSAGE.size, length - _MESSAGE.size)
        elif op in (SCHEMA, CHANNEL):
            _schema_channel(scan, op, buf, body)
        pos = after
    return pos


def _chunk(scan: Scan, buf: mmap.mmap, body: int, end: int, whole: bool) -> None:
    """One chunk record (``whole``: not cut by the end of the file)."""
    if body + _CHUNK.size + 4 > end:
        scan.lost.append("a chunk cut in its header")
        return
    _, _, size, crc = _CHUNK.unpack_from(buf, body)
    (n,) = struct.unpack_from("<I", buf, body + _CHUNK.size)
    if body + _CHUNK.size + 4 + n + 8 > end:
        scan.lost.append("a chunk cut in its header")
        return
    compression, pos = _string(buf, body + _CHUNK.size)
    (stored,) = struct.unpack_from("<Q", buf, pos)
    data = pos + 8
    if not compression:
        stop = min(data + stored, end)
        scan.good_bytes = _records(scan, buf, data, stop, IN_FILE)
        if scan.good_bytes < stop or not whole:
            scan.lost.append("the record the tear cut in an uncompressed chunk")
        return
    if not whole:
        scan.lost.append(f"a {compression} chunk cut by the tear")
        return
    try:
        raw = chunk_bytes(buf, data, stored, compression, size)
    except ValueError as err:
        scan.lost.append(f"a chunk that does not decompress ({err})")
        return
    if crc and _crc(raw) != crc:
        scan.lost.append("a chunk that fails its checksum")
        return
    scan.chunks.append((data, stored, compression, size))
    if _records(scan, raw, 0, len(raw), len(scan.chunks) - 1) < len(raw):
        scan.lost.append("a chunk's damaged records")


def _crc(data: bytes) -> int:
    import zlib

    return zlib.crc32(data)


def chunk_bytes(buf: bytes | mmap.mmap, data: int, stored: int, compression: str,
                size: int) -> bytes:
    """A compressed chunk's records (ValueError when they do not come out whole)."""
    try:
        raw = decompress(compression, bytes(buf[data:data + stored]), size)
    except KeyError:
        raise ValueError(f"unknown compression {compression!r}") from None
    except Exception as err:  # each codec has its own error type
        raise ValueError(str(err)) from err
    if len(raw) != size:
        raise ValueError(f"{len(raw)} bytes, {size} expected")
    return bytes(raw)


def scan(buf: mmap.mmap) -> Scan:
    """Walk the records of an MCAP file from its magic to its end or tear."""
    size = len(buf)
    if size < len(MAGIC) or buf[:len(MAGIC)] != MAGIC:
        raise NotMcapError("does not start with the MCAP magic")
    found = Scan(size)
    pos, head, mark = len(MAGIC), _RECORD.size, 0
    while pos < size:
        if pos > mark + Payloads.RELEASE:  # the pages walked past are not needed now
            mark = release(buf, mark, pos - mark)
        if pos + head > size:
            found.lost.append(f"the first {size - pos} bytes of a record header")
            break
        op, length = _RECORD.unpack_from(buf, pos)
        body, after = pos + head, pos + head + length
        whole = after <= size
        if op == CHUNK:
            _chunk(found, buf, body, min(after, size), whole)
        elif not whole:
            what = "message" if op == MESSAGE else f"opcode 0x{op:02x}"
            found.lost.append(f"a {what} record cut mid-payload")
        elif op == MESSAGE and length >= _MESSAGE.size:
            chan, _, log, _ = _MESSAGE.unpack_from(buf, body)
            found.add(log, chan, IN_FILE, body + _MESSAGE.size, length - _MESSAGE.size)
        elif op in (SCHEMA, CHANNEL):
            _schema_channel(found, op, buf, body)
        elif op in (DATA_END, FOOTER):
            found.complete = True
        if not whole:
            break
        found.good_bytes = pos = after
        if found.complete:
            break
    return found


class Payloads:
    """The bytes of located messages: the file's own, or from chunks decompressed again.

    A few decompressed chunks are kept: in log time order a chunk's messages come
    together, so each chunk is decompressed about once more. The mapped pages read are
    let go every :data:`RELEASE` bytes (the kernel reads them again if asked), so
    reading a recording does not keep all of it resident.
    """

    KEEP = 4
    RELEASE = 32 << 20

    def __init__(self, buf: mmap.mmap, chunks: list[tuple[int, int, str, int]]) -> None:
        self._buf, self._chunks = buf, chunks
        self._cache: OrderedDict[int, bytes] = OrderedDict()
        self._mark = 0  # pages before this were let go
        release(buf, 0, len(buf))  # after the scan

    def get(self, source: int, start: int, length: int) -> bytes:
        """One message's bytes."""
        if source == IN_FILE:
            if start > self._mark + self.RELEASE:
                self._mark = release(self._buf, self._mark, start - self._mark)
            return self._buf[start:start + length]
        raw = self._cache.get(source)
        if raw is None:
            raw = self._cache[source] = chunk_bytes(self._buf, *self._chunks[source])
            if len(self._cache) > self.KEEP:
                self._cache.popitem(last=False)
        return raw[start:start + length]


def release(buf: mmap.mmap, start: int, length: int) -> int:
    """Let the kernel drop the mapped pages of ``buf[start:start+length]``; where that ends.

    Whole pages only; a no-op where ``madvise`` is missing (not Linux).
    """
    begin = start - start % mmap.PAGESIZE
    end = (start + length) - (start + length) % mmap.PAGESIZE
    if end > begin and hasattr(buf, "madvise") and hasattr(mmap, "MADV_DONTNEED"):
        buf.madvise(mmap.MADV_DONTNEED, begin, end - begin)
    return max(end, start)


def open_map(path: Path) -> mmap.mmap | None:
    """The file mapped read-only (None for an empty file, which mmap refuses)."""
    with path.open("rb") as f:
        if f.seek(0, 2) == 0:
            return None
        return mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ)

