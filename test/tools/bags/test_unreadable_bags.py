"""A file that is no bag, or a bag damaged, is one line from every tool: what is wrong, what to do.

Issue 39: a corrupt ``.bag`` gave ``'utf-8' codec can't decode byte 0xff``. Beside it, a
ROS 1 bag damaged part way gave replay's ``cannot write the output: Invalid data stream``
and eval's ``cannot write``, and play and a damaged MCAP a traceback. The bags here are
the real recordings of test/data, damaged as disks and recorders damage them: noise
under a bag's name, a recording cut in half, bytes overwritten mid-file, a metadata.yaml
that does not parse. Where the line says what to do, the test does it and the bag reads.
"""

from __future__ import annotations

import random
import re
import shutil
from collections.abc import Callable
from pathlib import Path

import pytest

from diffdrive_odom.tools.cli import main as cli

from bagutil import OPTIODOM_PARAMS, TB3_PARAMS, write_params
from paths import DATA

RUN04 = DATA / "optiodom" / "square_231220200029_run-04"
TB3 = DATA / "turtlebot3_sim" / "turtlebot3.bag"
GIVE = "give a rosbag2 folder, an .mcap or .db3 file, or a ROS 1 .bag"


def _scramble(path: Path, at: int, n: int, seed: int) -> None:
    """Overwrite ``n`` bytes from ``at`` with noise (a bad sector, a flipped block)."""
    data = bytearray(path.read_bytes())
    rng = random.Random(seed)
    data[at:at + n] = bytes(rng.randrange(256) for _ in range(n))
    path.write_bytes(bytes(data))


def noise_bag(tmp: Path) -> tuple[Path, str]:
    bag = tmp / "noise.bag"
    bag.write_bytes(random.Random(1).randbytes(5000))  # 0xff early: the UTF-8 message
    return bag, (f"{bag}: not a ROS 1 bag (it does not start with '#ROSBAG V2.0'); {GIVE}")


def cut_ros1_bag(tmp: Path) -> tuple[Path, str]:
    bag = tmp / "cut.bag"
    bag.write_bytes(TB3.read_bytes()[:600_000])  # the index is at the end
    return bag, (f"{bag}: a ROS 1 bag whose index does not read (REASON): a recording cut "
                 f"short is made whole by ROS 1's `rosbag reindex {bag}`")


def scrambled_ros1_bag(tmp: Path) -> tuple[Path, str]:
    bag = tmp / "scrambled.bag"
    shutil.copy(TB3, bag)
    _scramble(bag, 400_000, 400, seed=1)  # inside a compressed chunk, a third of the way
    return bag, (f"{bag}: damaged 14.0 s into the recording (REASON): it cannot be read "
                 "past that point: record the run again")


