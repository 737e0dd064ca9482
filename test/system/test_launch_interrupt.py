"""Ctrl-C in the terminal of ``ros2 launch``: every node ends cleanly (exit 0); and when
launch itself is killed, or cannot start, no node stays behind.

A terminal sends SIGINT to the whole foreground process group: ``ros2 launch`` and each
node get it, then launch sends each node its own SIGINT. A user who presses Ctrl-C twice
adds a third. Each signal after the first used to raise into the node's teardown or hit
the default action Python restores at its exit: ``process has died [... exit code -2]``.
Here the real ``ros2 launch`` runs base.launch.py (odometry, cmd_vel, sim and follower
nodes) from the colcon install in a session of its own, the test sends SIGINT to its
process group as the terminal does, and launch's own log says how each process ended.

A ``ros2 launch`` killed with SIGKILL (or SIGHUP, which it does not handle) runs no
shutdown: its nodes, handed to init, kept running. Each now watches launch's pid and
stops by itself. ``rviz:=true`` without RViz2 failed only when launch came to start it,
after the odometry node, which stayed running: now it is named before anything starts.
And what the same command says of an argument no file declares (issue 39 item 5), and
of the simulated gyro (item 6).
"""

from __future__ import annotations

import contextlib
import os
import re
import shlex
import signal
import subprocess
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest

from rosutil import BIN, ros_test_node, spin_until, still_running

PACKAGE = "diffdrive_odom"
NODES = {"odometry_node", "cmd_vel_node", "sim_node", "path_follower_node"}
FINISHED = re.compile(r"\[INFO\] \[(\w+)-\d+\]: process has finished cleanly \[pid \d+\]")
STARTED = re.compile(r"\[INFO\] \[(\w+)-\d+\]: process started with pid \[(\d+)\]")
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


@contextmanager
def launched(env: dict[str, str], *arguments: str
             ) -> Iterator[tuple[subprocess.Popen[str], list[str]]]:
    """``ros2 launch diffdrive_odom ARGUMENTS`` in a session of its own, and its output
    lines as they come; complete once the block is left, with whatever of the session is
    left killed."""
    proc = subprocess.Popen(
        [str(BIN / "ros2"), "launch", PACKAGE, *arguments],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env,
        start_new_session=True)  # its own process group, as a terminal's foreground job
    lines: list[str] = []
    reader = threading.Thread(target=lambda: lines.extend(proc.stdout or ()), daemon=True)
    reader.start()
    try:
        yield proc, lines
    finally:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGKILL)  # launch, or nodes it left behind
        proc.wait()
        reader.join(10.0)


def wait_for_nodes(proc: subprocess.Popen[str], lines: list[str],
                   nodes: frozenset[str] | set[str] = NODES) -> None:
    """Until each node has logged its first INFO line (built: all of them spin then)."""
    deadline = time.monotonic() + 60.0
    while time.monotonic() < deadline and not all(
            any(line.startswith(f"[{n}-") and "[INFO]" in line for line in lines)
            for n in nodes):
        assert proc.poll() is None, "".join(lines)
        time.sleep(0.1)


@pytest.mark.parametrize("signum", [signal.SIGKILL, pytest.param(
    signal.SIGHUP, marks=pytest.mark.skipif(
        signal.getsignal(signal.SIGHUP) == signal.SIG_IGN,
        reason="SIGHUP ignored from the start (nohup): launch would ignore it"))],
    ids=["sigkill", "sighup"])
def test_no_node_outlives_a_killed_launch(ros2_env: dict[str, str], signum: int) -> None:
    """The signal to launch's pid only (``kill``, a closed ssh session): launch ends at
    once, running no shutdown; each node, watching launch's pid, stops by itself."""
    with launched(ros2_env, "base.launch.py", "use_sim:=true", "use_follower:=true"
                  ) as (proc, lines):
        wait_for_nodes(proc, lines)
        pids = {m.group(1): int(m.group(2)) for m in STARTED.finditer("".join(lines))}
        assert set(pids) == NODES, "".join(lines)
        os.kill(proc.pid, signum)
        assert proc.wait(timeout=30) == -signum, "".join(lines)
        assert not still_running(list(pids.values()), 30.0), "".join(lines)


def test_rviz_without_rviz2_is_named_before_any_node_starts(
        ros2_env: dict[str, str]) -> None:
    """On a machine without RViz2, the user's command: one line naming what is missing
    and how to get it, exit 1, and no process started (launch's own log says which)."""
    index = "share/ament_index/resource_index/packages/rviz2"
    if any((Path(prefix) / index).exists()
           for prefix in ros2_env.get("AMENT_PREFIX_PATH", "").split(os.pathsep) if prefix):
        pytest.skip("RViz2 is installed here: nothing is missing")
    command = ["base.launch.py", "use_sim:=true", "rviz:=true"]
    with launched(ros2_env, *command) as (proc, lines):
        code = proc.wait(timeout=60)
    text = "".join(lines)
    assert code == 1, f"ros2 launch {shlex.join(command)}:\n{text}"
    errors = [ln for ln in text.splitlines() if "[ERROR]" in ln]
    assert len(errors) == 1 and "rviz:=true needs RViz2" in errors[0], text
    assert "apt install ros-jazzy-rviz2" in errors[0], text
    assert not STARTED.search(text), text


