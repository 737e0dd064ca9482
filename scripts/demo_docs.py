"""Write the demo's table and plot into the README and doc/tools/demo.md from a run.

Why generated: the demo runs in lockstep, so a run prints the same table to the last digit
on every run of one install; what the pages show must be that table, not one edited by
hand (and it moves whenever the odometry's rules do). Runs ``diffdrive-odom demo`` with
the given options (none: the default run, as ``make demo``), then replaces the table
between the pages' markers (the README: its header and three rows; the demo page: all
of it) and copies the plot to doc/images/trajectory.png. Prints what it changed.
Run: make demo-docs  (DEMO_ARGS are passed on, e.g. DEMO_ARGS="--domain-id 42")
"""

from __future__ import annotations

import dataclasses
import shutil
import sys
import tempfile
from pathlib import Path

from diffdrive_odom.demo import cli, interrupts, loop
from diffdrive_odom.demo.report import FIT, GYRO, NOMINAL, DemoResult

ROOT = Path(__file__).resolve().parent.parent
BEGIN = "<!-- demo table: written by `make demo-docs` from a run, do not edit -->"
END = "<!-- end of demo table -->"
README_ROWS = (NOMINAL, FIT, GYRO)


# How each page fences the table: GitHub shows the README; the docs' wide-output class
# lets the demo page's long lines scroll instead of wrapping.
README_FENCE = "```text\n"
DOCS_FENCE = "```{code-block} text\n:class: wide-output\n\n"


def block(text: str, fence: str) -> str:
    """The table as a page holds it: a fenced text block between the markers."""
    return f"{BEGIN}\n{fence}{text}\n```\n{END}"


def replace_block(page: Path, text: str, fence: str) -> bool:
    """Put ``text`` between ``page``'s markers; True if the page changed."""
    old = page.read_text(encoding="utf-8")
    start, end = old.find(BEGIN), old.find(END)
    if start < 0 or end < start:
        raise SystemExit(f"{page}: no '{BEGIN}' ... '{END}' markers")
    new = old[:start] + block(text, fence) + old[end + len(END):]
    if new != old:
        page.write_text(new, encoding="utf-8")
    return new != old


def tables(result: DemoResult) -> tuple[str, str]:
    """(the README's excerpt, the demo page's whole table), without the run's paths."""
    whole = dataclasses.replace(result, plot=None, bag=None).table()
    return "\n".join(result.grid(README_ROWS)), whole


def main(argv: list[str]) -> int:
    """Run the demo (``argv``: its options), write the pages and the plot."""
    with tempfile.TemporaryDirectory() as tmp:
        opts = cli.parse([*argv, "--output", str(Path(tmp) / "demo_output")])
        with interrupts.handled():
            result = loop.run(opts)
        readme, whole = tables(result)
        changed = [str(p.relative_to(ROOT)) for p, text, fence in (
            (ROOT / "README.md", readme, README_FENCE),
            (ROOT / "doc" / "tools" / "demo.md", whole, DOCS_FENCE))
            if replace_block(p, text, fence)]
        image = ROOT / "doc" / "images" / "trajectory.png"
        plot = opts.output / "trajectory.png"
        if plot.read_bytes() != image.read_bytes():
            shutil.copyfile(plot, image)
            changed.append(str(image.relative_to(ROOT)))
    print(whole)
    print("changed: " + (", ".join(changed) if changed else "nothing (the pages hold this run)"))
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
