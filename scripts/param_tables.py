"""Print the parameter tables (markdown) from the parameter registry.

Why: the documentation's pages render the same rows through ``doc/_ext/param_tables.py``
(both read ``settings.registry.table_rows``); this prints them for a terminal or an
issue. Run: .venv/bin/python scripts/param_tables.py [table ...]
"""

from __future__ import annotations

import sys

from diffdrive_odom.settings.registry import TABLE_HEADER, TABLES, table_rows


def rendered(name: str) -> str:
    """The markdown table for one registry entry (an unknown name raises)."""
    rows = ["| " + " | ".join(TABLE_HEADER) + " |", "|---|---|---|---|"]
    rows += [f"| `{n}` | {kind} | `{default}` | {meaning} |"
             for n, kind, default, meaning in table_rows(name)]
    return "\n".join(rows)


def main(argv: list[str]) -> int:
    for name in argv or [t.name for t in TABLES]:
        print(f"## {name}\n\n{rendered(name)}\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
