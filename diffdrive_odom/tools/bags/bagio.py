"""Opening bags for the offline tools (no rclpy), and finding the topics asked for.

Why one module: every tool (replay, evaluate, calibrate, play) turns a path into a
reader the same way and refuses the same mistakes with the same message. Reading goes
through rosbags' ``AnyReader``, so rosbag2 (sqlite3 or mcap) and ROS 1 bags look the
same; a ROS 2 Jazzy typestore is the default for bags that carry no message
definitions. Anything that is not a bag, a bag damaged on opening or while it is read, a
missing topic or one of the wrong type is one :class:`BagError`: one line naming the
path or the topics there are, and what to do (:func:`unreadable`, :func:`damaged`).
"""

from __future__ import annotations

import functools
from collections.abc import Collection, Generator, Iterable
from pathlib import Path
from typing import Any

from rosbags.highlevel import AnyReader, AnyReaderError
from rosbags.interfaces import Connection
from rosbags.typesys import Stores, get_typestore
from rosbags.typesys.store import Typestore

from diffdrive_odom.tools.bags import recovery

JOINT_STATE = "sensor_msgs/msg/JointState"
IMU = "sensor_msgs/msg/Imu"
ODOMETRY = "nav_msgs/msg/Odometry"
TF_MESSAGE = "tf2_msgs/msg/TFMessage"


class BagError(RuntimeError):
    """A bag that cannot be used as asked (missing topic, wrong type, bad path)."""


class UnreadableBagError(BagError):
    """A path that does not read as a bag, on opening or part way: its data, not the request."""


@functools.cache
def typestore() -> Typestore:
    """Return the ROS 2 Jazzy typestore (JointState, Odometry, TFMessage, Clock, ...).

    Shared and never modified: building it (and its serializers) costs ~0.3 s.
    """
    return get_typestore(Stores.ROS2_JAZZY)


# What rosbags raises for a path that is not a bag (or a damaged one).
_NOT_A_BAG = (AnyReaderError, OSError, KeyError, ValueError)
ROS1_MAGIC = b"#ROSBAG V2.0\n"  # the first line of every ROS 1 bag rosbags reads
KINDS = "a rosbag2 folder, an .mcap or .db3 file, or a ROS 1 .bag"


def _reason(err: BaseException) -> str:
    """An error's first line (a YAML error goes on to quote the file)."""
    lines = [line.strip() for line in str(err).splitlines() if line.strip()]
    return lines[0] if lines else type(err).__name__


def unreadable(path: Path, err: BaseException) -> UnreadableBagError:
    """The one line for ``path`` that does not open as a bag: what is wrong, what to do."""
    reason = _reason(err)
    for named in (f"{path}: ", f"{path.name}: "):  # recovery's errors name the file
        reason = reason.removeprefix(named)
    if path.is_dir():
        if (path / "metadata.yaml").exists():
            return UnreadableBagError(f"{path}: its metadata.yaml does not read ({reason}): move "
                                 "it aside and the storage files are read without it; "
                                 f"`diffdrive-odom reindex {path}` then writes a new one")
        return UnreadableBagError(f"{path}: {reason}; give {KINDS}")
    if path.suffix == ".bag":
        try:
            with path.open("rb") as f:
                head = f.read(len(ROS1_MAGIC))
        except OSError as failed:
            return UnreadableBagError(f"{path}: cannot be read ({failed.strerror or failed})")
        if head != ROS1_MAGIC:
            what = "an empty file" if not head else "it does not start with '#ROSBAG V2.0'"
            return UnreadableBagError(f"{path}: not a ROS 1 bag ({what}); give {KINDS}")
        return UnreadableBagError(f"{path}: a ROS 1 bag whose index does not read ({reason}): a "
                             "recording cut short is made whole by ROS 1's "
                             f"`rosbag reindex {path}`")
    return UnreadableBagError(f"{path}: not a readable bag ({reason}); give {KINDS}")


