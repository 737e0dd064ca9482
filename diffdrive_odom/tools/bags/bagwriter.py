"""Output bags: rosbag2 written with rosbags' own message classes, by topic name.

Why: replay, the demo's recorder and the tests write odometry bags that ``ros2 bag
play`` and independent readers (mcap-ros2-support) must read. rclpy's serializer pads
some messages in a way strict readers reject, so messages are serialised by rosbags (or
handed over as CDR bytes the wire layer wrote), as rosbag2 with mcap storage by default
or sqlite3 on request; many rows at once go to MCAP in bulk
(:mod:`diffdrive_odom.tools.bags.bulkmcap`, through
:mod:`~diffdrive_odom.tools.bags.rosbagsinternals`).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from types import TracebackType
from typing import Any

import numpy as np
import numpy.typing as npt
from rosbags.interfaces import Connection
from rosbags.rosbag2 import StoragePlugin
from rosbags.typesys.store import Typestore

from diffdrive_odom.tools.bags import rosbagsinternals
from diffdrive_odom.tools.bags.bagio import BagError, typestore
from diffdrive_odom.tools.cmdline.outputs import STORAGES


class BagWriter:
    """A rosbag2 being written: topics by name, messages as objects or CDR bytes.

    Refuses an existing output path (rosbag2 does too) rather than mixing two runs.
    """

    def __init__(self, path: str | Path, storage: str = "mcap") -> None:
        if storage not in STORAGES:
            raise BagError(f"storage must be one of {STORAGES}, got {storage!r}")
        self.path = Path(path)
        if self.path.exists():
            raise BagError(f"{self.path} exists: remove it or choose another output")
        plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
        self._writer = rosbagsinternals.FastWriter(self.path, version=9, storage_plugin=plugin)
        self.typestore = typestore()
        self._conns: dict[str, tuple[Connection, str]] = {}
        self.count = 0

    def __enter__(self) -> BagWriter:
        self._writer.open()
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self._writer.close()

    def add_topic(self, topic: str, msgtype: str, store: Typestore | None = None) -> None:
        """Register ``topic`` once; a second type on the same topic is an error."""
        known = self._conns.get(topic)
        if known is not None:
            if known[1] != msgtype:
                raise BagError(f"topic {topic} would carry both {known[1]} and {msgtype}")
            return
        conn = self._writer.add_connection(topic, msgtype, typestore=store or self.typestore)
        self._conns[topic] = (conn, msgtype)

    def write(self, topic: str, log_ns: int, msg: Any) -> None:
        """Serialize a rosbags message object (Jazzy types) onto ``topic``."""
        conn, msgtype = self._conns[topic]
        self._writer.write(conn, log_ns, self.typestore.serialize_cdr(msg, msgtype))
        self.count += 1

    def write_cdr(self, topic: str, log_ns: int, data: bytes) -> None:
        """Write already-serialized CDR bytes onto ``topic``."""
        self._writer.write(self._conns[topic][0], log_ns, data)
        self.count += 1

    def write_rows(self, topics: Sequence[str], log_ns: npt.NDArray[np.int64],
                   payloads: Sequence[npt.NDArray[np.uint8]]) -> None:
        """Per row ``k``: ``payloads[j][k]`` (CDR bytes) onto ``topics[j]`` at ``log_ns[k]``.

        The same bag as :meth:`write_cdr` once per message, in that order; MCAP in bulk
        (:mod:`diffdrive_odom.tools.bags.bulkmcap`), sqlite3 one by one.
        """
        conns = [self._conns[t][0] for t in topics]
        if rosbagsinternals.supported(self._writer):
            rosbagsinternals.write_rows(self._writer, conns, log_ns, payloads)
        else:
            for k, stamp in enumerate(log_ns.tolist()):
                for conn, data in zip(conns, payloads, strict=True):
                    self._writer.write(conn, stamp, data[k].tobytes())
        self.count += len(log_ns) * len(topics)
