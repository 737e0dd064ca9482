"""Any bag's messages -> ROS 2 CDR with Jazzy type names, where they leave the bag.

Why: ``replay --keep-input`` copies the input bag's messages into the output bag, and
``play`` publishes them; both must hand over ROS 2 CDR whatever the input was. ROS 1
messages are converted where they leave the bag: same field names, minus
``Header.seq``.
"""

from __future__ import annotations

import functools
from collections.abc import Callable

from rosbags.highlevel import AnyReader
from rosbags.interfaces import Connection
from rosbags.typesys import Stores, get_typestore

from diffdrive_odom.tools.bags.rosbagsinternals import is_same_wireformat, migrate_bytes


class CdrConverter:
    """Raw bytes of any connection of a bag -> ROS 2 CDR with a Jazzy type name.

    rosbag2 data passes through untouched. ROS 1 data is re-encoded; types whose
    fields differ from Jazzy's (only ``Header.seq`` for the common messages) are
    migrated field by field, as ``rosbags-convert`` does. Types Jazzy lacks are
    registered from the bag's own definitions.
    """

    def __init__(self, reader: AnyReader) -> None:
        self._reader = reader
        self.typestore = get_typestore(Stores.ROS2_JAZZY)  # its own: types get added
        self._funcs: dict[str, Callable[[bytes], bytes]] = {}
        self._cache: dict[str, object] = {}

    def __call__(self, conn: Connection, raw: bytes) -> bytes:
        """CDR bytes of one message of ``conn``."""
        func = self._funcs.get(conn.msgtype)
        if func is None:
            func = self._funcs[conn.msgtype] = self._make(conn.msgtype)
        return func(raw)

    def _make(self, msgtype: str) -> Callable[[bytes], bytes]:
        src = self._reader.typestore
        if self._reader.is2:
            if msgtype not in self.typestore.fielddefs:
                self.typestore.register({msgtype: src.fielddefs[msgtype]})
            return bytes
        if msgtype not in self.typestore.fielddefs:
            missing = {
                k: v
                for k, v in src.fielddefs.items()
                if k not in self.typestore.fielddefs and k != "std_msgs/msg/Header"
            }
            self.typestore.register(missing)
        if is_same_wireformat(src, self.typestore, msgtype, msgtype):
            to_cdr = functools.partial(self.typestore.ros1_to_cdr, typename=msgtype)
            return lambda raw: bytes(to_cdr(raw))
        migrate = functools.partial(
            migrate_bytes, src, self.typestore, msgtype, msgtype, self._cache,
            src_is2=False, dst_is2=True,
        )
        return lambda raw: bytes(migrate(raw))
