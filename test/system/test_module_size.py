"""The 450-line rule: no product module under ``diffdrive_odom/`` is longer.

Why a test: a module past that length has usually taken on a second concern (issue 23:
``tools/bagio.py`` had grown six jobs, ``core/cdr.py`` three); the developers' guide
stated the rule and nothing checked it, so it was broken unseen. The cure is a split by
concern, not by line count. The package is found by import, so the rule holds wherever
the tests run from (a checkout, a colcon install).
"""

from __future__ import annotations

from pathlib import Path

import diffdrive_odom

LIMIT = 450  # lines a product module may have


def oversized(package: Path, limit: int = LIMIT) -> dict[str, int]:
    """Every ``.py`` file below ``package`` longer than ``limit`` lines, with its length.

    Keys are paths from the package's parent (``diffdrive_odom/tools/replay.py``); a
    last line without its newline counts, as an editor shows it.
    """
    found = {}
    for path in sorted(package.rglob("*.py")):
        with path.open(encoding="utf-8") as text:
            lines = sum(1 for _ in text)
        if lines > limit:
            found[path.relative_to(package.parent).as_posix()] = lines
    return found


def test_no_product_module_is_over_450_lines() -> None:
    package = Path(diffdrive_odom.__file__).parent
    # The walk sees the whole package: every layer, sub-packages included.
    walked = {p.relative_to(package).parts[0] for p in package.rglob("*.py")}
    assert {"core", "wire", "settings", "ros", "tools", "demo"} <= walked
    too_long = oversized(package)
    assert not too_long, f"over {LIMIT} lines (split it by concern): " + ", ".join(
        f"{path} ({lines})" for path, lines in too_long.items())


def test_the_rule_names_each_file_over_the_limit(tmp_path: Path) -> None:
    """The check really checks: each long file is named, at any depth; nothing else."""
    package = tmp_path / "pkg"
    (package / "sub").mkdir(parents=True)
    (package / "at_limit.py").write_text("x = 1\n" * LIMIT)
    (package / "over.py").write_text("x = 1\n" * (LIMIT + 100))
    (package / "sub" / "one_over.py").write_text("x = 1\n" * LIMIT + "x = 2")  # no last \n
    (package / "notes.txt").write_text("words\n" * 1000)  # not Python
    assert oversized(package) == {"pkg/over.py": LIMIT + 100, "pkg/sub/one_over.py": LIMIT + 1}
