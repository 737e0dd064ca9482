"""Every node's parameter table, listed once.

The unknown-name check, the documentation's tables (``doc/_ext/param_tables.py``, through
:func:`table_rows`) and the shipped YAML (``scripts/gen_config.py``) all read
:data:`TABLES`, so a new node or parameter is
added in one place. The shipped YAML holds every parameter of every node (the sim's too)
under one ``/**`` section, so a name several nodes declare is written once and must mean
the same to each of them (``test_params`` checks which names are shared).
"""

from __future__ import annotations

import difflib
from collections.abc import Iterable
from dataclasses import dataclass
from functools import cache

from diffdrive_odom.settings.cmd_vel import CMD_VEL_OWN_PARAMS, CMD_VEL_PARAMS
from diffdrive_odom.settings.follower import FOLLOWER_OWN_PARAMS, FOLLOWER_PARAMS
from diffdrive_odom.settings.geometry import GEOMETRY_PARAMS
from diffdrive_odom.settings.odometry import ODOMETRY_OWN_PARAMS, ODOMETRY_PARAMS
from diffdrive_odom.settings.params import ParamSpec, yaml_text
from diffdrive_odom.settings.sim import SIM_PARAMS


@dataclass(frozen=True)
class Table:
    """One parameter table: its name in the docs, its YAML title, its rows."""

    name: str  # what the docs' ``param-table`` directive names
    title: str  # the group's heading in the shipped YAML
    own: tuple[ParamSpec, ...]  # rows listed in this table (shared rows are listed once)
    declared: tuple[ParamSpec, ...]  # everything the node(s) declare


TABLES: tuple[Table, ...] = (
    Table("geometry", "geometry and joints: odometry_node and cmd_vel_node",
          GEOMETRY_PARAMS, GEOMETRY_PARAMS),
    Table("odometry", "odometry_node", ODOMETRY_OWN_PARAMS, ODOMETRY_PARAMS),
    Table("cmd_vel", "cmd_vel_node", CMD_VEL_OWN_PARAMS, CMD_VEL_PARAMS),
    # The sim's rows that equal a geometry row are listed there, once.
    Table("sim", "sim_node (its nominal geometry, joints and base_frame_id: the rows above)",
          tuple(s for s in SIM_PARAMS if s not in GEOMETRY_PARAMS), SIM_PARAMS),
    Table("follower",
          "path_follower_node (geometry and enable_stamped_cmd_vel: shared rows above)",
          FOLLOWER_OWN_PARAMS, FOLLOWER_PARAMS),
)


def table(name: str) -> Table:
    """The table named ``name`` (StopIteration for an unknown one)."""
    return next(t for t in TABLES if t.name == name)


TABLE_HEADER = ("parameter", "type", "default", "meaning")


def table_rows(name: str) -> tuple[tuple[str, str, str, str], ...]:
    """The rows the docs print for table ``name``: name, type, default (YAML text), meaning.

    One function for every rendering (the Sphinx directive, ``scripts/param_tables.py``),
    so a page shows what the node declares and the default as the shipped YAML writes it.
    """
    return tuple((s.name, s.kind, yaml_text(s.default), s.description)
                 for s in table(name).own)


def config_groups() -> tuple[tuple[str, tuple[ParamSpec, ...]], ...]:
    """(title, rows) of the shipped YAML: every table's rows, each name once (first table wins).

    One ``/**`` section cannot hold a name twice; the sim's rows that share a name with a
    geometry row (its nominal radius, its joints) differ from it only in default and
    wording, so the geometry row is written and the sim reads the same value.
    """
    written: set[str] = set()
    groups = []
    for t in TABLES:
        rows = tuple(s for s in t.own if s.name not in written)
        written.update(s.name for s in rows)
        groups.append((t.title, rows))
    return tuple(groups)


# ------------------------------------------------------------ unknown names

# diff_drive_controller parameters that have no meaning for these nodes: a ddc file
# is welcome, these are named once at start as ignored instead of warned about.
DDC_IGNORED: tuple[str, ...] = (
    "position_feedback",  # positions are used when present, else velocities
    "wheels_per_side",  # the wheel name lists say it
    "use_stamped_vel",  # Humble's name; enable_stamped_cmd_vel selects the type here
)
# Names rclpy itself declares or reads on every node.
_RCLPY_NAMES = ("use_sim_time", "start_type_description_service")
_RCLPY_PREFIXES = ("qos_overrides.",)


@cache
def known_names() -> frozenset[str]:
    """Every parameter some node of this package declares, plus rclpy's own.

    One params file feeds every node, so a name is only suspicious when no node
    knows it (the cmd_vel node must not warn about the odometry node's names).
    """
    return frozenset(s.name for t in TABLES for s in t.declared) | frozenset(_RCLPY_NAMES)


# The node each table (other than the shared geometry rows) belongs to.
_NODES = {"odometry": "odometry_node", "cmd_vel": "cmd_vel_node", "sim": "sim_node",
          "follower": "path_follower_node"}


# robot_localization's names for what diff_drive_controller, and so this package, names
# otherwise (a difflib match would take publish_tf for publish_rate).
ROBOT_LOCALIZATION_NAMES = {"publish_tf": "enable_odom_tf", "odom_frame": "odom_frame_id",
                            "base_link_frame": "base_frame_id"}


def did_you_mean(name: str, candidates: Iterable[str]) -> str:
    """``did you mean X?`` for the candidate ``name`` most likely stands for, else "".

    robot_localization's name for one of ours (said so), else the closest spelling
    (difflib, ratio >= 0.6: a typo).
    """
    known = sorted(candidates)
    ours = ROBOT_LOCALIZATION_NAMES.get(name)
    if ours in known:
        return (f"did you mean {ours}? {name} is robot_localization's name, {ours} "
                "diff_drive_controller's and this package's")
    close = difflib.get_close_matches(name, known, n=1, cutoff=0.6)
    return f"did you mean {close[0]}?" if close else ""


def unknown_name_hint(name: str, declared: Iterable[str]) -> str:
    """Why a node declaring ``declared`` has no ``name`` ("" when no reason is known).

    The name it most likely stands for (:func:`did_you_mean`), else the nodes of this
    package that have it.
    """
    hint = did_you_mean(name, declared)
    if hint:
        return hint
    owners = sorted(node for key, node in _NODES.items()
                    if any(s.name == name for s in table(key).declared))
    return f"a parameter of {' and '.join(owners)}" if owners else ""


def unknown_parameters_report(names: Iterable[str]) -> tuple[str | None, str | None]:
    """Return (warning, info) lines about parameter names given to a node.

    The warning names unknown ones with the closest real name (typos); the info line
    names diff_drive_controller parameters that mean nothing here.
    """
    known = known_names()
    ddc = [n for n in names if n in DDC_IGNORED and n not in known]
    unknown = sorted(
        n for n in names
        if n not in known and n not in DDC_IGNORED and not n.startswith(_RCLPY_PREFIXES))
    warning = info = None
    if unknown:
        hints = []
        for name in unknown:
            hint = did_you_mean(name, known)
            hints.append(f"{name} ({hint})" if hint else name)
        warning = ("unknown parameters, no diffdrive_odom node uses them (ignored): "
                   + ", ".join(hints))
    if ddc:
        info = ("diff_drive_controller parameters with no meaning here (ignored): "
                + ", ".join(sorted(ddc)))
    return warning, info
