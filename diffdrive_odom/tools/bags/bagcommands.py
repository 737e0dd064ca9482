"""A bag's velocity commands (Twist or TwistStamped) as open-loop odometry takes them.

Why: ``replay -p open_loop:=true`` integrates commands, not wheel readings. A command is
applied when it arrives, so it comes out in *log time* order (the recorder's receive
time, which stands for the node's); a TwistStamped's own stamp only shortens how long it
is held, as in the node. rosbag2 and ROS 1 bags alike (rosbags' deserialisation).
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

from rosbags.highlevel import AnyReader

from diffdrive_odom.tools.bags.bagio import connections_for
from diffdrive_odom.tools.bags.bagreadings import Passthrough
from diffdrive_odom.wire.conversions import stamp_to_ns

TWIST = "geometry_msgs/msg/Twist"
TWIST_STAMPED = "geometry_msgs/msg/TwistStamped"
COMMAND_TYPES = (TWIST, TWIST_STAMPED)


@dataclass(frozen=True, slots=True)
class CommandSample:
    """One command: log time [ns], its own stamp (None: a Twist or a zero stamp), v, w."""

    log_ns: int
    stamp_ns: int | None
    linear: float
    angular: float


def iter_commands(reader: AnyReader, topic: str,
                  passthrough: Passthrough | None = None) -> Iterator[CommandSample]:
    """The commands on ``topic`` of an open reader, in log time order, streaming.

    With ``passthrough`` every message of the bag is handed to it too (``--keep-input``).
    """
    commands = connections_for(reader, topic, COMMAND_TYPES)
    ids = {id(c) for c in commands}
    conns = reader.connections if passthrough is not None else commands
    for conn, log_ns, raw in reader.messages(connections=conns):
        if passthrough is not None:
            passthrough(conn, log_ns, raw)
        if id(conn) not in ids:
            continue
        msg = reader.deserialize(raw, conn.msgtype)
        stamp_ns = None
        if conn.msgtype == TWIST_STAMPED:
            stamp_ns = stamp_to_ns(msg.header.stamp) or None
            msg = msg.twist
        yield CommandSample(log_ns, stamp_ns, float(msg.linear.x), float(msg.angular.z))


def command_topics(reader: AnyReader) -> list[str]:
    """The bag's topics of a command type (for a hint when odometry is missing)."""
    return sorted({str(c.topic) for c in reader.connections if c.msgtype in COMMAND_TYPES})
