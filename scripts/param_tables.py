"""Print the README's parameter tables (markdown) from the spec tables.

Why: the README must match what the code declares; test_docs.py checks every
parameter appears there. Run: .venv/bin/python scripts/param_tables.py [--update-readme | table ...]
"""

from __future__ import annotations

import re
import sys
from collections.abc import Callable
from pathlib import Path

from diffdrive_odom.settings.params import ParamSpec, yaml_text
from diffdrive_odom.settings.registry import TABLES
from diffdrive_odom.settings.registry import table as registry_table


def table(specs: tuple[ParamSpec, ...]) -> str:
    rows = ["| parameter | type | default | meaning |", "|---|---|---|---|"]
    for s in specs:
        default = yaml_text(s.default)
        rows.append(f"| `{s.name}` | {s.kind} | `{default}` | {s.description} |")
    return "\n".join(rows)


def rendered(name: str) -> str:
    """The markdown table for one registry entry (an unknown name raises)."""
    return table(registry_table(name).own)


def _replacement(body: str) -> Callable[[re.Match[str]], str]:
    return lambda m: m.group(1) + body + "\n"


def update_readme(path: Path) -> None:
    """Replace each ``<!-- name -->`` table in the README with the current one."""
    text = path.read_text(encoding="utf-8")
    for name in (t.name for t in TABLES):
        body = rendered(name)
        pattern = re.compile(rf"(<!-- {name} -->\n)(\|.*\|\n)+")
        text = pattern.sub(_replacement(body), text)
    path.write_text(text, encoding="utf-8")


def main(argv: list[str]) -> int:
    if argv[:1] == ["--update-readme"]:
        update_readme(Path(__file__).resolve().parent.parent / "README.md")
        return 0
    for name in argv or [t.name for t in TABLES]:
        print(f"<!-- {name} -->\n{rendered(name)}\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
