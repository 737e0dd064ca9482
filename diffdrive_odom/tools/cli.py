"""``diffdrive-odom``: one entry point for the tools, each in its own module.

Subcommands are imported only when used, so ``diffdrive-odom eval`` does not pay
for rclpy and ``diffdrive-odom play`` does not pay for matplotlib. Each imports its
optional dependencies (the ``tools`` extra: rosbags, scipy, matplotlib) only past its
argument parsing, so ``--help`` works on a plain install; one missing at run time is
one line naming the extra (:mod:`diffdrive_odom.settings.dependencies`), exit 2.
"""

from __future__ import annotations

import argparse
import difflib
import importlib
import shutil
import signal
import sys
import threading
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from importlib import metadata
from pathlib import Path
from xml.etree import ElementTree

from diffdrive_odom.ros.lifetime import stop_signals
from diffdrive_odom.settings.dependencies import missing_text
from diffdrive_odom.tools.cmdline import once

PROGRAM = "diffdrive-odom"
PACKAGE = "diffdrive_odom"

COMMANDS: dict[str, tuple[str, str]] = {
    "demo": ("diffdrive_odom.demo.cli",
             "closed-loop demo: follower + cmd_vel + sim + odometry; calibrates; table, plot, bag"),
    "play": ("diffdrive_odom.tools.play",
             "publish a bag's messages over DDS with /clock (no rosbag2)"),
    "replay": ("diffdrive_odom.tools.replay",
               "run the estimator over a bag offline; write bag/CSV"),
    "eval": ("diffdrive_odom.tools.evaluate", "compare odometry with ground truth in a bag"),
    "calibrate": ("diffdrive_odom.tools.calibrate", "fit wheel radii and separation; UMBmark"),
    "reindex": ("diffdrive_odom.tools.reindex",
                "a recording cut short: write its metadata.yaml, or a whole copy of a torn one"),
}


class HelpFormatter(argparse.ArgumentDefaultsHelpFormatter):
    """Every subcommand's ``--help`` shows each default, once.

    A default of None, False or empty says nothing as "(default: None)": those options
    spell out their default in their own help text, and an option whose help already
    says "(default" is left as written.
    """

    def _get_help_string(self, action: argparse.Action) -> str | None:
        default = action.default
        empty = default is None or default is False or (
            isinstance(default, (list, tuple)) and not default)
        if empty or "(default" in (action.help or ""):
            return action.help
        return super()._get_help_string(action)


def command_parser(command: str, description: str) -> argparse.ArgumentParser:
    """The parser of ``diffdrive-odom COMMAND``: its name in the usage, every default shown."""
    return argparse.ArgumentParser(prog=f"{PROGRAM} {command}", description=description,
                                   formatter_class=HelpFormatter)


def version() -> str:
    """The installed distribution's version, else package.xml's (a source checkout).

    colcon and pip both install the metadata; the fallback covers running from a tree
    that was never installed, where package.xml is the one place the version lives.
    """
    try:
        return metadata.version(PACKAGE)
    except metadata.PackageNotFoundError:
        pass
    candidates = [Path(__file__).resolve().parents[2] / "package.xml"]
    try:
        from ament_index_python.packages import get_package_share_directory

        candidates.insert(0, Path(get_package_share_directory(PACKAGE)) / "package.xml")
    except Exception:  # not in an ament workspace (or the index lacks the package)
        pass
    for path in candidates:
        try:
            text = ElementTree.parse(path).findtext("version")
        except (OSError, ElementTree.ParseError):
            continue
        if text:
            return text.strip()
    return "unknown"


def invocation() -> str:
    """How to run ``diffdrive-odom`` from here, for the hints the tools print.

    The bare name when the shell finds this very script; else its path (relative to
    the working directory when inside it), e.g. ``.venv/bin/diffdrive-odom`` after
    ``make demo``, whose venv is not on PATH.
    """
    script = Path(sys.executable).parent / PROGRAM
    found = shutil.which(PROGRAM)
    if not script.exists() or (found is not None and Path(found).resolve() == script.resolve()):
        return PROGRAM
    try:
        return str(script.relative_to(Path.cwd()))
    except ValueError:
        return str(script)


def usage() -> str:
    """The command list, as ``--help`` prints it."""
    lines = [f"usage: {PROGRAM} [--version] {{{','.join(COMMANDS)}}} ...", ""]
    lines += [f"  {name:8s} {text}" for name, (_, text) in COMMANDS.items()]
    lines += ["", f"`{PROGRAM} COMMAND --help` shows each command's options and defaults."]
    return "\n".join(lines)


@contextmanager
def terminate_as_interrupt() -> Iterator[None]:
    """SIGTERM and SIGHUP end a command as Ctrl-C does.

    SIGTERM: ``timeout``, a batch system's stop; SIGHUP: the terminal or ssh session closed
    (not under ``nohup``, :func:`diffdrive_odom.ros.lifetime.stop_signals`). Why: SIGTERM's
    default ends the process on the spot, so a replay's staged outputs stayed behind as
    ``.NAME.partial-PID``; as a KeyboardInterrupt they are removed on the way out and the
    exit status is 130. Only where signals can be set (the main thread); the earlier handler
    comes back afterwards.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def interrupt(signum: int, frame: object) -> None:
        raise KeyboardInterrupt

    previous = {s: signal.signal(s, interrupt) for s in stop_signals() if s != signal.SIGINT}
    try:
        yield
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)


def main(argv: Sequence[str] | None = None) -> int:
    """Dispatch to ``<module>.main(argv)``; 2 (and the reason) for a missing/unknown command."""
    args = list(sys.argv[1:] if argv is None else argv)
    if args and args[0] in ("-h", "--help"):
        print(usage())
        return 0
    if args and args[0] == "--version":
        print(f"{PROGRAM} {version()}")
        return 0
    if not args:
        print(f"{PROGRAM}: no command given\n\n{usage()}", file=sys.stderr)
        return 2
    if args[0] not in COMMANDS:
        close = difflib.get_close_matches(args[0], COMMANDS, n=1)
        hint = f"; did you mean '{close[0]}'?" if close else ""
        print(f"{PROGRAM}: unknown command '{args[0]}' (commands: {', '.join(COMMANDS)})"
              f"{hint}", file=sys.stderr)
        return 2
    once.new_command()
    try:
        with terminate_as_interrupt():
            module = importlib.import_module(COMMANDS[args[0]][0])
            return int(module.main(args[1:]) or 0)
    except KeyboardInterrupt:  # a command that did not say it (replay and the demo do)
        print(f"{PROGRAM} {args[0]}: interrupted", file=sys.stderr)
        return 130
    except ModuleNotFoundError as err:
        line = missing_text(err.name, f"{PROGRAM} {args[0]}")
        if line is None:
            raise
        print(line, file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
