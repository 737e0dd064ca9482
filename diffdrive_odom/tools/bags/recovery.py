"""Recordings cut short: a bag folder without ``metadata.yaml``, a torn MCAP, a malformed db3.

Why: rosbag2 writes ``metadata.yaml`` only when a recording closes and an MCAP file is
indexed only once its summary and footer are written, so the recording of the run that
went wrong (power lost, recorder killed) is often a folder of storage files and no
metadata, or an MCAP file torn mid-record; rosbags refuses both. :class:`RecoveredReader`
reads such a recording with rosbags' ``AnyReader`` interface, so every tool that opens
a bag (replay, eval, calibrate, play, fleet runs) reads it as it would the intact one:

- the storage files of a folder, ``_2`` before ``_10`` (rosbag2's split suffix);
- MCAP by walking its records (:mod:`~diffdrive_odom.tools.bags.mcapscan`), sqlite3
  read-only and immutable (:mod:`~diffdrive_odom.tools.bags.sqlitescan`);
- messages in log time order, ties by position in the file (by file, then within it),
  the order rosbags gives for the same messages in an intact bag.

Opening prints one line (``[recovery] ...``) when something was missing or lost: what,
and what was recovered (messages per topic, the log time where the recording stops).
Nothing is written anywhere; ``diffdrive-odom reindex`` writes what is missing on request.
"""

from __future__ import annotations

import mmap
import re
import sqlite3
import sys
from collections import Counter
from collections.abc import Generator, Iterator
from pathlib import Path
from types import TracebackType
from typing import IO, Any, Self

import numpy as np
import numpy.typing as npt
from rosbags.highlevel import AnyReader
from rosbags.interfaces import (
    Connection,
    ConnectionExtRosbag2,
    MessageDefinition,
    MessageDefinitionFormat,
    TopicInfo,
)
from rosbags.typesys.store import Typestore

from diffdrive_odom.tools.bags import mcapscan, rosbagsinternals, sqlitescan
from diffdrive_odom.tools.cmdline import once

SUFFIXES = (".mcap", ".db3")
_FORMATS = {"ros2msg": MessageDefinitionFormat.MSG, "ros2idl": MessageDefinitionFormat.IDL,
            "omgidl": MessageDefinitionFormat.IDL}
_NEVER = 2**63 - 1
BLOCK = 8192  # index rows turned into Python numbers at a time (memory stays small)


class RecoveryError(ValueError):
    """A path that holds no recording (no storage file, or not MCAP / sqlite3)."""


def split_key(path: Path) -> tuple[str, int]:
    """Sort key of a split file: ``bag_2`` before ``bag_10`` (numeric suffix)."""
    m = re.fullmatch(r"(.*?)(\d+)", path.stem)
    return (path.stem, -1) if m is None else (m.group(1), int(m.group(2)))


def storage_files(folder: Path) -> list[Path]:
    """A folder's storage files in recording order."""
    return sorted((p for p in folder.iterdir() if p.suffix in SUFFIXES and p.is_file()),
                  key=split_key)


def mcap_is_whole(path: Path) -> bool:
    """Tell whether an MCAP file ends with the magic (its footer was written)."""
    with path.open("rb") as f:
        if f.seek(0, 2) < 2 * len(mcapscan.MAGIC):
            return False
        f.seek(-len(mcapscan.MAGIC), 2)
        return f.read() == mcapscan.MAGIC


def needs_recovery(path: Path) -> bool:
    """Tell whether rosbags alone cannot open ``path`` (a folder or storage file) whole.

    A folder without ``metadata.yaml`` or with a torn MCAP file; a torn MCAP file; a
    db3 file (rosbags opens one that is malformed, then fails mid-read on the damage).
    """
    if path.is_dir():
        return not (path / "metadata.yaml").exists() or any(
            not mcap_is_whole(f) for f in path.glob("*.mcap"))
    if path.suffix == ".db3":
        return True
    return path.suffix == ".mcap" and not mcap_is_whole(path)


def _msgdef(encoding: str, data: str) -> MessageDefinition:
    fmt = _FORMATS.get(encoding)
    return (MessageDefinition(MessageDefinitionFormat.NONE, "") if fmt is None
            else MessageDefinition(fmt, data))