@pytest.mark.parametrize("presses", [1, 2], ids=["ctrl_c", "ctrl_c_twice"])
def test_ctrl_c_in_the_launch_terminal_ends_every_node_cleanly(
    ros2_env: dict[str, str], presses: int
) -> None:
    with launched(ros2_env, "base.launch.py", "use_sim:=true", "use_follower:=true"
                  ) as (proc, lines):
        wait_for_nodes(proc, lines)
        for press in range(presses):
            os.killpg(proc.pid, signal.SIGINT)
            if press + 1 < presses:
                time.sleep(0.3)  # a second press while the nodes stop
        code = proc.wait(timeout=30)
    text = "".join(lines)
    # Launch's own exit: 0; or, pressed again as it exits once every node has ended (each
    # logged below as finished cleanly, so nothing is left behind), launch's SIGINT death,
    # as after any program that ended (a fresh clone's quick nodes were gone in 0.3 s).
    assert code == 0 or (presses == 2 and code == -signal.SIGINT), text
    assert {m.group(1): 0 for m in FINISHED.finditer(text)} | {
        m.group(1): int(m.group(2)) for m in DIED.finditer(text)} == dict.fromkeys(NODES, 0), text
    assert "Traceback" not in text and "[FATAL]" not in text, text  # issue 40 item 5


@pytest.mark.parametrize("launch_file", ["base.launch.py", "odometry.launch.py"])
def test_an_unknown_launch_argument_gets_one_warning_naming_the_real_one(
        ros2_env: dict[str, str], launch_file: str) -> None:
    """``publish_tf:=false`` (robot_localization's name) was silently ignored: one warning
    line now names enable_odom_tf, and launch goes on (an including file's arguments
    reach what it includes, so it is not refused; base.launch.py's include of
    odometry.launch.py says nothing more). With enable_odom_tf:=false the node's start
    line no longer says ``odom -> base_link``."""
    command = [launch_file, "publish_tf:=false", "enable_odom_tf:=false", "use_sim_tme:=true"]
    with launched(ros2_env, *command) as (proc, lines):
        wait_for_nodes(proc, lines, {"odometry_node", "cmd_vel_node"}
                       if launch_file == "base.launch.py" else {"odometry_node"})
    text = "".join(lines)
    warned = [ln for ln in text.splitlines() if "has no launch argument" in ln]
    assert len(warned) == 1, text
    assert warned[0].startswith("[WARNING] [launch]: "), warned
    assert f"{launch_file} has no launch argument publish_tf:= (did you mean " \
        "enable_odom_tf?" in warned[0], warned
    assert "use_sim_tme:= (did you mean use_sim_time?)" in warned[0], warned
    assert "enable_odom_tf:=," not in warned[0], warned  # a known one is not named
    start = [ln for ln in text.splitlines() if "wheel odometry:" in ln]
    assert len(start) == 1 and "->" not in start[0] and "no /tf" in start[0], start


def test_the_simulated_gyro_starts_without_warnings_that_contradict_it(
        ros2_env: dict[str, str]) -> None:
    """``use_sim:=true use_imu:=true`` warned that the gyro's noise is 0 (the sim's gyro has
    none: nothing to set gyro_noise_density to) and logged "IMU silent" then "IMU samples
    again" at every start (the imu topic matched after joint_states). Held until the
    node's /diagnostics count more zero-velocity updates than the noise check needs."""
    from diagnostic_msgs.msg import DiagnosticArray

    updates: list[int] = []

    def on_diagnostics(msg: DiagnosticArray) -> None:
        for status in msg.status:
            values = {kv.key: kv.value for kv in status.values}
            if "odometry" in status.name and "zero-velocity updates" in values:
                updates.append(int(values["zero-velocity updates"]))

    with launched(ros2_env, "base.launch.py", "use_sim:=true", "use_imu:=true"
                  ) as (proc, lines), ros_test_node("gyro_peer") as (node, ex):
        node.create_subscription(DiagnosticArray, "/diagnostics", on_diagnostics, 10)
        # standstill.NOISE_AFTER (25) rates held, the noise judged from twice that
        assert spin_until(ex, lambda: bool(updates) and updates[-1] > 60, 60.0), (
            updates, "".join(lines))
        os.killpg(proc.pid, signal.SIGINT)
        assert proc.wait(timeout=30) == 0, "".join(lines)
    text = "".join(lines)
    assert "wheel odometry:" in text, text
    for said in ("gyro's noise", "IMU silent", "IMU samples again", "no zero-velocity"):
        assert said not in text, text
