"""A child ends with the process that started it, however that one ends (``ros.lifetime``).

Real processes: a parent (a fresh interpreter) starts a child that watches it, the test
kills the parent with SIGKILL (no cleanup of any kind runs) and holds the check until the
child is gone. What the child did is in a file it writes when its ``on_end`` runs, so a
child that merely crashed would not pass. PR_SET_PDEATHSIG would end the child when the
parent's *thread* that started it ends: a child started from a short-lived thread must
live on while the parent does.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from diffdrive_odom.ros import lifetime

from rosutil import GEOMETRY, executable, kill_left, running, still_running

# The child: watch the named parent; on its end, write the marker (the grace then ends it).
CHILD = r"""
import sys, time
from pathlib import Path
from diffdrive_odom.ros import lifetime
marker = Path(sys.argv[1])
pid = lifetime.named_parent()
lifetime.watch(pid, lambda: marker.write_text(f"parent {pid} ended"), grace=0.2)
time.sleep(600)
"""

# The parent: start the child (from the main thread or a thread that then ends), print
# its pid, live until killed.
PARENT = r"""
import json, os, subprocess, sys, threading, time
from diffdrive_odom.ros import lifetime
child, marker, from_thread = sys.argv[1], sys.argv[2], sys.argv[3] == "thread"
started = []
def start():
    started.append(subprocess.Popen([sys.executable, "-c", child, marker],
                                    env=lifetime.child_env(os.environ)))
if from_thread:
    t = threading.Thread(target=start)
    t.start()
    t.join()  # the thread that forked the child has ended
else:
    start()
print(json.dumps(started[0].pid), flush=True)
time.sleep(600)
"""

pytestmark = [pytest.mark.process]


Started = tuple[subprocess.Popen[str], int, Path]  # the parent, its child's pid, the marker


@pytest.fixture
def parent_of_a_watcher(tmp_path: Path) -> Iterator[Callable[[bool], Started]]:
    """Starts (parent, child pid, marker) as asked; kills what is left at the end."""
    procs: list[tuple[subprocess.Popen[str], int]] = []

    def start(from_thread: bool) -> Started:
        marker = tmp_path / f"ended-{len(procs)}"
        parent = subprocess.Popen(
            [sys.executable, "-c", PARENT, CHILD, str(marker),
             "thread" if from_thread else "main"], stdout=subprocess.PIPE, text=True)
        assert parent.stdout is not None
        child = int(json.loads(parent.stdout.readline()))
        procs.append((parent, child))
        return parent, child, marker

    yield start
    for parent, child in procs:
        kill_left(parent, [child])


@pytest.mark.parametrize("from_thread", [False, True], ids=["main_thread", "ended_thread"])
def test_a_child_ends_when_its_parent_is_killed(
        parent_of_a_watcher: Callable[[bool], Started], from_thread: bool) -> None:
    parent, child, marker = parent_of_a_watcher(from_thread)
    time.sleep(1.0)  # the child watches by now; a thread's end must not have ended it
    assert running(child) and not marker.exists(), "the child ended while its parent ran"
    parent.kill()
    parent.wait()
    assert not still_running([child], 20.0), "the child outlived its parent"
    assert marker.read_text() == f"parent {parent.pid} ended"


def exited_pid() -> int:
    """The pid of a process that has ended (and been reaped)."""
    proc = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                          capture_output=True, text=True, check=True)
    return int(proc.stdout)


@pytest.mark.parametrize("named", ["ended", "not_an_ancestor"])
def test_a_parent_gone_before_the_child_looked_ends_it_at_once(tmp_path: Path,
                                                               named: str) -> None:
    """The race of a parent killed while its child starts: the child, handed to init
    meanwhile, finds the pid gone, or naming a process that is not its ancestor."""
    marker = tmp_path / "ended"
    stranger = subprocess.Popen(["sleep", "60"]) if named == "not_an_ancestor" else None
    try:
        pid = stranger.pid if stranger else exited_pid()
        child = subprocess.run([sys.executable, "-c", CHILD, str(marker)],
                               env={**os.environ, lifetime.PARENT_ENV: str(pid)},
                               timeout=30)
    finally:
        if stranger:
            stranger.kill()
            stranger.wait()
    assert marker.read_text() == f"parent {pid} ended"
    assert child.returncode == lifetime.EXIT_ORPHANED  # on_end did not stop it: the grace


def test_the_named_parent_is_taken_out_of_the_environment(
        monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv(lifetime.PARENT_ENV, "4242")
    assert lifetime.named_parent() == 4242
    assert lifetime.PARENT_ENV not in os.environ  # what the child starts does not watch it
    assert lifetime.named_parent() is None
    for bad in ("x", "-3", "0"):
        monkeypatch.setenv(lifetime.PARENT_ENV, bad)
        with pytest.raises(ValueError, match=f"{lifetime.PARENT_ENV}='{bad}' is not a process"):
            lifetime.named_parent()


def test_sighup_is_a_stop_signal_unless_ignored_from_the_start() -> None:
    """nohup ignores SIGHUP before the program starts: the user wants it to outlive the
    terminal, so it stays ignored; otherwise a closed terminal is a stop."""
    before = signal.signal(signal.SIGHUP, signal.SIG_IGN)
    try:
        assert lifetime.stop_signals() == (signal.SIGINT, signal.SIGTERM)
        signal.signal(signal.SIGHUP, signal.SIG_DFL)
        assert lifetime.stop_signals() == (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)
    finally:
        signal.signal(signal.SIGHUP, before)


@pytest.mark.dds
def test_a_node_whose_parent_has_ended_stops_cleanly_with_a_line() -> None:
    """The node's stop, as on SIGTERM: exit 0, one line naming the parent, no traceback;
    a value that is no pid stops it at start with one line (exit 2)."""
    gone = exited_pid()
    node = subprocess.run([executable("odometry_node"), "--ros-args", *GEOMETRY],
                          env={**os.environ, lifetime.PARENT_ENV: str(gone)},
                          capture_output=True, text=True, timeout=60)
    assert node.returncode == 0, node.stdout + node.stderr
    assert (f"[odometry_node] the process that started it (pid {gone}) has ended: "
            "stopping") in node.stderr
    assert "Traceback" not in node.stdout + node.stderr
    bad = subprocess.run([executable("odometry_node"), "--ros-args", *GEOMETRY],
                         env={**os.environ, lifetime.PARENT_ENV: "launch"},
                         capture_output=True, text=True, timeout=60)
    assert (bad.returncode, bad.stderr) == (
        2, f"[odometry_node] {lifetime.PARENT_ENV}='launch' is not a process id\n")