def scrambled_mcap(tmp: Path) -> tuple[Path, str]:
    bag = tmp / "run04"
    shutil.copytree(RUN04, bag)
    (mcap,) = bag.glob("*.mcap")
    _scramble(mcap, mcap.stat().st_size // 2, 300, seed=2)
    return bag, (f"{bag}: damaged (REASON): `diffdrive-odom reindex {mcap}` copies what "
                 "still reads into a new bag")


def bad_metadata(tmp: Path) -> tuple[Path, str]:
    bag = tmp / "run04"
    shutil.copytree(RUN04, bag)
    (bag / "metadata.yaml").write_text("rosbag2_bagfile_information:\n  version: [9\n")
    return bag, (f"{bag}: its metadata.yaml does not read (REASON): move it aside and the "
                 f"storage files are read without it; `diffdrive-odom reindex {bag}` then "
                 "writes a new one")


DAMAGES: dict[str, Callable[[Path], tuple[Path, str]]] = {
    f.__name__: f for f in (noise_bag, cut_ros1_bag, scrambled_ros1_bag, scrambled_mcap,
                            bad_metadata)}


def _is(line: str, expected: str) -> bool:
    """``line`` is ``expected``, whose REASON (rosbags' or a codec's words) may be any text."""
    return re.fullmatch(".+".join(re.escape(p) for p in expected.split("REASON")),
                        line) is not None


def _said(prefix: str, expected: str, capsys: pytest.CaptureFixture[str]) -> None:
    """One line on stderr, and it is ``prefix`` and ``expected``."""
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1, err
    assert "Traceback" not in err and "codec" not in err, err
    assert _is(lines[0], f"{prefix} {expected}"), (lines[0], expected)


@pytest.mark.parametrize("damage", DAMAGES)
def test_replay_eval_and_calibrate_say_in_one_line_what_is_wrong_and_what_to_do(
        damage: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bag, line = DAMAGES[damage](tmp_path)
    # The robot's own joint names: calibrate names a run none of whose readings it can
    # use (the intact TurtleBot3 run read with OptiOdom's joints was one more failure).
    params = write_params(tmp_path / "p.yaml",
                          TB3_PARAMS if bag.suffix == ".bag" else OPTIODOM_PARAMS)
    out = tmp_path / "out"
    out.mkdir()
    assert cli(["replay", str(bag), "--params-file", str(params), "--csv",
                str(out / "o.csv"), "-o", str(out / "bag")]) == 2
    _said("[replay]", line, capsys)
    odom = "/odom" if bag.suffix == ".bag" else "/firmware/odom"  # TB3's, OptiOdom's
    assert cli(["eval", str(bag), "--odom", odom, "--json", str(out / "e.json")]) == 2
    _said("[eval]", line, capsys)
    # beside an intact run of the same robot: TB3 has no ground truth but its /odom
    other, truth = (TB3, ["--ground-truth", "/odom"]) if bag.suffix == ".bag" else (RUN04, [])
    assert cli(["calibrate", str(bag), str(other), "--params-file", str(params), *truth]) == 2
    _said("[calibrate]", line, capsys)
    assert list(out.iterdir()) == []  # nothing half-written


def test_a_damaged_mcap_reads_once_reindex_copied_it_as_the_line_says(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bag, _ = scrambled_mcap(tmp_path)
    (mcap,) = bag.glob("*.mcap")
    params = write_params(tmp_path / "p.yaml", OPTIODOM_PARAMS)
    assert cli(["reindex", str(mcap), "--output", str(tmp_path / "copy")]) == 0
    capsys.readouterr()
    assert cli(["replay", str(tmp_path / "copy"), "--params-file", str(params), "--csv",
                str(tmp_path / "o.csv")]) == 0
    rows = (tmp_path / "o.csv").read_text().splitlines()
    assert 100 < len(rows) - 1 < 1385  # what still read: not all of run 04's readings


def test_a_bag_whose_metadata_does_not_read_reads_once_it_is_moved_aside(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bag, _ = bad_metadata(tmp_path)
    params = write_params(tmp_path / "p.yaml", OPTIODOM_PARAMS)
    (bag / "metadata.yaml").rename(tmp_path / "metadata.yaml.bad")
    assert cli(["replay", str(bag), "--params-file", str(params), "--csv",
                str(tmp_path / "o.csv")]) == 0
    assert len((tmp_path / "o.csv").read_text().splitlines()) == 1 + 1385  # a row a reading
    assert cli(["reindex", str(bag)]) == 0  # and the new metadata.yaml, as the line says
    assert (bag / "metadata.yaml").exists()


def test_reindex_of_a_ros1_bag_points_to_ros1_s_own(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bag, _ = cut_ros1_bag(tmp_path)
    assert cli(["reindex", str(bag)]) == 2
    _said("[reindex]", f"{bag}: a ROS 1 bag; this makes rosbag2 recordings whole, ROS 1's "
          f"`rosbag reindex {bag}` does it for a ROS 1 bag", capsys)


@pytest.mark.dds
def test_play_of_a_bag_damaged_part_way_ends_with_the_line(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bag, line = scrambled_ros1_bag(tmp_path)
    assert cli(["play", str(bag), "--rate", "20"]) == 2
    err = capsys.readouterr().err
    assert _is(err.splitlines()[-1], f"[play] {line}"), err
    assert "Traceback" not in err