def damaged(reader: AnyReader, last_ns: int | None, err: BaseException) -> UnreadableBagError:
    """The one line for a bag that fails while it is read, after log time ``last_ns``.

    None: before any message came out (rosbags may open every chunk at the first one).
    """
    path = Path(reader.paths[0])
    where = ("" if last_ns is None
             else f" {(last_ns - reader.start_time) * 1e-9:.1f} s into the recording")
    if reader.is2 and not isinstance(reader, recovery.RecoveredReader):
        files = recovery.storage_files(path) if path.is_dir() else [path]
        todo = (f"`diffdrive-odom reindex {files[0] if len(files) == 1 else path / 'FILE'}` "
                "copies what still reads into a new bag")
    else:
        todo = "it cannot be read past that point: record the run again"
    return UnreadableBagError(f"{path}: damaged{where} ({_reason(err)}): {todo}")


class _Reader(AnyReader):
    """AnyReader whose failures, on opening or while reading, are one BagError each."""

    def open(self) -> None:
        try:
            super().open()
        except _NOT_A_BAG as err:
            raise unreadable(Path(self.paths[0]), err) from err

    def messages(self, connections: Collection[Connection] = (), start: int | None = None,
                 stop: int | None = None) -> Generator[tuple[Connection, int, bytes], None, None]:
        """The messages, as rosbags reads them; damage part way ends them (:func:`damaged`)."""
        last: int | None = None
        try:
            for item in super().messages(connections, start, stop):
                last = item[1]
                yield item
        except Exception as err:  # rosbags' readers and codecs: each has its own error type
            raise damaged(self, last, err) from err

    def deserialize(self, rawdata: bytes, typ: str) -> Any:
        """A message, as rosbags decodes it; one that does not decode is a :class:`BagError`."""
        try:
            return super().deserialize(rawdata, typ)
        except AnyReaderError as err:
            raise UnreadableBagError(f"{self.paths[0]}: a {typ} message does not decode "
                                f"({_reason(err)}): the bag is damaged or its type "
                                "differs from the definition it carries") from err


class _Recovered(_Reader, recovery.RecoveredReader):
    """A recording cut short (no metadata.yaml, torn, malformed): :mod:`.recovery`."""


def open_bag(path: str | Path) -> AnyReader:
    """Return an unopened reader for a rosbag2 dir / ``.mcap`` / ``.db3`` or ROS 1 ``.bag``.

    Use as a context manager. A single rosbag2 storage file is accepted for
    convenience: its directory is opened when it holds the metadata. Anything that is
    not a bag raises :class:`BagError` naming the path, here or on opening.
    """
    p = Path(path)
    if not p.exists():
        raise BagError(f"{p}: no such bag")
    if p.is_file() and p.suffix in (".mcap", ".db3") and (p.parent / "metadata.yaml").exists():
        p = p.parent
    try:
        if recovery.needs_recovery(p):
            return _Recovered(p, default_typestore=typestore())
        return _Reader([p], default_typestore=typestore())
    except _NOT_A_BAG as err:
        raise unreadable(p, err) from err


def connections_for(
    reader: AnyReader, topic: str, msgtypes: Iterable[str] = ()
) -> list[Connection]:
    """Return the connections on ``topic``; BagError naming what exists if none fit."""
    wanted = set(msgtypes)
    found = [c for c in reader.connections if c.topic == topic]
    if not found:
        have = ", ".join(sorted({c.topic for c in reader.connections})) or "none"
        raise BagError(f"topic {topic} is not in the bag (topics: {have})")
    if wanted:
        typed = [c for c in found if c.msgtype in wanted]
        if not typed:
            raise BagError(
                f"topic {topic} has type {found[0].msgtype}, expected one of {sorted(wanted)}"
            )
        found = typed
    return found


def count_messages(reader: AnyReader, topic: str) -> int:
    """Messages on ``topic`` according to the bag's index (no decoding)."""
    return sum(c.msgcount for c in reader.connections if c.topic == topic)
