"""A rosbag2 sqlite3 file read for whatever sqlite can still give, changing nothing.

Why: a power cut can leave the database malformed (a page torn, the file cut short);
sqlite then fails the query that walks into the damage, and rosbags' reader with it.
Here the file is opened read-only and immutable (``mode=ro&immutable=1``: no lock, no
journal or ``-shm`` file beside it, nothing written), the messages' rowids, topics and
log times are read in rowid pages, skipping past a range that fails, and each
message's bytes are read afterwards, in log time order (ties by rowid, the order an
intact bag's timestamp index gives). A row that does not read is dropped and counted.
"""

from __future__ import annotations

import shutil
import sqlite3
import tempfile
from array import array
from collections.abc import Iterator
from pathlib import Path
from typing import Any

BATCH = 256  # messages' bytes asked for at once
_GIVE_UP = 62  # a gallop past damage tries offsets up to 2**this rowids ahead


class NotSqliteError(ValueError):
    """The file is not an sqlite database of a rosbag2 recording."""


def wal_of(path: Path) -> Path | None:
    """The ``-wal`` file a recorder killed in WAL mode left beside ``path`` (None: none)."""
    wal = path.with_name(path.name + "-wal")
    return wal if wal.exists() and wal.stat().st_size else None


def connect(path: Path) -> sqlite3.Connection:
    """The database opened read-only and immutable (nothing is created beside it).

    A file cut short is read from memory instead: sqlite would fill a page cut in
    two with zeros and pass rows from its zeroed part on as data, and a table rooted
    past the end fails the schema. So its whole pages only, padded with zero pages
    (which fail when read) to the length its header gives.
    """
    wal = wal_of(path)
    if wal is not None:
        return _with_wal(path, wal)
    with path.open("rb") as f:
        head = f.read(100)
        size = f.seek(0, 2)
    if len(head) < 100 or not head.startswith(b"SQLite format 3\x00"):
        raise NotSqliteError("not an sqlite database (no sqlite header)")
    page = int.from_bytes(head[16:18], "big")
    page = 65536 if page == 1 else page
    pages = int.from_bytes(head[28:32], "big")
    if size % page == 0 and size >= pages * page:
        uri = f"{path.resolve().as_uri()}?mode=ro&immutable=1"
        try:
            db = sqlite3.connect(uri, uri=True, check_same_thread=False)
            db.execute("SELECT name FROM sqlite_master").fetchall()
            return db
        except sqlite3.DatabaseError as err:
            raise NotSqliteError(f"not a readable sqlite database ({err})") from err
    data = path.read_bytes()
    data = data[:len(data) // page * page]
    try:
        db = sqlite3.connect(":memory:", check_same_thread=False)
        db.deserialize(data + bytes(max(pages * page - len(data), 0)))
        db.execute("SELECT name FROM sqlite_master").fetchall()
    except sqlite3.DatabaseError as err:
        raise NotSqliteError(f"not a readable sqlite database ({err})") from err
    return db


def _with_wal(path: Path, wal: Path) -> sqlite3.Connection:
    """A database whose recorder died in WAL mode, in memory with its ``-wal``.

    Its last committed transactions are in the ``-wal`` file beside it, which
    immutable mode would ignore. Both are copied to a temporary folder (not the
    recording's), checkpointed there, and the result kept in memory.
    """
    with tempfile.TemporaryDirectory() as tmp:
        copy = Path(tmp) / "bag.db3"
        shutil.copyfile(path, copy)
        shutil.copyfile(wal, Path(tmp) / "bag.db3-wal")
        try:
            disk = sqlite3.connect(copy)
            disk.execute("PRAGMA journal_mode=DELETE")  # the WAL into the copy's pages
            image = disk.serialize()
            disk.close()
        except sqlite3.DatabaseError as err:
            raise NotSqliteError(f"not a readable sqlite database ({err})") from err
    db = sqlite3.connect(":memory:", check_same_thread=False)
    db.deserialize(image)
    return db


def _table_rows(db: sqlite3.Connection, query: str) -> list[dict[str, Any]]:
    try:
        cur = db.execute(query)
        names = [d[0] for d in cur.description]
        return [dict(zip(names, row, strict=True)) for row in cur.fetchall()]
    except sqlite3.DatabaseError:
        return []


def topics(db: sqlite3.Connection) -> list[dict[str, Any]]:
    """The topics table's rows (empty where it does not read); NotSqliteError without one."""
    try:
        db.execute("SELECT id, name, type FROM topics LIMIT 0")
        db.execute("SELECT id, topic_id, timestamp, data FROM messages LIMIT 0")
    except sqlite3.DatabaseError as err:
        raise NotSqliteError(f"no rosbag2 topics and messages tables ({err})") from err
    return _table_rows(db, "SELECT * FROM topics")


def definitions(db: sqlite3.Connection) -> dict[str, tuple[str, str]]:
    """Type name -> (encoding, definition) from ``message_definitions`` (rosbag2 >= 8)."""
    rows = _table_rows(db, "SELECT topic_type, encoding, encoded_message_definition "
                           "FROM message_definitions")
    return {r["topic_type"]: (r["encoding"], r["encoded_message_definition"]) for r in rows}


_AFTER = "SELECT id, topic_id, timestamp FROM messages WHERE id > ? ORDER BY id"


def index(db: sqlite3.Connection) -> tuple[array[int], int]:
    """Every (rowid, topic id, log time) that reads, by rowid, flat; the failed ranges.

    Rows come one at a time, so those before the damage are kept. Past a range that
    fails, the next start that reads is found by galloping (1, 2, 4, ... rowids on),
    then bisected back towards the damage, so little that still reads is skipped.
    """
    rows: array[int] = array("q")
    last, failures = -(2**63), 0
    while True:
        try:
            for row in db.execute(_AFTER, (last,)):
                rows.extend(row)
                last = row[0]
            break
        except sqlite3.DatabaseError:
            failures += 1
            resumed = _resume(db, last)
            if resumed is None:
                break
            last = resumed
    return rows, failures


def _reads(db: sqlite3.Connection, after: int) -> bool:
    try:
        db.execute(_AFTER + " LIMIT 1", (after,)).fetchall()
    except sqlite3.DatabaseError:
        return False
    return True


def _resume(db: sqlite3.Connection, last: int) -> int | None:
    """A rowid past ``last`` after which rows read again (None: nothing more reads)."""
    base = max(last, 0)
    bad = base
    for k in range(_GIVE_UP):
        probe = base + (1 << k)
        if _reads(db, probe):
            good = probe
            break
        bad = probe
    else:
        return None
    while good - bad > 1:
        mid = (good + bad) // 2
        if _reads(db, mid):
            good = mid
        else:
            bad = mid
    return good


def payloads(db: sqlite3.Connection, rowids: list[int]) -> Iterator[bytes | None]:
    """Each rowid's message bytes, in the order given; None for one that does not read."""
    for k in range(0, len(rowids), BATCH):
        batch = rowids[k:k + BATCH]
        try:
            marks = ",".join("?" * len(batch))
            got = dict(db.execute(f"SELECT id, data FROM messages WHERE id IN ({marks})",
                                  batch).fetchall())
        except sqlite3.DatabaseError:
            got = {}
            for rid in batch:
                try:
                    row = db.execute("SELECT data FROM messages WHERE id = ?", (rid,)).fetchone()
                except sqlite3.DatabaseError:
                    continue
                if row is not None:
                    got[rid] = row[0]
        for rid in batch:
            data = got.get(rid)
            yield None if data is None else bytes(data)
