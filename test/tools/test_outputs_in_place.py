"""An output that is a device or a pipe is written where it is, never renamed over.

``--csv /dev/null`` (a user who wants the summary and not the poses; this suite's IMU
advice test) went through the staging rename: run as root it replaced the machine's
/dev/null with a regular file, which then filled up (``yes > /dev/null``: "No space
left on device"), and as a user it was refused (/dev is not writable). Checked on a
FIFO of the test's own: the CSV read from it is the one written to a regular file.
"""

from __future__ import annotations

import os
import stat
import threading
from pathlib import Path

from diffdrive_odom.tools.cli import main as cli
from diffdrive_odom.tools.cmdline.outputs import output_problem, staged

from bagutil import OPTIODOM_PARAMS, write_params
from rosutil import DATA

BAG = DATA / "optiodom" / "square_231220200029_run-01"


def test_replay_writes_its_csv_into_a_fifo_and_leaves_the_fifo_a_fifo(tmp_path: Path) -> None:
    params = write_params(tmp_path / "p.yaml", OPTIODOM_PARAMS)
    fifo = tmp_path / "poses.fifo"
    os.mkfifo(fifo)
    got: list[bytes] = []
    reader = threading.Thread(target=lambda: got.append(fifo.read_bytes()), daemon=True)
    reader.start()
    assert cli(["replay", str(BAG), "--params-file", str(params), "--csv", str(fifo)]) == 0
    reader.join(timeout=30)
    assert stat.S_ISFIFO(fifo.stat().st_mode)
    assert not [p for p in tmp_path.iterdir() if ".partial-" in p.name]
    regular = tmp_path / "poses.csv"
    assert cli(["replay", str(BAG), "--params-file", str(params), "--csv", str(regular)]) == 0
    assert got == [regular.read_bytes()] and len(got[0].splitlines()) > 100


def test_dev_null_is_a_writable_output_and_stays_a_device() -> None:
    null = Path(os.devnull)
    assert output_problem(null, "--csv") is None
    with staged(null) as path:
        assert path == null
        path.write_text("x\n", encoding="utf-8")
    assert stat.S_ISCHR(null.stat().st_mode)


def test_a_regular_file_is_still_staged(tmp_path: Path) -> None:
    final = tmp_path / "out.csv"
    final.write_text("old\n", encoding="utf-8")
    with staged(final) as path:
        assert path != final and path.name == final.name
        path.write_text("new\n", encoding="utf-8")
        assert final.read_text(encoding="utf-8") == "old\n"
    assert final.read_text(encoding="utf-8") == "new\n"


def test_an_output_through_a_symlink_is_written_to_its_target_and_the_link_stays(
        tmp_path: Path) -> None:
    """``--csv latest.csv`` where latest.csv links to the run's file (or to a file not yet
    there): the target is written, staged beside it, and the link stays a link, as a
    shell's ``>`` would leave it. Before, the staged file was renamed over the link."""
    params = write_params(tmp_path / "p.yaml", OPTIODOM_PARAMS)
    runs = tmp_path / "runs"
    runs.mkdir()
    regular = tmp_path / "poses.csv"
    assert cli(["replay", str(BAG), "--params-file", str(params), "--csv", str(regular)]) == 0
    for existing in (True, False):
        target = runs / f"poses-{existing}.csv"
        if existing:
            target.write_text("old\n", encoding="utf-8")
        link = tmp_path / f"latest-{existing}.csv"
        link.symlink_to(target)
        assert output_problem(link, "--csv") is None
        assert cli(["replay", str(BAG), "--params-file", str(params), "--csv", str(link)]) == 0
        assert link.is_symlink() and link.readlink() == target
        assert target.read_bytes() == regular.read_bytes()
        assert not [p for d in (tmp_path, runs) for p in d.iterdir() if ".partial-" in p.name]


def test_a_symlink_into_a_missing_directory_is_refused_naming_it(tmp_path: Path) -> None:
    """The target's directory is the one written (its staging and rename happen there)."""
    link = tmp_path / "latest.csv"
    link.symlink_to(tmp_path / "runs" / "missing" / "poses.csv")
    problem = output_problem(link, "--csv")
    assert problem is not None and problem.startswith(f"--csv {link}: directory ")
    assert str(tmp_path / "runs" / "missing") in problem
