"""``diffdrive-odom reindex BAG``: make a recording cut short whole again, on request.

Why: every tool here reads such a recording as it is (:mod:`.bags.recovery`), but other
tools (rosbags, ``ros2 bag``, the mcap CLI) need the ``metadata.yaml`` rosbag2 writes
at the end of a recording and an MCAP file's summary and footer. This writes what is
missing, never over what exists:

- a folder whose storage files are whole and only ``metadata.yaml`` is missing gets
  one, rosbag2's version 9 as Jazzy writes it (per-file and per-topic counts, times,
  QoS, type hashes);
- anything torn or damaged, or a single storage file, gets a complete copy in a new
  folder beside it (``NAME.recovered``): the recovered messages in reading order, in
  the same storage format, with its own ``metadata.yaml`` and (MCAP) summary.

What is written is :mod:`diffdrive_odom.tools.bags.reindexing`'s; this is the command line.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

from diffdrive_odom.tools.cli import command_parser


def _parser() -> argparse.ArgumentParser:
    p = command_parser("reindex", "Write a cut-short recording's missing metadata.yaml, or "
                       "a complete copy of a torn or damaged one in a new folder beside it.")
    p.add_argument("bag", help="bag folder without metadata.yaml, or a .mcap / .db3 file")
    p.add_argument("--output", default=None,
                   help="folder for the copy (default: BAG.recovered beside BAG)")
    return p


def main(argv: Sequence[str] | None = None) -> int:
    """Reindex one recording; 2 (and one line) when it is not a recording."""
    args = _parser().parse_args(list(sys.argv[1:] if argv is None else argv))
    bag = Path(args.bag)
    if bag.is_dir() and (bag / "metadata.yaml").exists():
        print(f"[reindex] {bag}: has its metadata.yaml already; nothing to do")
        return 0
    if bag.suffix == ".bag":
        print(f"[reindex] {bag}: a ROS 1 bag; this makes rosbag2 recordings whole, ROS 1's "
              f"`rosbag reindex {bag}` does it for a ROS 1 bag", file=sys.stderr)
        return 2
    from diffdrive_odom.tools.bags import bagio, recovery  # past the parsing: no rosbags
    from diffdrive_odom.tools.bags.reindexing import copy, metadata, yaml_text

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
