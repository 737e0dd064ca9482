"""The command lines: ``diffdrive-odom`` and the three nodes, run as a user runs them.

Each check runs the installed console script in its own process (nodes) or the CLI
entry point (tools) and reads what a user would see: the exit code and the lines.
"""

from __future__ import annotations

import argparse
import importlib
import subprocess
from importlib import metadata
from pathlib import Path
from xml.etree import ElementTree

import pytest

from diffdrive_odom.tools import cli as cli_module
from diffdrive_odom.tools.cli import main as cli

from rosutil import ROOT, executable

NODES = ("odometry_node", "cmd_vel_node", "sim_node")
# The topics each node's page (doc/nodes/) documents (default parameters, no namespace).
PAGE_TOPICS = {
    "odometry_node": ("/joint_states", "/odom", "/tf", "reset_odometry", "set_pose"),
    "cmd_vel_node": ("/cmd_vel", "/wheel_commands"),
    "sim_node": ("/wheel_commands", "/joint_states", "/ground_truth/odom"),
}


def _run(name: str, *args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([executable(name), *args], capture_output=True, text=True,
                          timeout=60)


def _lines(text: str) -> list[str]:
    return [ln for ln in text.splitlines() if ln.strip()]


def _package_xml_version() -> str:
    text = ElementTree.parse(ROOT / "package.xml").findtext("version")
    assert text
    return text.strip()


# --- diffdrive-odom ------------------------------------------------------------------


def test_an_unknown_command_is_named_and_exits_2(capsys: pytest.CaptureFixture[str]) -> None:
    assert cli(["evaluate"]) == 2
    err = capsys.readouterr().err
    assert "unknown command 'evaluate'" in err and "did you mean 'eval'" in err
    assert len(_lines(err)) == 1
    assert cli([]) == 2
    assert "no command" in capsys.readouterr().err
    assert cli(["--help"]) == 0
    out = capsys.readouterr().out
    assert all(name in out for name in cli_module.COMMANDS)


@pytest.mark.process
def test_version_is_the_package_version(capsys: pytest.CaptureFixture[str],
                                        monkeypatch: pytest.MonkeyPatch) -> None:
    expected = _package_xml_version()
    assert cli(["--version"]) == 0
    assert capsys.readouterr().out.strip() == f"diffdrive-odom {expected}"
    done = _run("diffdrive-odom", "--version")
    assert done.returncode == 0 and done.stdout.strip() == f"diffdrive-odom {expected}"

    # Run from a tree that was never installed: package.xml is the fallback.
    def missing(name: str) -> str:
        raise metadata.PackageNotFoundError(name)

    monkeypatch.setattr(metadata, "version", missing)
    assert cli_module.version() == expected


@pytest.mark.parametrize("command", sorted(cli_module.COMMANDS))
@pytest.mark.process
def test_every_subcommand_help_shows_every_default(command: str) -> None:
    done = _run("diffdrive-odom", command, "--help")
    assert done.returncode == 0, done.stderr
    flat = "".join(done.stdout.split())  # argparse wraps long values mid-word
    module = importlib.import_module(cli_module.COMMANDS[command][0])
    parser: argparse.ArgumentParser = module._parser()
    for action in parser._actions:
        default = action.default
        if (default is argparse.SUPPRESS or not action.option_strings or action.nargs == 0
                or action.required or action.help == argparse.SUPPRESS
                or default in ([], ())):
            continue  # positionals, required, flags, repeatables, hidden: no default to show
        if default is None:
            # no value to print: the help text must say what happens instead
            assert "default" in (action.help or ""), action.option_strings
        else:
            assert "".join(str(default).split()) in flat, (action.option_strings, default)


# --- the nodes ---------------------------------------------------------------------------


@pytest.mark.parametrize("node", NODES)
@pytest.mark.process
def test_node_help_prints_topics_and_where_parameters_go(node: str) -> None:
    done = _run(node, "--help")
    assert done.returncode == 0, done.stdout + done.stderr
    out = done.stdout
    assert out.startswith(f"usage: {node}")
    for topic in PAGE_TOPICS[node]:
        assert topic in out, (node, topic, out)
    assert f"{node} --ros-args --params-file" in out and f"doc/nodes/{node}.md" in out
    assert (ROOT / "doc" / "nodes" / f"{node}.md").is_file()
    # The same with a namespace: the listed names are the node's own, resolved.
    ns = _run(node, "--ros-args", "-r", "__ns:=/robot1", "--", "--help")
    expected = "/robot1/odom" if node == "odometry_node" else "/robot1/wheel_commands"
    assert ns.returncode == 0 and expected in ns.stdout, ns.stdout


@pytest.mark.process
def test_node_arguments_outside_ros_args_are_named_with_the_right_form() -> None:
    done = _run("odometry_node", "-p", "wheel_radius:=0.05")
    assert done.returncode == 2
    lines = _lines(done.stdout + done.stderr)
    assert len(lines) == 1, lines
    assert "`odometry_node --ros-args -p wheel_radius:=0.05`" in lines[0]
    bare = _run("cmd_vel_node", "wheel_radius:=0.05")  # rcl would take it for a remap
    assert bare.returncode == 2 and "--ros-args -p wheel_radius:=0.05" in bare.stderr
    stray = _run("sim_node", "foo")
    assert stray.returncode == 2
    lines = _lines(stray.stdout + stray.stderr)
    assert len(lines) == 1 and "'foo'" in lines[0] and "--ros-args" in lines[0], lines


@pytest.mark.parametrize("node", NODES)
@pytest.mark.process
def test_a_missing_params_file_is_one_line_naming_it(node: str, tmp_path: Path) -> None:
    missing = tmp_path / "nope.yaml"
    done = _run(node, "--ros-args", "--params-file", str(missing))
    assert done.returncode == 2
    lines = _lines(done.stdout + done.stderr)
    assert len(lines) == 1 and str(missing) in lines[0], lines
    assert "Traceback" not in done.stderr


@pytest.mark.parametrize("command", ["replay", "calibrate"])
def test_a_params_file_that_is_not_yaml_is_one_line_with_where(
        command: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Issue 39 item 1 (every tool's failure is one line): PyYAML's message took four
    lines, the last a caret under a blank."""
    broken = tmp_path / "p.yaml"
    broken.write_text("/**:\n  ros__parameters:\n    left_wheel_names: [a\n", encoding="utf-8")
    extra = ["--eval"] if command == "replay" else []
    assert cli([command, str(tmp_path / "bag"), "--params-file", str(broken), *extra]) == 2
    lines = _lines(capsys.readouterr().err)
    assert len(lines) == 1 and lines[0].startswith(f"[{command}] "), lines
    assert f"{broken} is not YAML: " in lines[0] and "(line 4, column 1)" in lines[0], lines