def _qos(text: Any) -> Any:
    try:
        return rosbagsinternals.parse_qos(text or [])
    except Exception:  # a damaged QoS entry costs the QoS, not the recording
        return []


class Storage:
    """One storage file as ``AnyReader`` uses a reader: connections, messages, times."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.connections: list[Connection] = []
        self.lost: list[str] = []
        self.whole = True  # nothing was found missing or damaged
        self.size = 0  # the file's bytes, and those that were read (MCAP)
        self.read_bytes = 0
        self.torn = False  # the file ends before its last record does (MCAP)
        # (log time, ...) of every message kept, in reading order
        self._rows: npt.NDArray[np.int64] = np.zeros((0, 3), dtype=np.int64)

    def __enter__(self) -> Self:
        try:
            self.open()
        except (mcapscan.NotMcapError, sqlitescan.NotSqliteError) as err:
            raise RecoveryError(f"{self.path.name}: {err}") from err
        except OSError as err:
            raise RecoveryError(f"{self.path.name}: {err.strerror or err}") from err
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()

    def open(self) -> None:
        """Read the file's index."""
        raise NotImplementedError

    def close(self) -> None:
        """Release the file."""

    def _connections(self, found: list[tuple[int, str, str, MessageDefinition, str, Any]],
                     counts: Counter[int]) -> None:
        self.connections = [
            Connection(cid, topic, msgtype, msgdef, "", counts.get(cid, 0),
                       ConnectionExtRosbag2(fmt, qos), self)
            for cid, topic, msgtype, msgdef, fmt, qos in found]

    @property
    def start_time(self) -> int:
        """Log time of the earliest message (ns)."""
        return int(self._rows[:, 0].min()) if len(self._rows) else _NEVER

    @property
    def end_time(self) -> int:
        """Just after the latest message (ns; exclusive, as rosbags)."""
        return int(self._rows[:, 0].max()) + 1 if len(self._rows) else 0

    @property
    def message_count(self) -> int:
        """Messages recovered."""
        return len(self._rows)

    def _selected(self, connections: Any, start: int | None, stop: int | None,
                  column: int, rows: npt.NDArray[np.int64] | None = None
                  ) -> Iterator[tuple[Connection, list[int]]]:
        """Rows of the wanted connections (id in ``column``) and times, in blocks."""
        wanted = {c.id: c for c in (connections or self.connections)}
        ids = np.array(sorted(wanted), dtype=np.int64)
        lo, hi = (0 if start is None else start), (_NEVER if stop is None else stop)
        rows = self._rows if rows is None else rows
        for k in range(0, len(rows), BLOCK):
            block = rows[k:k + BLOCK]
            keep = np.isin(block[:, column], ids) & (block[:, 0] >= lo) & (block[:, 0] < hi)
            for row in block[keep].tolist():
                yield wanted[row[column]], row

    @property
    def topics(self) -> dict[str, TopicInfo]:
        """Topic -> TopicInfo, as rosbags' readers give it."""
        return {c.topic: TopicInfo(c.msgtype, c.msgdef, c.msgcount, [c])
                for c in self.connections}


class McapStorage(Storage):
    """An MCAP file walked record by record (:func:`mcapscan.scan`)."""

    _buf: mmap.mmap | None = None

    def open(self) -> None:
        """Walk the records once; locate every whole message."""
        buf = mcapscan.open_map(self.path)
        if buf is None:
            raise mcapscan.NotMcapError("empty file")
        self._buf = buf
        found = mcapscan.scan(buf)
        self.size, self.read_bytes = found.size, found.good_bytes
        self.torn = not mcap_is_whole(self.path)
        self.whole = found.complete and not found.lost and not self.torn
        self.lost = found.lost
        known = [cid for cid, ch in found.channels.items() if ch.schema_id in found.schemas]
        rows = found.columns()
        kept = np.isin(rows[:, 1], np.array(known, dtype=np.int64))
        if not kept.all():
            self.lost.append(f"{int((~kept).sum())} messages of unknown channels")
            rows = rows[kept]
        self._rows = rows
        self._payloads = mcapscan.Payloads(buf, found.chunks)
        counts = Counter(rows[:, 1].tolist())
        self._connections([
            (cid, ch.topic, (s := found.schemas[ch.schema_id]).name,
             _msgdef(s.encoding, s.data.decode(errors="replace")), ch.encoding,
             _qos(_channel_qos(ch.metadata)))
            for cid, ch in sorted(found.channels.items()) if cid in known], counts)

    def close(self) -> None:
        """Unmap the file."""
        buf = self._buf
        if buf is not None:
            self._payloads = mcapscan.Payloads(buf, [])
            buf.close()
            self._buf = None

    def messages(self, connections: Any = (), start: int | None = None,
                 stop: int | None = None) -> Any:
        """(connection, log time, bytes) in log time order, ties by position."""
        get = self._payloads.get
        for conn, (log, _, source, begin, length) in self._selected(connections, start, stop, 1):
            yield conn, log, get(source, begin, length)


