"""A ``-p`` that never reaches the node, named in one line (the node and the tools say it).

rcl puts every ``-p`` into the ``/**`` section and applies the sections that match a
node in the order they were first seen: a node-named section of a params file
(``odometry_node:``, ``/**/odometry_node:``) comes after ``/**`` and wins, and a params
file given after the ``-p`` sets ``/**`` again. The demo's own params file has
``odometry_node: {use_imu: false}``, so ``replay -p use_imu:=true`` did nothing and
said nothing. Here the resolution of :mod:`~diffdrive_odom.settings.params` is run
once more, keeping where each value came from.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

from diffdrive_odom.settings.rcl import (
    ParamSource,
    ParamValue,
    fully_qualified_name,
    node_matches,
    parse_override,
    rcl_entries,
)


def _same(a: ParamValue, b: ParamValue) -> bool:
    if isinstance(a, (list, tuple)) and isinstance(b, (list, tuple)):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b, strict=True))
    if isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b):
        return True
    return bool(type(a) is type(b) and a == b)


def shadowed_overrides_line(
    sources: Sequence[ParamSource], node_name: str, namespace: str = "/",
    settled: Mapping[str, ParamValue] | None = None,
) -> str | None:
    """One line naming each ``-p`` whose value the node does not get, and why; or None.

    ``settled``: values a tool sets after every source; a ``-p`` of the same value is
    then not lost.
    """
    fqn = fully_qualified_name(node_name, namespace)
    given: dict[str, tuple[str, ParamValue]] = {}
    for kind, item in sources:
        if kind == "param":
            name, value = parse_override(item)
            given[name] = (item, value)
    if not given:
        return None
    entries = rcl_entries(sources)
    lost: list[str] = []
    for name, (text, value) in given.items():
        winner = None
        for pattern, values in entries.items():
            if name in values and node_matches(pattern, fqn):
                winner = pattern
        if winner is None or _same(entries[winner][name], value):
            continue
        if settled and name in settled and _same(settled[name], value):
            continue
        if winner == "/**":
            lost.append(f"-p {text} (a params file after it sets {name} in '/**')")
        else:
            lost.append(f"-p {text} (the params file's section '{winner}' sets {name})")
    if not lost:
        return None
    return (f"{fqn} does not get {'; '.join(lost)}: rcl applies a node's own section after "
            "'/**', where every -p goes, and a later file after an earlier -p; set the value "
            "in that section or in a params file given last")
