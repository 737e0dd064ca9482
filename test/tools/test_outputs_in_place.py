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