def _channel_qos(metadata: bytes) -> str:
    """The ``offered_qos_profiles`` entry of a channel's metadata map ('' if none)."""
    pos = 0
    try:
        while pos < len(metadata):
            key, pos = mcapscan._string(metadata, pos)
            value, pos = mcapscan._string(metadata, pos)
            if key == "offered_qos_profiles":
                return value
    except Exception:  # a damaged map costs the QoS only
        pass
    return ""


class SqliteStorage(Storage):
    """A rosbag2 sqlite3 file, read-only and immutable (:mod:`sqlitescan`)."""

    _db: sqlite3.Connection | None = None

    def open(self) -> None:
        """Read the topics and every message row's index that still reads."""
        self.size = self.path.stat().st_size
        self._db = db = sqlitescan.connect(self.path)
        tops = sqlitescan.topics(db)
        defs = sqlitescan.definitions(db)
        rows, failures = sqlitescan.index(db)
        index = np.frombuffer(rows, dtype=np.int64).reshape(-1, 3)[:, (2, 1, 0)]
        kept = index[np.isin(index[:, 1], np.array([t["id"] for t in tops], dtype=np.int64))]
        kept = kept[np.argsort(kept[:, 0], kind="stable")]  # log time, ties by rowid
        if failures:
            self.lost.append(f"{failures} damaged range{'s' if failures > 1 else ''} of rows")
        if len(kept) < len(index):
            self.lost.append(f"{len(index) - len(kept)} messages of unreadable topics")
        # with a -wal, rosbags (immutable) would miss its commits: not whole for reindex
        self.whole = not self.lost and sqlitescan.wal_of(self.path) is None
        self._rows = kept
        # rows in log time order by rowid, none damaged: one streaming query reads them
        self._streams = not failures and bool((np.diff(index[:, 0]) >= 0).all())
        counts = Counter(kept[:, 1].tolist())
        self._connections([
            (t["id"], t["name"], t["type"], _msgdef(*defs.get(t["type"], ("", ""))),
             t.get("serialization_format") or "cdr", _qos(t.get("offered_qos_profiles")))
            for t in tops], counts)
        self.unread = 0  # rows indexed whose bytes then did not read

    def close(self) -> None:
        """Close the database."""
        db = self._db
        if db is not None:
            db.close()
            self._db = None

    def messages(self, connections: Any = (), start: int | None = None,
                 stop: int | None = None) -> Any:
        """(connection, log time, bytes) by log time, ties by rowid."""
        rows = self._rows
        if self._streams:
            last = yield from self._stream(connections, start, stop)
            if last is None:
                return
            rows = rows[rows[:, 2] > last]  # damage the index did not meet: row by row
        pending: list[tuple[Connection, list[int]]] = []
        for item in self._selected(connections, start, stop, 1, rows):
            pending.append(item)
            if len(pending) == sqlitescan.BATCH:
                yield from self._fetch(pending)
                pending = []
        yield from self._fetch(pending)

    def _stream(self, connections: Any, start: int | None, stop: int | None
                ) -> Generator[tuple[Connection, int, bytes], None, int | None]:
        """Every row by rowid in one query; None, or the last rowid read before damage."""
        assert self._db is not None, "not open"
        wanted = {c.id: c for c in (connections or self.connections)}
        lo, hi = (0 if start is None else start), (_NEVER if stop is None else stop)
        last = -(2**63)
        try:
            for rowid, topic_id, log, data in self._db.execute(
                    "SELECT id, topic_id, timestamp, data FROM messages ORDER BY id"):
                last = rowid
                conn = wanted.get(topic_id)
                if conn is not None and lo <= log < hi:
                    yield conn, log, data
        except sqlite3.DatabaseError:
            return last
        return None

    def _fetch(self, pending: list[tuple[Connection, list[int]]]
               ) -> Iterator[tuple[Connection, int, bytes]]:
        assert self._db is not None, "not open"
        datas = sqlitescan.payloads(self._db, [row[2] for _, row in pending])
        for (conn, row), data in zip(pending, datas, strict=True):
            if data is None:
                self.unread += 1
                continue
            yield conn, row[0], data


