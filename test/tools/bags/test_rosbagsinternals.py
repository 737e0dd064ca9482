"""Each rosbags internal that tools.bags.rosbagsinternals uses, checked by name.

rosbags is pinned to the minor version these pass on (setup.py); an upgrade that moves
or changes one of them fails the test named after it, before a tool misbehaves. The
last test keeps every other module of the package on rosbags' public API.
"""

from __future__ import annotations

import dataclasses
import importlib
import json
import zlib
from io import BytesIO
from pathlib import Path
from typing import Any

import pytest
from mcap.records import Chunk
from mcap.stream_reader import StreamReader
from mcap.writer import CompressionType
from mcap.writer import Writer as McapLibWriter
from rosbags.highlevel import AnyReader
from rosbags.rosbag2 import CompressionMode, Reader, StoragePlugin, Writer
from rosbags.rosbag2.storage_mcap import McapWriter, PendingChunk, write_record, write_string
from rosbags.typesys import Stores, get_typestore

import diffdrive_odom
from diffdrive_odom.tools.bags import recovery, rosbagsinternals

from importscan import imported_names
from paths import DATA, ROOT

RUN04 = DATA / "optiodom" / "square_231220200029_run-04"
TB3 = DATA / "turtlebot3_sim" / "turtlebot3.bag"
STORE = get_typestore(Stores.ROS2_JAZZY)
STRING = "std_msgs/msg/String"


def _cdr(text: str) -> bytes:
    return bytes(STORE.serialize_cdr(STORE.types[STRING](data=text), STRING))


def _open_writer(path: Path) -> tuple[Writer, Any]:
    writer = Writer(path, version=9, storage_plugin=StoragePlugin.MCAP)
    writer.open()
    return writer, writer.add_connection("/chatter", STRING, typestore=STORE)


def test_writer_STORAGE_PLUGINS_storage_counts_and_timestamps(tmp_path: Path) -> None:  # noqa: N802
    """FastWriter swaps the MCAP plugin; write_rows keeps Writer's counts and times."""
    assert Writer.STORAGE_PLUGINS[StoragePlugin.MCAP] is McapWriter
    assert rosbagsinternals.FastWriter.STORAGE_PLUGINS[StoragePlugin.MCAP] is (
        rosbagsinternals.FastMcapWriter)
    writer, conn = _open_writer(tmp_path / "bag")
    assert isinstance(writer.storage, McapWriter)
    assert writer.compression_mode == CompressionMode.NONE
    writer.write(conn, 5_000, _cdr("a"))
    writer.write(conn, 3_000, _cdr("b"))
    assert writer.counts == {conn.id: 2}
    assert (writer.min_timestamp, writer.max_timestamp) == (3_000, 5_000)
    writer.close()


def test_mcap_writer_pending_chunk_and_its_state(tmp_path: Path) -> None:
    """McapWriter's PendingChunk, chunks, compressor, compression, channel_stats, times."""
    assert [f.name for f in dataclasses.fields(PendingChunk)] == [
        "message_start_time", "message_end_time", "bio", "msgs"]
    writer, conn = _open_writer(tmp_path / "bag")
    storage = writer.storage
    before = storage.chunk.bio.tell()  # the schema and channel records
    writer.write(conn, 7_000, _cdr("a"))
    chunk = storage.chunk
    assert isinstance(chunk, PendingChunk)
    assert (chunk.message_start_time, chunk.message_end_time) == (7_000, 7_000)
    assert dict(chunk.msgs) == {conn.id: [(7_000, before)]}
    assert (storage.message_start_time, storage.message_end_time) == (7_000, 7_000)
    assert storage.channel_stats == {conn.id: 1}
    assert storage.compression == "" and storage.compressor(b"xy") == b"xy"
    assert storage.chunks == []
    storage.close_chunk()
    assert len(storage.chunks) == 1 and storage.chunk.bio.tell() == 0
    assert storage.bio.tell() > 0
    writer.close()


def test_chunk_limit_is_where_mcap_writer_closes_a_chunk(tmp_path: Path) -> None:
    """CHUNK_LIMIT: the first record that takes a chunk past it closes the chunk."""
    writer, conn = _open_writer(tmp_path / "bag")
    storage = writer.storage
    data = _cdr("x" * 100_000)
    sizes = []
    while not storage.chunks:
        sizes.append(storage.chunk.bio.tell())
        writer.write(conn, 1_000 + len(sizes), data)
    assert sizes[-1] <= rosbagsinternals.CHUNK_LIMIT
    assert sizes[-1] + 1 + 8 + 2 + 4 + 8 + 8 + len(data) > rosbagsinternals.CHUNK_LIMIT
    writer.close()


