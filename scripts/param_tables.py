"""Print the README's parameter tables (markdown) from the spec tables.

Why: the README must match what the code declares; test_docs.py checks every
parameter appears there. Run: .venv/bin/python scripts/param_tables.py [table ...]
"""

from __future__ import annotations

import importlib
import sys

from diffdrive_odom.params import ParamSpec, yaml_text

TABLES = {
    "geometry": ("diffdrive_odom.params", "GEOMETRY_PARAMS"),
    "odometry": ("diffdrive_odom.params", "ODOMETRY_PARAMS"),
    "cmd_vel": ("diffdrive_odom.cmd_vel_settings", "CMD_VEL_PARAMS"),
    "sim": ("diffdrive_odom.sim_node", "SIM_PARAMS"),
}


def table(specs: tuple[ParamSpec, ...], skip: tuple[ParamSpec, ...] = ()) -> str:
    rows = ["| parameter | type | default | meaning |", "|---|---|---|---|"]
    for s in specs:
        if s in skip:
            continue
        default = yaml_text(s.default)
        rows.append(f"| `{s.name}` | {s.kind} | `{default}` | {s.description} |")
    return "\n".join(rows)


def main(argv: list[str]) -> int:
    from diffdrive_odom.params import GEOMETRY_PARAMS

    for name in argv or list(TABLES):
        module, attr = TABLES[name]
        try:
            specs = getattr(importlib.import_module(module), attr)
        except (ImportError, AttributeError) as err:
            print(f"<!-- {name}: {err} -->")
            continue
        skip = GEOMETRY_PARAMS if name != "geometry" else ()
        print(f"<!-- {name} -->\n{table(tuple(specs), skip)}\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
