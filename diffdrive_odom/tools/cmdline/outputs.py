"""The tools' output files: checked before the work, written under their name only at the end.

Pure standard library (no bag library), so the argument checks of every command and
the demo's output directory work on an install without the ``tools`` extra.
"""

from __future__ import annotations

import os
import re
import shutil
import stat
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from diffdrive_odom.ros.lifetime import pid_exists

STORAGES = ("mcap", "sqlite3")  # rosbag2 storages an output bag can be written in


def output_problem(path: str | Path, flag: str) -> str | None:
    """Why ``path`` cannot be written (one line naming ``flag``), or None.

    Checked before the work starts, so a long replay does not end in a traceback
    over a typo in ``--plot``.
    """
    named = Path(path)
    p = through_link(named)
    parent = p.parent if str(p.parent) else Path(".")
    if p.is_dir():
        return f"{flag} {named}: is a directory"
    if written_in_place(p):
        return None if os.access(p, os.W_OK) else f"{flag} {named}: not writable"
    if not parent.is_dir():
        return f"{flag} {named}: directory {parent} does not exist"
    if not os.access(parent, os.W_OK | os.X_OK) or (p.exists() and not os.access(p, os.W_OK)):
        return f"{flag} {named}: not writable"
    return None


def through_link(path: Path) -> Path:
    """Where writing ``path`` goes: a symlink's target, else ``path`` itself.

    The link is followed to its end, the target existing or not. A shell's ``>`` writes
    through a link and leaves it a link; so does a tool's output, staged beside the
    target and renamed over it, not over the link.
    """
    return Path(os.path.realpath(path)) if path.is_symlink() else path


@contextmanager
def staged(path: str | Path) -> Iterator[Path]:
    """Where to write ``path``: its name in a hidden sibling directory, moved on success.

    A device, FIFO or socket is written in place (:func:`written_in_place`); a symlink is
    written through (:func:`through_link`).

    On any exception (Ctrl-C included) the staging directory is removed, so a failed
    run never leaves a half-written output under the name the user asked for. Same
    file system, so the move is a rename; same name, so a bag's storage file inside
    (``NAME_0.mcap``) is named as if written in place. A directory already at ``path``
    is replaced only if empty (``os.replace``'s rule); the caller decides before. A run
    killed outright (SIGKILL, power) cannot remove its staging directory: the next run
    for the same output removes it (:func:`remove_stale_stages`) and says so.
    """
    final = through_link(Path(path))
    if written_in_place(final):
        yield final
        return
    for line in remove_stale_stages(final):
        print(line, file=sys.stderr)
    stage = final.parent / f".{final.name}.partial-{os.getpid()}"
    stage.mkdir()
    try:
        yield stage / final.name
        os.replace(stage / final.name, final)
    finally:
        shutil.rmtree(stage, ignore_errors=True)


def written_in_place(path: Path) -> bool:
    """Whether ``path`` is a device, a FIFO or a socket (``--csv /dev/null``, a named pipe).

    Such an output is written where it is: there is no half-written file to hide, and a
    staged one would be renamed over it (run as root, ``--csv /dev/null`` replaced the
    machine's /dev/null with a regular file) or need a writable /dev.
    """
    try:
        mode = path.stat().st_mode
    except OSError:
        return False
    return not (stat.S_ISREG(mode) or stat.S_ISDIR(mode))


def remove_stale_stages(final: Path) -> list[str]:
    """Remove the staging directories of ``final`` whose process is gone; one line each.

    ``.NAME.partial-PID`` is hidden: a run killed before it could clean up left it there,
    out of sight, holding what it had written. Only its own process writes into it, so
    once that process is gone it is removed.
    """
    pattern = re.compile(rf"\.{re.escape(final.name)}\.partial-(\d+)")
    parent = final.parent if str(final.parent) else Path(".")
    said: list[str] = []
    try:
        entries = sorted(parent.iterdir())
    except OSError:
        return said
    for entry in entries:
        found = pattern.fullmatch(entry.name)
        if not found or not entry.is_dir() or pid_exists(int(found.group(1))):
            continue
        shutil.rmtree(entry, ignore_errors=True)
        said.append(f"removed {entry}: the partial output of an earlier run for {final} "
                    f"that was stopped before it could clean up (process "
                    f"{found.group(1)} is gone)")
    return said
