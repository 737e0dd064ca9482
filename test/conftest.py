"""Test-session setup: every run (each xdist worker) gets its own DDS domain, on loopback
only; a test marked neither ``process`` nor ``dds`` may start neither (the tiers); the
colcon workspace that test_colcon and test_launch share; the odometry_node rig of the
DDS tests (``odom_rig``); Hypothesis without its wall-clock deadline."""

from __future__ import annotations

import contextlib
import os
import random
import shutil
import subprocess
import sys
from collections.abc import Callable, Iterator
from contextlib import ExitStack
from pathlib import Path
from typing import TYPE_CHECKING, Any

import pytest
from hypothesis import settings

from diffdrive_odom.ros import discovery

from paths import ROOT

if TYPE_CHECKING:
    from rosutil import OdomRig

# Before anything imports rclpy or starts a node: child processes inherit these.
if "ROS_DOMAIN_ID" not in os.environ or os.environ.get("DIFFDRIVE_ODOM_FRESH_DOMAIN", "1") == "1":
    os.environ["ROS_DOMAIN_ID"] = str(random.Random(os.getpid() ^ id(os)).randint(1, 100))
    os.environ["DIFFDRIVE_ODOM_FRESH_DOMAIN"] = "0"
if os.environ.get("PYTEST_XDIST_WORKER", "").startswith("gw"):
    # Workers inherit the controller's domain: each moves to its own (gw0 -> +1, gw1 -> +2).
    _worker = int(os.environ["PYTEST_XDIST_WORKER"][2:])
    os.environ["ROS_DOMAIN_ID"] = str((int(os.environ["ROS_DOMAIN_ID"]) + _worker) % 100 + 1)
os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
os.environ.pop("ROS_LOCALHOST_ONLY", None)
os.environ.setdefault("RCUTILS_COLORIZED_OUTPUT", "0")

# No per-example wall-clock deadline: on four workers sharing two cores an example can be
# descheduled past Hypothesis's 200 ms, which says nothing about the property.
settings.register_profile("diffdrive_odom", deadline=None)
settings.load_profile("diffdrive_odom")

# The suite's processes start one after another, as the demo's do: Fast DDS's first
# announcements as the demo gives them (diffdrive_odom/ros/discovery.py), so a process
# finds one started up to 3 s before it at once, not at the next announcement 3 s later
# (the parallel tier 7.2 -> 6.3 min). A user's own profile or RMW is left as it is.
os.environ.update(discovery.with_profile(os.environ))


def pytest_sessionstart(session: pytest.Session) -> None:
    """Let matplotlib build its font cache now, outside any test's tier guard.

    On a machine that has never run matplotlib, its first import runs ``fc-list``: inside
    a pure test that is a child process the guard refuses (seen on a new machine).
    """
    with contextlib.suppress(ImportError):
        import matplotlib.font_manager  # noqa: F401


def _refuse(what: str, marker: str, nodeid: str) -> Any:
    def refuse(*args: Any, **kwargs: Any) -> Any:
        raise AssertionError(f"{nodeid} {what}: mark it `{marker}` (setup.cfg lists the tiers)")
    return refuse


@pytest.hookimpl(trylast=True)
def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Keeps ``make test``'s ``--dist loadgroup`` grouping: the tests of an xdist_group
    (``colcon``: one build, one ``ros2`` graph of nine nodes) on one worker.

    pytest-xdist tells its scheduler a test's group by a suffix on its node id, written
    where pytest 9.2's structured node ids no longer read it (pytest-xdist issue 1386):
    the group was silently dropped, and both workers built the workspace and started the
    graph. The suffix goes where pytest reads it now; where xdist's own worked, it is there.
    """
    if not getattr(config.option, "loadgroup", False):  # an xdist worker under loadgroup
        return
    for item in items:
        groups = sorted({str(m.args[0] if m.args else m.kwargs.get("name", "default"))
                         for m in item.iter_markers("xdist_group")})
        if groups and "@" not in item.nodeid and hasattr(item, "_id"):
            from _pytest.nodeid import NodeId

            item._id = NodeId.parse(f"{item.nodeid}@{'_'.join(groups)}")


@pytest.fixture(autouse=True)
def _tier_guard(request: pytest.FixtureRequest, monkeypatch: pytest.MonkeyPatch) -> Iterator[None]:
    """A test of the fast tier really is pure: no child process, no rclpy Context."""
    marks = {m.name for m in request.node.iter_markers()}
    if "process" not in marks:
        monkeypatch.setattr(subprocess, "Popen", _refuse("starts a process", "process",
                                                         request.node.nodeid))
    rclpy = sys.modules.get("rclpy")
    if "dds" not in marks and rclpy is not None:
        monkeypatch.setattr(rclpy, "init", _refuse("starts rclpy", "dds", request.node.nodeid))
    yield


BIN = Path(sys.executable).parent


def _tracked_files() -> list[str]:
    # Tracked and new (not ignored) files: what a commit of this checkout would hold.
    out = subprocess.run(["git", "ls-files", "--cached", "--others", "--exclude-standard"],
                         cwd=ROOT, capture_output=True, text=True)
    if out.returncode == 0 and out.stdout.strip():
        return out.stdout.split()
    # Not a git checkout (an sdist): take everything but caches and build outputs.
    skip = {".venv", "build", "install", "log", "__pycache__", ".git"}
    return [str(p.relative_to(ROOT)) for p in ROOT.rglob("*")
            if p.is_file() and not skip & set(p.relative_to(ROOT).parts)]


@pytest.fixture(scope="session")
def colcon_ws(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The workspace with the package built by ``colcon build``, once per test session.

    test_launch runs its launch files against this install too: one build serves both.
    The package's tracked files are copied into a fresh workspace, as a user's checkout
    in ``~/ws/src`` would be.
    """
    ws = tmp_path_factory.mktemp("colcon_ws")
    src = ws / "src" / "diffdrive_odom"
    for rel in _tracked_files():
        if rel.startswith("test/data/") or not (ROOT / rel).is_file():
            continue  # the workspace does not need the recordings; skip deleted files
        dest = src / rel
        dest.parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(ROOT / rel, dest)
    env = {**os.environ, "PATH": f"{BIN}:{os.environ.get('PATH', '')}"}
    # console_direct (colcon's default) passes setup.py's stderr on to colcon's, where
    # test_colcon reads it (kept beside the workspace's log/).
    build = subprocess.run(
        [str(BIN / "colcon"), "build"],
        cwd=ws, capture_output=True, text=True, env=env, timeout=300,
    )
    assert build.returncode == 0, build.stdout + build.stderr
    (ws / "log" / "colcon_build.stderr").write_text(build.stderr, encoding="utf-8")
    return ws


@pytest.fixture
def odom_rig() -> Iterator[Callable[..., OdomRig]]:
    """Starts the rig of an odometry_node test, as often as the test calls it: ``rig =
    odom_rig(*params, geometry=..., ns=..., joints=..., qos=...)`` is the node's process
    (with its output read as it comes) and a peer node with its executor, publisher and
    sink, matched both ways (rosutil.odom_rig); all stopped when the test ends.
    """
    from rosutil import odom_rig as start  # rclpy only where a DDS test asks for it

    with ExitStack() as stack:
        yield lambda *params, **options: stack.enter_context(start(*params, **options))
