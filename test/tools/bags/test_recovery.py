"""Recordings cut short (issue 27): real files written here, cut, then read back.

The oracle is what each test's own writer logged (log time, payload bytes), where each
payload's record ends in the file (found by searching the intact file for its bytes)
and, for compressed chunks, where the chunk ends (the mcap library's own summary of the
intact file): never the code under test.
"""

from __future__ import annotations

import hashlib
import io
import os
import shutil
import sqlite3
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap.writer import CompressionType
from mcap.writer import Writer as McapLibWriter
from rosbags.highlevel import AnyReader
from rosbags.rosbag2 import StoragePlugin, Writer

from diffdrive_odom.tools.bags import bagio, bagreadings, recovery
from diffdrive_odom.tools.cli import main as cli
from diffdrive_odom.tools.cmdline.args import load_settings
from diffdrive_odom.tools.replaying.readings import replay_readings

from bagutil import write_params

JS = bagio.JOINT_STATE
T0 = 1_700_000_000 * 10**9
NAMES = ["left_wheel_joint", "right_wheel_joint"]


def _payload(k: int, stamp: int, left: float, right: float) -> bytes:
    t = bagio.typestore().types
    msg = t[JS](header=t["std_msgs/msg/Header"](
        stamp=t["builtin_interfaces/msg/Time"](sec=stamp // 10**9, nanosec=stamp % 10**9),
        frame_id=f"f{k}"), name=NAMES, position=np.array([left, right]),
        velocity=np.zeros(0), effort=np.zeros(0))
    return bytes(bagio.typestore().serialize_cdr(msg, JS))


def _run(n: int, dt: int = 10_000_000, start: int = T0) -> list[tuple[int, bytes]]:
    """n readings of a robot turning gently: (log time, CDR bytes), all distinct."""
    return [(start + k * dt, _payload(k, start + k * dt, 0.05 * k, 0.06 * k))
            for k in range(n)]


def _rosbags_bag(path: Path, msgs: list[tuple[int, bytes]], storage: str = "mcap") -> None:
    plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
    with Writer(path, version=9, storage_plugin=plugin) as w:
        conn = w.add_connection("/joint_states", JS, typestore=bagio.typestore())
        for log, raw in msgs:
            w.write(conn, log, raw)


def _mcap_lib_file(msgs: list[tuple[int, bytes]], chunked: bool,
                   compression: CompressionType, chunk_size: int = 700) -> bytes:
    """An MCAP file written by the mcap library (ros2msg schema), as bytes."""
    out = io.BytesIO()
    w = McapLibWriter(out, chunk_size=chunk_size, compression=compression,
                      use_chunking=chunked)
    w.start(profile="ros2", library="test")
    text = bagio.typestore().generate_msgdef(JS, ros_version=2)[0]
    sid = w.register_schema(JS, "ros2msg", text.encode())
    cid = w.register_channel("/joint_states", "cdr", sid)
    for log, raw in msgs:
        w.add_message(cid, log, raw, log)
    w.finish()
    return out.getvalue()


def _ends(data: bytes, msgs: list[tuple[int, bytes]], compressed: bool) -> list[int]:
    """Per message, the byte a cut must be at or past to leave it whole.

    Where its record ends (its payload found in the intact file), or for a compressed
    chunk where the chunk ends (the mcap library's summary of the intact file).
    """
    if compressed:
        summary = make_reader(io.BytesIO(data)).get_summary()
        assert summary is not None
        chunks = [(c.message_start_time, c.message_end_time,
                   c.chunk_start_offset + c.chunk_length) for c in summary.chunk_indexes]
        return [next(e for s, t, e in chunks if s <= log <= t) for log, _ in msgs]
    ends = []
    for _, raw in msgs:
        at = data.find(raw)
        assert at > 0 and data.find(raw, at + 1) < 0, "payloads are unique"
        ends.append(at + len(raw))
    return ends


def _expected(data: bytes, msgs: list[tuple[int, bytes]], cut: int,
              compressed: bool, ends: list[int] | None = None) -> list[tuple[int, bytes]]:
    """What a cut at ``cut`` leaves whole, by the writer's log and the file's layout."""
    ends = _ends(data, msgs, compressed) if ends is None else ends
    return [m for m, end in zip(msgs, ends, strict=True) if end <= cut]


def _storage_read(path: Path) -> list[tuple[int, bytes]]:
    with recovery.McapStorage(path) as s:
        return [(log, bytes(raw)) for _, log, raw in s.messages()]


@pytest.mark.parametrize(("chunked", "compression"), [
    (False, CompressionType.NONE), (True, CompressionType.NONE),
    (True, CompressionType.ZSTD), (True, CompressionType.LZ4)])
def test_an_mcap_cut_at_every_byte_gives_the_whole_records_before_the_cut(
        tmp_path: Path, chunked: bool, compression: CompressionType) -> None:
    msgs = _run(14)
    data = _mcap_lib_file(msgs, chunked, compression, chunk_size=500)
    compressed = chunked and compression != CompressionType.NONE
    f = tmp_path / "cut.mcap"
    f.write_bytes(data)
    seen = set()
    ends = _ends(data, msgs, compressed)
    first = max(8, data.find(msgs[0][1]) - 60)  # every byte from the first message on
    for cut in reversed([*range(8, first, 11), *range(first, len(data) + 1)]):
        os.truncate(f, cut)
        got = _storage_read(f)
        assert got == _expected(data, msgs, cut, compressed, ends), cut
        seen.add(len(got))
    assert seen == set(range(len(msgs) + 1)) if not compressed else len(seen) > 2


def test_a_rosbags_mcap_cut_at_record_boundaries_and_inside_them(tmp_path: Path) -> None:
    msgs = _run(300)
    _rosbags_bag(tmp_path / "bag", msgs)
    data = next((tmp_path / "bag").glob("*.mcap")).read_bytes()
    ends = [data.find(raw) + len(raw) for _, raw in msgs]
    cuts = sorted({c + d for c in ends for d in (-1, 0, 1)} | set(range(8, len(data), 97)))
    f = tmp_path / "cut.mcap"
    for cut in cuts:
        f.write_bytes(data[:cut])
        assert _storage_read(f) == [m for m, e in zip(msgs, ends, strict=True) if e <= cut], cut


def test_a_torn_mcap_replays_to_the_bit_as_the_intact_bag_of_its_readings(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    msgs = _run(2000)
    _rosbags_bag(tmp_path / "full", msgs)
    data = next((tmp_path / "full").glob("*.mcap")).read_bytes()
    cut = int(len(data) * 0.6)
    torn = tmp_path / "torn"
    torn.mkdir()
    (torn / "torn_0.mcap").write_bytes(data[:cut])
    kept = _expected(data, msgs, cut, False)
    assert 0 < len(kept) < len(msgs)
    _rosbags_bag(tmp_path / "intact", kept)  # the same readings, complete
    settings = load_settings(write_params(tmp_path / "p.yaml", {
        "wheel_radius": 0.042, "wheel_separation": 0.2}))

    def poses(bag: Path) -> list[Any]:
        out: list[Any] = []
        replay_readings(bagreadings.read_joint_states(bag), settings, out.append)
        return out

    before = sorted(p.name for p in torn.iterdir())
    got, want = poses(torn), poses(tmp_path / "intact")
    assert len(got) == len(want) > 0 and got == want
    assert sorted(p.name for p in torn.iterdir()) == before  # nothing written there
    _rosbags_bag(tmp_path / "indexed", msgs)  # metadata.yaml there, the MCAP torn
    (mcap,) = (tmp_path / "indexed").glob("*.mcap")
    mcap.write_bytes(data[:cut])
    assert poses(tmp_path / "indexed") == want
    line = capsys.readouterr().err.strip().splitlines()
    assert len(line) == 2 and "no metadata.yaml" not in line[1] and "torn" in line[1]
    assert "no metadata.yaml" in line[0] and f"torn at byte {cut}" in line[0]
    last = kept[-1][0]
    assert f"/joint_states {len(kept)}" in line[0]
    assert f"{last // 10**9}.{last % 10**9:09d}" in line[0]


def test_a_split_folder_without_metadata_reads_in_log_time_then_file_order(
        tmp_path: Path) -> None:
    """``_2`` before ``_10``; equal log times in several files come in file order."""
    bag = tmp_path / "run"
    bag.mkdir()
    logs = [T0 + k * 10**7 for k in range(5)]
    written = {}
    for part in (10, 0, 2):
        msgs = [(log, _payload(part * 100 + k, log, part, k)) for k, log in enumerate(logs)]
        _rosbags_bag(tmp_path / f"p{part}", msgs)
        shutil.move(next((tmp_path / f"p{part}").glob("*.mcap")), bag / f"run_{part}.mcap")
        written[part] = msgs
    want = [m for log in logs for part in (0, 2, 10) for m in written[part] if m[0] == log]
    with bagio.open_bag(bag) as r:
        got = [(log, bytes(raw)) for _, log, raw in r.messages()]
    assert got == want


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_metadata_removed_gives_the_intact_readings_and_reindex_restores_it(
        tmp_path: Path, storage: str, capsys: pytest.CaptureFixture[str]) -> None:
    msgs = _run(500)
    bag = tmp_path / "bag"
    _rosbags_bag(bag, msgs, storage)
    with AnyReader([bag]) as r:
        intact = [(log, bytes(raw)) for _, log, raw in r.messages()]
    original = (bag / "metadata.yaml").read_text()
    (bag / "metadata.yaml").unlink()
    files = {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in bag.iterdir()}
    with bagio.open_bag(bag) as r:
        got = [(log, bytes(raw)) for _, log, raw in r.messages()]
    assert got == intact == msgs
    # read-only and immutable: no -shm, -wal or journal, not a byte changed
    assert {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in bag.iterdir()} == files
    assert cli(["reindex", str(bag)]) == 0
    with AnyReader([bag]) as r:  # rosbags, through the new metadata.yaml
        assert [(log, bytes(raw)) for _, log, raw in r.messages()] == msgs
        assert r.message_count == len(msgs)
    import yaml

    ours = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    theirs = yaml.safe_load(original)["rosbag2_bagfile_information"]
    assert ours["version"] == 9 and ours["ros_distro"] == "jazzy"
    for key in ("storage_identifier", "relative_file_paths", "duration", "starting_time",
                "message_count", "topics_with_message_count", "files"):
        assert ours[key] == theirs[key], key
    capsys.readouterr()


def test_reindex_of_a_torn_mcap_writes_a_complete_copy_beside_it(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    msgs = _run(400)
    data = _mcap_lib_file(msgs, True, CompressionType.ZSTD, chunk_size=4000)
    cut = len(data) * 2 // 3
    folder = tmp_path / "rec"
    folder.mkdir()
    (folder / "rec_0.mcap").write_bytes(data[:cut])
    kept = _expected(data, msgs, cut, True)
    assert cli(["reindex", str(folder)]) == 0
    assert sorted(p.name for p in folder.iterdir()) == ["rec_0.mcap"]
    copy = tmp_path / "rec.recovered"
    with AnyReader([copy]) as r:
        assert [(log, bytes(raw)) for _, log, raw in r.messages()] == kept
    (mcap,) = copy.glob("*.mcap")
    with mcap.open("rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None and summary.statistics is not None
    assert summary.statistics.message_count == len(kept)
    assert [c.topic for c in summary.channels.values()] == ["/joint_states"]
    assert cli(["reindex", str(folder)]) == 2  # the copy exists: not overwritten
    out = capsys.readouterr()
    assert "exists" in out.err


def _sqlite_bag(tmp_path: Path, n: int) -> tuple[Path, list[tuple[int, bytes]]]:
    msgs = _run(n)
    _rosbags_bag(tmp_path / "src", msgs, "sqlite3")
    return next((tmp_path / "src").glob("*.db3")), msgs


def _read_all(path: Path) -> list[tuple[int, bytes]]:
    with bagio.open_bag(path) as r:
        return [(log, bytes(raw)) for _, log, raw in r.messages()]


def _commit_to_wal(db: Path, more: list[tuple[int, bytes]]
                   ) -> tuple[sqlite3.Connection, list[tuple[int, bytes]]]:
    """One more transaction committed in WAL mode, not checkpointed (still open)."""
    con = sqlite3.connect(db)
    con.execute("PRAGMA journal_mode=WAL")
    con.execute("PRAGMA wal_autocheckpoint=0")
    with con:
        con.executemany("INSERT INTO messages (topic_id, timestamp, data) VALUES (1, ?, ?)",
                        more)
    return con, more


@pytest.mark.parametrize("wal_left", [False, True])
def test_sqlite_killed_in_wal_mode_gives_every_transaction_its_files_hold(
        tmp_path: Path, wal_left: bool, capsys: pytest.CaptureFixture[str]) -> None:
    """The last transaction committed to ``-wal``: lost with that file, read with it."""
    db, msgs = _sqlite_bag(tmp_path, 200)
    con, more = _commit_to_wal(db, _run(50, start=msgs[-1][0] + 10**7))
    folder = tmp_path / "killed"
    folder.mkdir()
    for suffix in ("", "-wal") if wal_left else ("",):  # as the killed recorder left them
        shutil.copy(f"{db}{suffix}", folder / f"killed_0.db3{suffix}")
    con.close()
    before = {p.name: p.read_bytes() for p in folder.iterdir()}
    assert _read_all(folder) == msgs + (more if wal_left else [])
    assert {p.name: p.read_bytes() for p in folder.iterdir()} == before  # nothing written
    assert capsys.readouterr().err.count("\n") == 1


@pytest.mark.parametrize("damage", ["truncate_page", "truncate_mid", "garbage_page"])
def test_a_torn_sqlite_gives_what_still_reads_each_message_whole(
        tmp_path: Path, damage: str, capsys: pytest.CaptureFixture[str]) -> None:
    db, msgs = _sqlite_bag(tmp_path, 3000)
    data = bytearray(db.read_bytes())
    page = int.from_bytes(data[16:18], "big")
    pages = len(data) // page
    torn = tmp_path / "torn.db3"
    if damage == "truncate_page":
        torn.write_bytes(data[:page * (pages * 2 // 3)])
    elif damage == "truncate_mid":
        torn.write_bytes(data[:page * (pages // 2) + page // 3])
    else:
        k = pages // 2
        data[k * page:(k + 1) * page] = bytes(range(256)) * (page // 256)
        torn.write_bytes(bytes(data))
    got = _read_all(torn)
    logged = dict(msgs)
    assert 0 < len(got) < len(msgs)
    assert all(logged.get(log) == raw for log, raw in got)  # each one whole, as written
    assert [log for log, _ in got] == sorted({log for log, _ in got})  # in order, once
    line = capsys.readouterr().err.strip().splitlines()
    assert len(line) == 1 and "damaged" in line[0]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["src", "torn.db3"]
    assert cli(["reindex", str(torn)]) == 0  # a complete copy, beside
    with AnyReader([tmp_path / "torn.recovered"]) as r:
        assert [(log, bytes(raw)) for _, log, raw in r.messages()] == got


@pytest.mark.parametrize("what", ["text.mcap", "text.db3", "empty_dir", "notes.txt"])
def test_what_is_not_a_recording_is_one_line_and_exit_2(
        tmp_path: Path, what: str, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / what
    if what == "empty_dir":
        path.mkdir()
        (path / "README").write_text("hello\n")
    else:
        path.write_text("this is not a recording\n" * 50)
    params = write_params(tmp_path / "p.yaml", {"wheel_radius": 0.042,
                                                 "wheel_separation": 0.2})
    assert cli(["replay", str(path), "--params-file", str(params),
                "--csv", str(tmp_path / "o.csv")]) == 2
    assert cli(["reindex", str(path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 2 and all(str(path) in e for e in err), err
    assert not (tmp_path / "o.csv").exists()


def test_a_fleet_replay_of_recordings_cut_short_writes_the_intact_bags_csv(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """``replay`` with several bags (a fleet, one process): torn MCAP, sqlite3 without
    metadata; each CSV the very text of the intact bag of the same readings."""
    msgs = _run(1500)
    _rosbags_bag(tmp_path / "full", msgs)
    data = next((tmp_path / "full").glob("*.mcap")).read_bytes()
    cut = len(data) // 2 + 17
    kept = _expected(data, msgs, cut, False)
    broken, whole = tmp_path / "broken", tmp_path / "whole"
    (broken / "a").mkdir(parents=True)
    (broken / "a" / "a_0.mcap").write_bytes(data[:cut])
    _rosbags_bag(broken / "b", msgs, "sqlite3")
    (broken / "b" / "metadata.yaml").unlink()
    _rosbags_bag(whole / "a", kept)
    _rosbags_bag(whole / "b", msgs, "sqlite3")
    params = write_params(tmp_path / "p.yaml", {"wheel_radius": 0.042, "wheel_separation": 0.2})
    for top in (broken, whole):
        assert cli(["replay", str(top / "a"), str(top / "b"), "--params-file", str(params),
                    "--csv", str(top / "csv"), "--jobs", "1"]) == 0
    for name in ("a.csv", "b.csv"):
        got = (broken / "csv" / name).read_text()
        assert got == (whole / "csv" / name).read_text() and got.count("\n") > 100
    out = capsys.readouterr()
    assert out.out.count("[recovery]") + out.err.count("[recovery]") == 2


def test_a_real_run_torn_at_60_percent_replays_and_evaluates_as_its_intact_readings(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The issue's case: an OptiOdom run (JointStates, mocap, firmware odometry) cut at
    60 % of its bytes, no metadata.yaml; ``replay --eval`` and ``eval`` give the very
    figures of an intact bag of the messages whose records end before the cut."""
    from rosutil import DATA

    src = DATA / "optiodom" / "square_231220200029_run-01"
    (mcap,) = src.glob("*.mcap")
    data = mcap.read_bytes()
    cut = int(len(data) * 0.6)
    kept, at = [], 0
    with mcap.open("rb") as f:
        reader = make_reader(f)
        for schema, channel, message in reader.iter_messages(log_time_order=False):
            at = data.index(message.data, at) + len(message.data)  # file order
            if at <= cut:
                assert schema is not None
                kept.append((channel.topic, schema.name, message.log_time, message.data))
    torn = tmp_path / "torn"
    torn.mkdir()
    (torn / mcap.name).write_bytes(data[:cut])
    whole = tmp_path / "whole"
    with Writer(whole, version=9, storage_plugin=StoragePlugin.MCAP) as w:
        conns: dict[str, Any] = {}
        for topic, msgtype, log, raw in kept:
            if topic not in conns:
                conns[topic] = w.add_connection(topic, msgtype, typestore=bagio.typestore())
            w.write(conns[topic], log, raw)
    joints = sum(1 for k in kept if k[0] == "/joint_states")
    assert 0 < joints < 1388
    params = write_params(tmp_path / "p.yaml", {"wheel_radius": 0.042, "wheel_separation": 0.2})
    figures = {}
    for bag in (torn, whole):
        assert cli(["replay", str(bag), "--params-file", str(params), "--eval",
                    "--json", str(tmp_path / f"{bag.name}_replay.json")]) == 0
        assert cli(["eval", str(bag), "--odom", "/firmware/odom",
                    "--json", str(tmp_path / f"{bag.name}_eval.json")]) == 0
        figures[bag.name] = [(tmp_path / f"{bag.name}_{k}.json").read_text()
                             for k in ("replay", "eval")]
    assert figures["torn"] == figures["whole"]
    err = capsys.readouterr().err
    assert f"/joint_states {joints}" in err and "torn at byte" in err
    # One line per command (replay --eval opens the bag three times, eval twice).
    assert err.count("[recovery]") == 2, err
