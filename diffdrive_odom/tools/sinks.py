"""Where replay's published poses go: the output bag (odom, /tf), the CSV table, ``--eval``.

Kept apart from the engine (:mod:`diffdrive_odom.tools.replay`), which only decides
what is published; the bytes are the node's own layouts, so the bag holds what the
node would have sent.
"""

from __future__ import annotations

from array import array
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from diffdrive_odom.core.cdr import OdometryLayout, TransformLayout
from diffdrive_odom.core.estimator import Status
from diffdrive_odom.core.integration import Pose2D
from diffdrive_odom.core.metrics import Trajectory
from diffdrive_odom.settings.odometry import OdometrySettings

if TYPE_CHECKING:  # the bag library only where a bag is read or written (``tools`` extra)
    from rosbags.highlevel import AnyReader
    from rosbags.interfaces import Connection

    from diffdrive_odom.tools import bagio


@dataclass
class Published:
    """One pose the node would publish."""

    stamp_ns: int
    log_ns: int
    pose: Pose2D
    linear: float
    angular: float
    status: Status
    pose_covariance: Sequence[float]  # 6x6 row-major, as the node publishes it
    twist_covariance: Sequence[float]


class PoseLog:
    """Published poses kept compactly (32 bytes each) for ``--eval``."""

    def __init__(self) -> None:
        self.stamp_ns = array("q")
        self.xyz = array("d")

    def add(self, p: Published) -> None:
        """Keep the stamp and the planar pose of ``p``."""
        self.stamp_ns.append(p.stamp_ns)
        self.xyz.extend((p.pose.x, p.pose.y, p.pose.theta))

    def trajectory(self) -> Trajectory:
        """The poses kept, as eval's trajectory."""
        return Trajectory.from_arrays(
            np.frombuffer(self.stamp_ns, dtype=np.int64),
            *np.frombuffer(self.xyz, dtype=np.float64).reshape(-1, 3).T,
        )


def keep_input(reader: AnyReader, writer: bagio.BagWriter, odom_topic: str) -> bagio.Passthrough:
    """Copy every input message (converted to CDR) into the output bag as it streams by."""
    from diffdrive_odom.tools import bagio

    convert = bagio.CdrConverter(reader)
    for conn in reader.connections:
        if conn.topic == odom_topic:
            raise bagio.BagError(
                f"--keep-input: the input bag already has {conn.topic}; choose another "
                "--odom-topic for the replayed odometry")
    registered: set[str] = set()

    def passthrough(conn: Connection, log_ns: int, raw: bytes) -> None:
        data = convert(conn, raw)
        if conn.topic not in registered:
            writer.add_topic(conn.topic, conn.msgtype, convert.typestore)
            registered.add(conn.topic)
        writer.write_cdr(conn.topic, log_ns, data)

    return passthrough


def output_sink(
    settings: OdometrySettings,
    writer: bagio.BagWriter | None,
    csv_out: bagio.CsvWriter | None,
    traj: PoseLog | None = None,
    *,
    odom_topic: str = "/odom",
    tf_topic: str = "/tf",
) -> Callable[[Published], None]:
    """Where each published pose goes: output bag, CSV table, ``--eval`` trajectory.

    The bag's topics are registered by the caller.
    """
    # The node's own byte layouts: the bag holds what the node would have published.
    odom = OdometryLayout(settings.odom_frame_id, settings.base_frame_id)
    transform = TransformLayout(settings.odom_frame_id, settings.base_frame_id)
    tf = settings.enable_odom_tf

    def sink(p: Published) -> None:
        x, y, yaw = p.pose.x, p.pose.y, p.pose.theta
        if writer is not None:
            odom.covariance(p.pose_covariance, p.twist_covariance)
            writer.write_cdr(odom_topic, p.log_ns,
                             odom.planar(p.stamp_ns, x, y, yaw, p.linear, p.angular))
            if tf:
                writer.write_cdr(tf_topic, p.log_ns, transform.planar(p.stamp_ns, x, y, yaw))
        if csv_out is not None:
            csv_out.row(p.stamp_ns, x, y, yaw, linear=p.linear, angular=p.angular,
                        status=p.status.value, pose_covariance=p.pose_covariance)
        if traj is not None:
            traj.add(p)

    return sink