def test_write_record_and_write_string_write_mcap_s_layout() -> None:
    """write_record: opcode, uint64 length, body; write_string: uint32 length, UTF-8."""
    out = BytesIO()
    write_string(out, "zstd")
    assert out.getvalue() == b"\x04\x00\x00\x00zstd"
    out, body = BytesIO(), BytesIO()
    body.write(b"xyz")  # its length: where it was written to, as rosbags builds a record
    write_record(out, 0x07, body)
    assert out.getvalue() == b"\x07" + (3).to_bytes(8, "little") + b"xyz"


def test_fast_mcap_writer_close_chunk_is_mcap_writer_s_byte_for_byte(tmp_path: Path) -> None:
    """FastMcapWriter overrides McapWriter.close_chunk: the same file from the same calls."""
    files = []
    for name, cls in (("theirs", Writer), ("ours", rosbagsinternals.FastWriter)):
        (tmp_path / name).mkdir()
        writer = cls(tmp_path / name / "bag", version=9, storage_plugin=StoragePlugin.MCAP)
        writer.open()
        conn = writer.add_connection("/chatter", STRING, typestore=STORE)
        for k in range(3000):
            writer.write(conn, 10**9 + k * 10**6, _cdr(f"message {k} " + "x" * (k % 700)))
        writer.close()
        files.append((tmp_path / name / "bag" / "bag.mcap").read_bytes())
    assert files[0] == files[1]


@pytest.mark.parametrize("compression", [CompressionType.LZ4, CompressionType.ZSTD])
def test_decompressors_open_the_chunks_the_mcap_library_compresses(
        compression: CompressionType) -> None:
    """storage_mcap.DECOMPRESSORS: each chunk comes out whole, its CRC as MCAP wrote it."""
    out = BytesIO()
    writer = McapLibWriter(out, compression=compression, chunk_size=4096)
    writer.start("ros2", "test")
    channel = writer.register_channel("/chatter", "cdr", writer.register_schema(
        STRING, "ros2msg", b"string data"))
    for k in range(500):
        writer.add_message(channel, 10**9 + k, _cdr(f"message {k}"), 10**9 + k)
    writer.finish()
    out.seek(0)
    chunks = [r for r in StreamReader(out, emit_chunks=True).records if isinstance(r, Chunk)]
    assert len(chunks) > 3 and {c.compression for c in chunks} == {compression.name.lower()}
    for chunk in chunks:
        raw = rosbagsinternals.decompress(chunk.compression, chunk.data, chunk.uncompressed_size)
        assert len(raw) == chunk.uncompressed_size
        assert zlib.crc32(raw) == chunk.uncompressed_crc
    assert rosbagsinternals.decompress("", b"abc", 3) == b"abc"
    with pytest.raises(KeyError):
        rosbagsinternals.decompress("bz2", b"abc", 3)


def test_parse_qos_and_dump_qos_v9_read_and_write_rosbag2_s_profiles() -> None:
    """metadata.parse_qos (a list or its YAML text) and dump_qos_v9, as Jazzy writes it."""
    forever = {"sec": 9223372036, "nsec": 854775807}
    jazzy = [{"history": "keep_last", "depth": 10, "reliability": "reliable",
              "durability": "transient_local", "deadline": forever, "lifespan": forever,
              "liveliness": "automatic", "liveliness_lease_duration": forever,
              "avoid_ros_namespace_conventions": False}]
    (qos,) = rosbagsinternals.parse_qos(jazzy)
    assert (qos.depth, qos.reliability.name, qos.durability.name) == (
        10, "RELIABLE", "TRANSIENT_LOCAL")
    assert rosbagsinternals.parse_qos(json.dumps(jazzy)) == [qos]  # YAML text: JSON is YAML
    assert rosbagsinternals.dump_qos_v9([qos]) == jazzy
    assert rosbagsinternals.parse_qos("") == []


def test_is_same_wireformat_and_migrate_bytes_convert_ros1_joint_states() -> None:
    """convert.converter's two: wire formats compared (Header's seq aside), bytes migrated."""
    with AnyReader([TB3]) as reader:
        src = reader.typestore
        (conn,) = [c for c in reader.connections if c.topic == "/joint_states"]
        _, _, raw = next(reader.messages(connections=[conn]))
        ros1 = reader.deserialize(raw, conn.msgtype)
    assert rosbagsinternals.is_same_wireformat(src, STORE, conn.msgtype, conn.msgtype)
    assert not rosbagsinternals.is_same_wireformat(STORE, STORE, "geometry_msgs/msg/Point",
                                                   "geometry_msgs/msg/Quaternion")
    cdr = rosbagsinternals.migrate_bytes(src, STORE, conn.msgtype, conn.msgtype, {}, bytes(raw),
                                         src_is2=False, dst_is2=True)
    msg = STORE.deserialize_cdr(bytes(cdr), conn.msgtype)
    assert list(msg.name) == list(ros1.name) and list(msg.position) == list(ros1.position)
    assert (msg.header.stamp.sec, msg.header.frame_id) == (ros1.header.stamp.sec,
                                                           ros1.header.frame_id)


