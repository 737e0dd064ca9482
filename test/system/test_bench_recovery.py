"""The recovery bench still runs: ``--quick`` exits 0 and prints both rows.

Figures are not checked (they depend on the machine); the counts are: the torn copy
gives fewer messages than the intact recording, and the same in both rows.
"""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from rosutil import ROOT

pytestmark = [pytest.mark.process]


def test_recovery_bench_prints_both_rows() -> None:
    proc = subprocess.run([sys.executable, str(ROOT / "bench" / "bench_recovery.py"),
                           "--quick"], capture_output=True, text=True, timeout=300,
                          cwd=ROOT, env=dict(os.environ))
    assert proc.returncode == 0, proc.stdout + proc.stderr
    rows = {line.split()[0]: line.split()[-2:] for line in proc.stdout.splitlines()
            if line.startswith(("messages", "joint"))}
    assert set(rows) == {"messages", "joint"}
    (intact, torn), again = rows["messages"], rows["joint"]
    assert 0 < int(torn) < int(intact) and again == [intact, torn]
