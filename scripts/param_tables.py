"""Print the README's parameter tables (markdown) from the spec tables.

Why: the README must match what the code declares; test_docs.py checks every
parameter appears there. Run: .venv/bin/python scripts/param_tables.py [--update-readme | table ...]
"""

from __future__ import annotations

import importlib
import re
import sys
from collections.abc import Callable
from pathlib import Path

from diffdrive_odom.params import ParamSpec, yaml_text

TABLES = {
    "geometry": ("diffdrive_odom.geometry_settings", "GEOMETRY_PARAMS"),
    "odometry": ("diffdrive_odom.odometry_settings", "ODOMETRY_PARAMS"),
    "cmd_vel": ("diffdrive_odom.cmd_vel_settings", "CMD_VEL_PARAMS"),
    "sim": ("diffdrive_odom.sim_settings", "SIM_PARAMS"),
    "follower": ("diffdrive_odom.follower_settings", "FOLLOWER_PARAMS"),
}


def table(specs: tuple[ParamSpec, ...], skip: tuple[ParamSpec, ...] = ()) -> str:
    rows = ["| parameter | type | default | meaning |", "|---|---|---|---|"]
    for s in specs:
        if s in skip:
            continue
        default = yaml_text(s.default)
        rows.append(f"| `{s.name}` | {s.kind} | `{default}` | {s.description} |")
    return "\n".join(rows)


def rendered(name: str) -> str:
    """The markdown table for one entry of TABLES (a missing module or table raises)."""
    from diffdrive_odom.geometry_settings import GEOMETRY_PARAMS

    module, attr = TABLES[name]
    specs = getattr(importlib.import_module(module), attr)
    skip = GEOMETRY_PARAMS if name != "geometry" else ()
    if name == "follower":  # the cmd_vel node's row, listed in its table
        skip += tuple(s for s in specs if s.name == "enable_stamped_cmd_vel")
    return table(tuple(specs), skip)


def _replacement(body: str) -> Callable[[re.Match[str]], str]:
    return lambda m: m.group(1) + body + "\n"


def update_readme(path: Path) -> None:
    """Replace each ``<!-- name -->`` table in the README with the current one."""
    text = path.read_text(encoding="utf-8")
    for name in TABLES:
        body = rendered(name)
        pattern = re.compile(rf"(<!-- {name} -->\n)(\|.*\|\n)+")
        text = pattern.sub(_replacement(body), text)
    path.write_text(text, encoding="utf-8")


def main(argv: list[str]) -> int:
    if argv[:1] == ["--update-readme"]:
        update_readme(Path(__file__).resolve().parent.parent / "README.md")
        return 0
    for name in argv or list(TABLES):
        print(f"<!-- {name} -->\n{rendered(name)}\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
