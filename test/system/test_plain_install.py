"""A plain ``pip install`` (no ``tools`` extra, no tf2_msgs): help everywhere, one line
for what is missing, no partial output.

Each console script runs in a fresh interpreter in which rosbags, scipy, matplotlib
and tf2_msgs cannot be imported (a meta-path finder refuses them, as test_layering
does; here the refusal is the ``ModuleNotFoundError`` a missing package raises). The
scripts are the installed distribution's own entry points, so a new one is checked
too. On main, ``odometry_node --help`` ended in ``No module named 'tf2_msgs'`` and
``diffdrive-odom calibrate --help`` in ``'rosbags'``.
"""

from __future__ import annotations

import csv
import json
import os
import signal
import subprocess
import sys
from importlib.metadata import entry_points
from pathlib import Path

import pytest

from diffdrive_odom.demo.settings import DemoError, check_output
from diffdrive_odom.tools.cli import COMMANDS

from bagutil import OPTIODOM_PARAMS, write_params
from rosutil import DATA

pytestmark = [pytest.mark.process]

OPTIONAL = ("rosbags", "scipy", "matplotlib", "tf2_msgs")
RUN04 = DATA / "optiodom" / "square_231220200029_run-04"

# The console script ``argv[0]`` with ``argv[1:]``, as pip's launcher runs it, in an
# interpreter where the modules of argv... are missing.
LAUNCH = r"""
import importlib.abc, json, sys
from importlib.metadata import entry_points

blocked = set(json.loads(sys.argv[1]))

class Missing(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] in blocked:
            raise ModuleNotFoundError(f"No module named {name!r}", name=name)
        return None

sys.meta_path.insert(0, Missing())
script, *args = json.loads(sys.argv[2])
(ep,) = [e for e in entry_points(group="console_scripts") if e.name == script]
sys.argv = [script, *args]
sys.exit(ep.load()())
"""


def launch(script: str, *args: str, missing: tuple[str, ...] = OPTIONAL,
           cwd: Path | None = None) -> subprocess.Popen[str]:
    return subprocess.Popen(
        [sys.executable, "-c", LAUNCH, json.dumps(missing), json.dumps([script, *args])],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=cwd)


def finish(proc: subprocess.Popen[str]) -> tuple[int, str, str]:
    out, err = proc.communicate(timeout=120)
    return proc.returncode, out, err


def console_scripts() -> list[str]:
    return sorted(e.name for e in entry_points(group="console_scripts")
                  if e.value.startswith("diffdrive_odom."))


@pytest.mark.dds  # the nodes' help builds the node to list its topics
def test_every_console_script_and_command_helps_without_the_optional_packages() -> None:
    scripts = console_scripts()
    assert {"odometry_node", "sim_node", "diffdrive-odom"} <= set(scripts)
    runs: list[tuple[str, ...]] = [(s, "--help") for s in scripts]
    runs += [("diffdrive-odom", command, "--help") for command in COMMANDS]
    procs = {run: launch(*run) for run in runs}  # all at once: each pays rclpy's import
    for run, proc in procs.items():
        code, out, err = finish(proc)
        assert code == 0, (run, out, err)
        assert "usage:" in out, (run, out)
        assert "Traceback" not in out + err, (run, err)


# What `pip install diffdrive_odom` without the extra lacks, as the line names it: the
# extra, and its libraries for a colcon build (setup.py's TOOLS, as pip records them).
TOOLS_LINE = ("pip install 'diffdrive_odom[tools]' (or its libraries alone: pip install "
              "'rosbags<0.12,>=0.11.9' orjson matplotlib scipy threadpoolctl)")
RUN01 = DATA / "optiodom" / "square_231220200029_run-01"

# Each command, with the options that reach each library of the tools extra it needs.
NEEDS = [
    ("replay", ("--csv", "{tmp}/o.csv"), "rosbags"),
    ("replay", ("--csv", "{tmp}/o.csv", "--eval", "--plot", "{tmp}/o.png"), "matplotlib"),
    ("eval", ("--odom", "/firmware/odom"), "rosbags"),
    ("calibrate", (str(RUN01),), "rosbags"),
    ("calibrate", (str(RUN01),), "scipy"),
    ("calibrate", (str(RUN01), "--plot", "{tmp}/c.png"), "matplotlib"),
    ("play", ("--rate", "50"), "rosbags"),
    ("reindex", ("--output", "{tmp}/copy"), "rosbags"),  # of a torn recording
]


@pytest.mark.parametrize(("command", "options", "library"), NEEDS)
def test_a_missing_library_at_run_time_is_one_line_naming_the_extra(
        command: str, options: tuple[str, ...], library: str, tmp_path: Path) -> None:
    params = write_params(tmp_path / "p.yaml", OPTIODOM_PARAMS)
    out = tmp_path / "out"
    out.mkdir()
    bag = RUN04
    if command == "reindex":  # an intact one has nothing to do
        (mcap,) = RUN04.glob("*.mcap")
        bag = tmp_path / "torn.mcap"
        bag.write_bytes(mcap.read_bytes()[:500_000])
    args = [str(bag), *(o.format(tmp=out) for o in options)]
    if command in ("replay", "calibrate"):
        args += ["--params-file", str(params)]
    code, stdout, err = finish(launch("diffdrive-odom", command, *args, missing=(library,)))
    assert (code, err) == (2, f"diffdrive-odom {command} needs {library}: {TOOLS_LINE}\n"), stdout
    assert list(out.iterdir()) == []  # nothing half-written