def open_storage(path: Path) -> Storage:
    """The storage reader for one file (by its suffix; MCAP by its magic otherwise)."""
    if path.suffix == ".db3":
        return SqliteStorage(path)
    if path.suffix != ".mcap":
        with path.open("rb") as f:
            if f.read(len(mcapscan.MAGIC)) != mcapscan.MAGIC:
                return SqliteStorage(path)
    return McapStorage(path)


class RecoveredReader(AnyReader):
    """rosbags' ``AnyReader`` over storage readers of :mod:`recovery` instead of rosbags'.

    Opened, it prints :attr:`note` (one line) when something was missing or lost.
    """

    def __init__(self, path: Path, *, default_typestore: Typestore | None = None,
                 report: IO[str] | None = None) -> None:
        # AnyReader's own __init__ would build rosbags' readers, which refuse these
        # files: what it sets is set over this module's readers instead.
        if not path.exists():
            raise RecoveryError(f"{path}: no such file or folder")
        files = [path] if path.is_file() else storage_files(path)
        if not files:
            raise RecoveryError(f"{path}: no metadata.yaml and no .mcap or .db3 file: "
                                "not a recording")
        rosbagsinternals.adopt(self, path, [open_storage(f) for f in files], default_typestore)
        self.missing = ("no metadata.yaml" if path.is_dir()
                        and not (path / "metadata.yaml").exists() else "")
        self.note = ""
        self._report = report

    def open(self) -> None:
        """Open every storage file; print the note (on stderr, once per command)."""
        super().open()
        self.note = note(self)
        if self.note and (self._report is not None or once.first_time(self.note)):
            print(self.note, file=self._report or sys.stderr)

    @property
    def storages(self) -> list[Storage]:
        """The storage readers, in recording order."""
        return list(self.readers)  # type: ignore[arg-type]

    @property
    def whole(self) -> bool:
        """Tell whether every storage file was read to its end, nothing lost."""
        return all(s.whole for s in self.storages)


def note(reader: RecoveredReader) -> str:
    """One line: what was missing or lost, what was recovered, where the recording stops."""
    damage = []
    for s in reader.storages:
        if s.whole:
            continue
        where = (f" torn at byte {s.size}" if s.torn else " damaged" if s.lost
                 else " left unfinished")
        dropped = f"dropped: {'; '.join(s.lost)}" if s.lost else "no message lost"
        if isinstance(s, SqliteStorage) and sqlitescan.wal_of(s.path) is not None:
            dropped += "; its -wal read too"
        damage.append(f"{s.path.name}{where} ({dropped})")
    if not reader.missing and not damage:
        return ""
    counts: Counter[str] = Counter()
    for c in reader.connections:
        counts[c.topic] += c.msgcount
    total = sum(counts.values())
    per_topic = ", ".join(f"{t} {n}" for t, n in sorted(counts.items())) or "no topics"
    ends = [s.end_time for s in reader.storages if s.message_count]
    stop = (f"; the recording stops at log time {_seconds(max(ends) - 1)}" if ends
            else "; no message")
    what = "; ".join([m for m in (reader.missing,) if m] + damage)
    return (f"[recovery] {reader.paths[0]}: {what}; recovered {total} messages "
            f"({per_topic}){stop}")


def _seconds(ns: int) -> str:
    return f"{ns // 1_000_000_000}.{ns % 1_000_000_000:09d}"

