"""Ctrl-C in the terminal of ``ros2 launch``: every node ends cleanly (exit 0).

A terminal sends SIGINT to the whole foreground process group: ``ros2 launch`` and each
node get it, then launch sends each node its own SIGINT. A user who presses Ctrl-C twice
adds a third. Each signal after the first used to raise into the node's teardown or hit
the default action Python restores at its exit: ``process has died [... exit code -2]``.
Here the real ``ros2 launch`` runs base.launch.py (odometry, cmd_vel, sim and follower
nodes) from the colcon install in a session of its own, the test sends SIGINT to its
process group as the terminal does, and launch's own log says how each process ended.
"""

from __future__ import annotations

import os
import re
import signal
import subprocess
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from rosutil import BIN

PACKAGE = "diffdrive_odom"
NODES = {"odometry_node", "cmd_vel_node", "sim_node", "path_follower_node"}
FINISHED = re.compile(r"\[INFO\] \[(\w+)-\d+\]: process has finished cleanly \[pid \d+\]")
DIED = re.compile(r"\[ERROR\] \[(\w+)-\d+\]: process has died \[pid \d+, exit code (-?\d+)")

pytestmark = [pytest.mark.xdist_group("colcon"), pytest.mark.dds, pytest.mark.process,
              pytest.mark.launch]


@pytest.fixture
def ros2_env(colcon_ws: Path, tmp_path: Path) -> Iterator[dict[str, str]]:
    """A sourced install's environment for the real ``ros2`` command."""
    if not (BIN / "ros2").exists():
        pytest.skip("the ros2 command is missing (not on PyPI): on a robot it comes with "
                    "ROS 2 from apt; here run `bash ../shared/launch/install.sh .venv`")
    install = colcon_ws / "install" / PACKAGE
    site = next((install / "lib").glob("python3*/site-packages"))
    yield {**os.environ, "AMENT_PREFIX_PATH": str(install),
           "PYTHONPATH": os.pathsep.join(p for p in (str(site), os.environ.get("PYTHONPATH"))
                                         if p),
           "PATH": f"{BIN}{os.pathsep}{os.environ.get('PATH', '')}",
           "ROS_LOG_DIR": str(tmp_path / "log")}


@pytest.mark.parametrize("presses", [1, 2], ids=["ctrl_c", "ctrl_c_twice"])
def test_ctrl_c_in_the_launch_terminal_ends_every_node_cleanly(
    ros2_env: dict[str, str], presses: int
) -> None:
    proc = subprocess.Popen(
        [str(BIN / "ros2"), "launch", PACKAGE, "base.launch.py", "use_sim:=true",
         "use_follower:=true"],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=ros2_env,
        start_new_session=True)  # its own process group, as a terminal's foreground job
    lines: list[str] = []
    reader = threading.Thread(target=lambda: lines.extend(proc.stdout or ()), daemon=True)
    reader.start()
    try:
        # Each node logs one INFO line once it is built: then all of them spin.
        deadline = time.monotonic() + 60.0
        while time.monotonic() < deadline and not all(
                any(line.startswith(f"[{n}-") and "[INFO]" in line for line in lines)
                for n in NODES):
            assert proc.poll() is None, "".join(lines)
            time.sleep(0.1)
        for press in range(presses):
            os.killpg(proc.pid, signal.SIGINT)
            if press + 1 < presses:
                time.sleep(0.3)  # a second press while the nodes stop
        assert proc.wait(timeout=30) == 0, "".join(lines)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
        reader.join(10.0)
    text = "".join(lines)
    assert {m.group(1): 0 for m in FINISHED.finditer(text)} | {
        m.group(1): int(m.group(2)) for m in DIED.finditer(text)} == dict.fromkeys(NODES, 0), text
    assert "Traceback" not in text, text
