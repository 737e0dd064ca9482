"""Opening bags for the offline tools (no rclpy), and finding the topics asked for.

Why one module: every tool (replay, evaluate, calibrate, play) turns a path into a
reader the same way and refuses the same mistakes with the same message. Reading goes
through rosbags' ``AnyReader``, so rosbag2 (sqlite3 or mcap) and ROS 1 bags look the
same; a ROS 2 Jazzy typestore is the default for bags that carry no message
definitions. Anything that is not a bag, a missing topic or one of the wrong type is
one :class:`BagError` naming the path or the topics there are.
"""

from __future__ import annotations

import functools
from collections.abc import Iterable
from pathlib import Path

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


@functools.cache
def typestore() -> Typestore:
    """Return the ROS 2 Jazzy typestore (JointState, Odometry, TFMessage, Clock, ...).

    Shared and never modified: building it (and its serializers) costs ~0.3 s.
    """
    return get_typestore(Stores.ROS2_JAZZY)


# What rosbags raises for a path that is not a bag (or a damaged one).
_NOT_A_BAG = (AnyReaderError, OSError, KeyError, ValueError)


class _Reader(AnyReader):
    """AnyReader whose open() reports a file that is not a bag as one BagError."""

    def open(self) -> None:
        try:
            super().open()
        except _NOT_A_BAG as err:
            raise BagError(f"{self.paths[0]}: not a readable bag ({err})") from err


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
        raise BagError(f"{p}: not a readable bag ({err})") from err


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