def test_any_reader_init_sets_exactly_the_attributes_adopt_sets() -> None:
    """AnyReader.__init__'s attributes (ANY_READER_ATTRIBUTES), all set by adopt()."""
    store = get_typestore(Stores.ROS2_JAZZY)
    assert set(vars(AnyReader([RUN04], default_typestore=store))) == set(
        rosbagsinternals.ANY_READER_ATTRIBUTES)
    adopted = AnyReader.__new__(AnyReader)
    rosbagsinternals.adopt(adopted, RUN04, [], store)
    assert set(vars(adopted)) == set(rosbagsinternals.ANY_READER_ATTRIBUTES)
    assert adopted.paths == [RUN04] and adopted.is2 and adopted.default_typestore is store


class _Watched:
    """A rosbags sub-reader whose every attribute AnyReader asks for is noted."""

    def __init__(self, inner: Any, asked: set[str]) -> None:
        self._inner, self._asked = inner, asked

    def __getattr__(self, name: str) -> Any:
        self._asked.add(name)
        value = getattr(self._inner, name)
        if name == "connections":  # AnyReader.messages asks a connection's owner
            return [c._replace(owner=self) for c in value]
        return value

    def __enter__(self) -> _Watched:
        self._asked.add("__enter__")
        self._inner.__enter__()
        return self

    def __exit__(self, *exc: object) -> None:
        self._asked.add("__exit__")
        self._inner.__exit__(*exc)


def test_any_reader_asks_its_sub_readers_only_what_recovery_storage_offers() -> None:
    """AnyReader's sub-reader interface, over which adopt() puts recovery's Storage."""
    asked: set[str] = set()
    reader = AnyReader.__new__(AnyReader)
    rosbagsinternals.adopt(reader, RUN04, [_Watched(Reader(RUN04), asked)], None)
    with reader:
        conns = [c for c in reader.connections if c.topic == "/joint_states"]
        assert sum(1 for _ in reader.messages(connections=conns)) == 1385
        assert sum(1 for _ in reader.messages(start=reader.start_time, stop=reader.end_time))
        assert reader.message_count > 0 and reader.duration > 0 and reader.topics
    assert {"connections", "messages", "__enter__"} <= asked
    with recovery.open_storage(next(RUN04.glob("*.mcap"))) as storage:
        lacking = sorted(name for name in asked if not hasattr(storage, name))
    assert not lacking, f"AnyReader now asks its sub-readers for {lacking}"


PUBLIC = {"rosbags.typesys.store": {"Typestore"}}  # the type of get_typestore's result


def _public(module: str) -> set[str] | None:
    """Names rosbags exports from ``module`` (its ``__all__``); None: not a public module."""
    if module in PUBLIC:
        return PUBLIC[module]
    if module not in ("rosbags.highlevel", "rosbags.rosbag2", "rosbags.typesys",
                      "rosbags.interfaces"):
        return None
    mod = importlib.import_module(module)
    exported = getattr(mod, "__all__", None)
    return set(exported) if exported is not None else {
        n for n in dir(mod) if not n.startswith("_")}


def test_no_other_module_imports_rosbags_beyond_its_public_api() -> None:
    package = Path(diffdrive_odom.__file__).parent
    internal: dict[str, list[str]] = {}
    for path in sorted(package.rglob("*.py")):
        if path.name == "rosbagsinternals.py":
            continue
        modules, members = imported_names(path, for_typing=True)
        bad = [m for m in modules if m.startswith("rosbags.") and _public(m) is None]
        for member in members:  # from a public module: its exported names only
            module, _, name = member.rpartition(".")
            public = _public(module) if module.startswith("rosbags") else None
            if public is not None and name not in public:
                bad.append(member)
        if bad:
            internal[str(path.relative_to(ROOT))] = sorted(bad)
    assert not internal, f"rosbags internals outside rosbagsinternals.py: {internal}"
    assert _public("rosbags.rosbag2.storage_mcap") is None  # the check can fail
