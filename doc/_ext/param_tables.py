"""Sphinx directive ``param-table``: a node's parameter table, from the parameter registry.

Why: a table typed into a page drifts from what the node declares; this one is rendered at
build time from ``diffdrive_odom.settings.registry.table_rows``, the rows the shipped YAML
and the nodes' declarations come from. In a MyST page::

    ```{param-table} odometry
    ```

An unknown table name fails the build (``sphinx-build -W``) naming the known ones.
"""

from __future__ import annotations

import html
import re
from typing import Any

from docutils import nodes
from docutils.parsers.rst import Directive

from diffdrive_odom.settings.registry import TABLE_HEADER, TABLES, table_rows


class name_literal(nodes.literal):  # noqa: N801 (docutils names its node classes so)
    """A parameter name: a literal that HTML may break after ``_`` and ``.``.

    Why: names run to 44 characters (``online_calibration_reference_position_stddev``)
    and a browser breaks a word only at a space, so the name column would push the
    table past the page; ``<wbr>`` marks where a line may break and is not copied
    with the name.
    """


def visit_name_literal(translator: Any, node: name_literal) -> None:
    """``<code>`` with ``<wbr>`` after each ``_`` and ``.`` of the name."""
    parts = re.split(r"(?<=[_.])", node.astext())
    translator.body.append('<code class="docutils literal notranslate"><span class="pre">'
                           + "<wbr>".join(html.escape(p) for p in parts if p)
                           + "</span></code>")
    raise nodes.SkipNode


def visit_plain_literal(translator: Any, node: name_literal) -> None:
    """Other builders: the name as an ordinary literal."""
    translator.visit_literal(node)


def depart_plain_literal(translator: Any, node: name_literal) -> None:
    """Other builders: the ordinary literal's end."""
    translator.depart_literal(node)


def _cell(*children: nodes.Node) -> nodes.entry:
    return nodes.entry("", nodes.paragraph("", "", *children))


def _row(cells: list[nodes.entry]) -> nodes.row:
    row = nodes.row()
    row.extend(cells)
    return row


def table_node(name: str) -> nodes.table:
    """The docutils table of registry table ``name``: parameter, type, default, meaning."""
    group = nodes.tgroup(cols=len(TABLE_HEADER))
    for width in (25, 10, 15, 50):
        group += nodes.colspec(colwidth=width)
    group += nodes.thead("", _row([_cell(nodes.Text(h)) for h in TABLE_HEADER]))
    body = nodes.tbody()
    for param, kind, default, meaning in table_rows(name):
        body += _row([_cell(name_literal(param, param)), _cell(nodes.Text(kind)),
                      _cell(nodes.literal(default, default)), _cell(nodes.Text(meaning))])
    group += body
    table = nodes.table("", group, classes=["param-table"])
    table["ids"].append(f"param-table-{name}")
    return table


class ParamTable(Directive):
    """``param-table NAME``: the registry's table NAME (geometry, odometry, cmd_vel, ...)."""

    required_arguments = 1
    has_content = False

    def run(self) -> list[nodes.Node]:
        """The table, or an error naming the registry's tables (it fails the build)."""
        name = self.arguments[0]
        known = [t.name for t in TABLES]
        if name not in known:
            raise self.error(f"param-table: no table {name!r}; the registry has {known}")
        return [table_node(name)]


def setup(app: Any) -> dict[str, Any]:
    """Register the directive (Sphinx calls this for each entry of ``extensions``)."""
    app.add_directive("param-table", ParamTable)
    plain = (visit_plain_literal, depart_plain_literal)
    app.add_node(name_literal, html=(visit_name_literal, None), latex=plain, text=plain,
                 man=plain, texinfo=plain)
    return {"version": "1", "parallel_read_safe": True, "parallel_write_safe": True}
