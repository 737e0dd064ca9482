"""What a recording cut short lacks, written: rosbag2's ``metadata.yaml``, or a whole copy.

For ``diffdrive-odom reindex`` (:mod:`diffdrive_odom.tools.reindex`), from a
:class:`~.recovery.RecoveredReader` opened on the recording: :func:`metadata` is the
``metadata.yaml`` rosbag2 writes when a recording closes (version 9, as Jazzy writes it:
per-file and per-topic counts, times, QoS, type hashes); :func:`copy` writes the
recovered messages into a new bag with its own metadata and (MCAP) summary.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml
from rosbags.rosbag2 import StoragePlugin, Writer

from diffdrive_odom.tools.bags.rosbagsinternals import dump_qos_v9

__all__ = ["copy", "metadata", "yaml_text"]


def metadata(reader: Any, storage_id: str) -> dict[str, Any]:
    """rosbag2's ``metadata.yaml`` (version 9, as Jazzy writes it) of an open reader."""
    def span(start: int, end: int, count: int) -> dict[str, Any]:
        return {"starting_time": {"nanoseconds_since_epoch": start if count else 0},
                "duration": {"nanoseconds": end - 1 - start if count else 0},
                "message_count": count}

    def rihs01(msgtype: str) -> str:
        try:
            return str(reader.typestore.hash_rihs01(msgtype))
        except Exception:  # a type without a definition here: rosbag2 leaves it empty too
            return ""

    counts: dict[tuple[str, str], int] = {}
    first: dict[tuple[str, str], Any] = {}
    for conn in reader.connections:
        key = (conn.topic, conn.msgtype)
        counts[key] = counts.get(key, 0) + conn.msgcount
        first.setdefault(key, conn)
    storages = reader.storages
    total = sum(s.message_count for s in storages)
    whole = span(min(s.start_time for s in storages), max(s.end_time for s in storages), total)
    info = {
        "version": 9,
        "storage_identifier": storage_id,
        "duration": whole["duration"],
        "starting_time": whole["starting_time"],
        "message_count": total,
        "topics_with_message_count": [
            {"topic_metadata": {"name": topic, "type": msgtype,
                                "serialization_format": conn.ext.serialization_format,
                                "offered_qos_profiles": dump_qos_v9(
                                    conn.ext.offered_qos_profiles),
                                "type_description_hash": rihs01(msgtype)},
             "message_count": counts[(topic, msgtype)]}
            for (topic, msgtype), conn in first.items()],
        "compression_format": "",
        "compression_mode": "",
        "relative_file_paths": [s.path.name for s in storages],
        "files": [{"path": s.path.name, **span(s.start_time, s.end_time, s.message_count)}
                  for s in storages],
        "custom_data": None,
        "ros_distro": "jazzy",
    }
    return {"rosbag2_bagfile_information": info}


def yaml_text(data: dict[str, Any]) -> str:
    """YAML as rosbag2's readers (and rosbags) take it, in rosbag2's key order."""
    return yaml.safe_dump(data, default_flow_style=False, sort_keys=False)


def copy(reader: Any, out: Path, storage_id: str) -> int:
    """The recovered messages into a new bag ``out``, reading order; the count."""
    plugin = StoragePlugin.SQLITE3 if storage_id == "sqlite3" else StoragePlugin.MCAP
    count = 0
    with Writer(out, version=9, storage_plugin=plugin) as writer:
        conns = {}
        for conn in reader.connections:
            key = (conn.topic, conn.msgtype)
            if key not in conns:
                conns[key] = writer.add_connection(
                    conn.topic, conn.msgtype, typestore=reader.typestore,
                    serialization_format=conn.ext.serialization_format,
                    offered_qos_profiles=conn.ext.offered_qos_profiles)
        for conn, log_ns, raw in reader.messages():
            writer.write(conns[(conn.topic, conn.msgtype)], log_ns, raw)
            count += 1
    return count