@pytest.mark.parametrize("library", ["rosbags", "scipy", "matplotlib"])
def test_the_demo_missing_a_library_says_so_before_it_drives(library: str,
                                                             tmp_path: Path) -> None:
    """matplotlib draws the plot last: its absence was said after the drive (7 s with
    --short, over a minute without)."""
    output = tmp_path / "demo_output"
    code, out, err = finish(launch("diffdrive-odom", "demo", "--short", "--output", str(output),
                                   "--domain-id", os.environ.get("ROS_DOMAIN_ID", "0"),
                                   missing=(library,)))
    assert (code, err) == (2, f"diffdrive-odom demo needs {library}: {TOOLS_LINE}\n")
    assert out == "" and not output.exists()  # nothing started, nothing written


def test_orjson_missing_costs_nothing_but_speed(tmp_path: Path) -> None:
    """orjson (the CSV's numbers) is the one library of the extra a tool does without."""
    params = write_params(tmp_path / "p.yaml", OPTIODOM_PARAMS)
    procs = [launch("diffdrive-odom", "replay", str(RUN04), "--params-file", str(params),
                    "--csv", str(tmp_path / f"{name}.csv"), missing=missing)
             for name, missing in (("with", ()), ("without", ("orjson",)))]
    for proc in procs:
        code, _, err = finish(proc)
        assert code == 0, err
    tables = [list(csv.reader((tmp_path / f"{n}.csv").open())) for n in ("with", "without")]
    assert len(tables[0]) == len(tables[1]) == 1 + 1385  # the header, a row a reading
    for row, other in zip(*tables, strict=True):  # the same doubles (in another spelling)
        assert [_value(v) for v in row] == [_value(v) for v in other]


def _value(text: str) -> float | str:
    try:
        return float(text)
    except ValueError:
        return text


def test_eval_plot_without_matplotlib_prints_the_table_then_the_line(tmp_path: Path) -> None:
    png = tmp_path / "e.png"
    code, out, err = finish(launch("diffdrive-odom", "eval", str(RUN04), "--odom",
                                   "/firmware/odom", "--plot", str(png),
                                   missing=("matplotlib",)))
    assert code == 2, err
    assert "final position error" in out  # the table, first
    assert err.endswith(f"diffdrive-odom eval needs matplotlib: {TOOLS_LINE}\n"), err
    assert not png.exists()


@pytest.mark.dds
def test_odometry_node_without_tf2_msgs_says_how_to_get_it() -> None:
    code, out, err = finish(launch("odometry_node", "--ros-args", "-p", "wheel_radius:=0.05",
                                   "-p", "wheel_separation:=0.3", missing=("tf2_msgs",)))
    assert code == 2, out + err
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1, err
    assert lines[0].startswith("odometry_node needs tf2_msgs: ")
    assert "apt install ros-jazzy-tf2-msgs" in lines[0] and "build_tf2_msgs.sh" in lines[0]


# --- the demo's output ----------------------------------------------------------------


def test_the_demo_replaces_only_a_previous_demo_output(tmp_path: Path) -> None:
    """A finished demo replaces its output directory: refused up front unless it is new,
    empty or a previous demo's, so a user's own files are never deleted."""
    check_output(tmp_path / "new")
    previous = tmp_path / "previous"
    (previous / "logs").mkdir(parents=True)
    (previous / "results.json").write_text("{}")
    check_output(previous)
    (previous / "notes.txt").write_text("mine")
    with pytest.raises(DemoError, match=r"notes\.txt, not a demo's output"):
        check_output(previous)
    with pytest.raises(DemoError, match="not a directory"):
        check_output(previous / "notes.txt")


@pytest.mark.dds
@pytest.mark.demo
@pytest.mark.slow
def test_an_interrupted_demo_leaves_no_partial_output(tmp_path: Path) -> None:
    """Ctrl-C once the nodes are up: no new output, the previous one as it was, and no
    staging directory left beside it. On main the interrupted run's logs, params and
    bag stayed in demo_output/ (a half-written bag included)."""
    output = tmp_path / "demo_output"
    (output / "logs").mkdir(parents=True)
    (output / "results.json").write_text('{"previous": true}\n')
    proc = subprocess.Popen(
        [str(Path(sys.executable).parent / "diffdrive-odom"), "demo", "--output", str(output),
         "--no-plot", "--domain-id", os.environ.get("ROS_DOMAIN_ID", "0")],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert proc.stdout is not None
        out = ""
        while "nodes up" not in out:
            line = proc.stdout.readline()
            if not line:
                break
            out += line
        assert "nodes up" in out, out
        staging = [p for p in tmp_path.iterdir() if p.name.startswith(".demo_output.partial")]
        assert len(staging) == 1 and (staging[0] / "demo_output" / "logs").is_dir(), staging
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 130, err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["demo_output"]
    assert sorted(p.name for p in output.iterdir()) == ["logs", "results.json"]
    assert (output / "results.json").read_text() == '{"previous": true}\n'
