"""``diffdrive-odom reindex BAG``: make a recording cut short whole again, on request.

Why: every tool here reads such a recording as it is (:mod:`.recovery`), but other
tools (rosbags, ``ros2 bag``, the mcap CLI) need the ``metadata.yaml`` rosbag2 writes
at the end of a recording and an MCAP file's summary and footer. This writes what is
missing, never over what exists:

- a folder whose storage files are whole and only ``metadata.yaml`` is missing gets
  one, rosbag2's version 9 as Jazzy writes it (per-file and per-topic counts, times,
  QoS, type hashes);
- anything torn or damaged, or a single storage file, gets a complete copy in a new
  folder beside it (``NAME.recovered``): the recovered messages in reading order, in
  the same storage format, with its own ``metadata.yaml`` and (MCAP) summary.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from io import StringIO
from pathlib import Path
from typing import Any

from diffdrive_odom.tools.cli import HelpFormatter


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="diffdrive-odom reindex", formatter_class=HelpFormatter,
        description="Write a cut-short recording's missing metadata.yaml, or a complete "
                    "copy of a torn or damaged one in a new folder beside it.")
    p.add_argument("bag", help="bag folder without metadata.yaml, or a .mcap / .db3 file")
    p.add_argument("--output", default=None,
                   help="folder for the copy (default: BAG.recovered beside BAG)")
    return p


def metadata(reader: Any, storage_id: str) -> dict[str, Any]:
    """rosbag2's ``metadata.yaml`` (version 9, as Jazzy writes it) of an open reader."""
    from rosbags.rosbag2.metadata import dump_qos_v9

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
    storages = reader.readers
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
    """YAML as rosbag2's readers (and rosbags) take it."""
    from ruamel.yaml import YAML

    yaml = YAML(typ="safe")
    yaml.default_flow_style = False
    out = StringIO()
    yaml.dump(data, out)
    return out.getvalue()


def copy(reader: Any, out: Path, storage_id: str) -> int:
    """The recovered messages into a new bag ``out``, reading order; the count."""
    from rosbags.rosbag2 import StoragePlugin, Writer

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


def main(argv: Sequence[str] | None = None) -> int:
    """Reindex one recording; 2 (and one line) when it is not a recording."""
    args = _parser().parse_args(list(sys.argv[1:] if argv is None else argv))
    bag = Path(args.bag)
    if bag.is_dir() and (bag / "metadata.yaml").exists():
        print(f"[reindex] {bag}: has its metadata.yaml already; nothing to do")
        return 0
    from diffdrive_odom.tools.bags import bagio, recovery

    try:
        reader = recovery.RecoveredReader(bag, default_typestore=bagio.typestore(),
                                          report=sys.stdout)
        reader.open()
    except (recovery.RecoveryError, OSError, ValueError, KeyError) as err:
        print(f"[reindex] {bag}: not a readable bag ({err})", file=sys.stderr)
        return 2
    try:
        kinds = {"sqlite3" if isinstance(s, recovery.SqliteStorage) else "mcap"
                 for s in reader.storages}
        storage_id = "sqlite3" if kinds == {"sqlite3"} else "mcap"
        if bag.is_dir() and reader.whole and len(kinds) == 1:
            target = bag / "metadata.yaml"
            target.write_text(yaml_text(metadata(reader, storage_id)), "utf8")
            print(f"[reindex] wrote {target}")
            return 0
        name = (bag.name if bag.is_dir() else bag.stem) + ".recovered"
        out = Path(args.output) if args.output else bag.with_name(name)
        if out.exists():
            print(f"[reindex] {out} exists: remove it or name another --output",
                  file=sys.stderr)
            return 2
        n = copy(reader, out, storage_id)
        print(f"[reindex] wrote {out}: {n} messages, complete ({storage_id})")
        return 0
    finally:
        reader.close()
