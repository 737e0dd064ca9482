"""``colcon test`` runs this package's suite as pytest on the colcon build.

colcon picks pytest because setup.py's ``test`` extra names it; the suite then runs
from the workspace's copy with the package as colcon installed it. A fast subset here
(pure tests; the workspace has no recorded bags), the whole suite being ``make test``'s.
"""

from __future__ import annotations

import os
import subprocess
import xml.etree.ElementTree as ElementTree
from pathlib import Path

import pytest

from rosutil import BIN

pytestmark = [pytest.mark.process, pytest.mark.launch, pytest.mark.xdist_group("colcon")]

SUBSET = "test_se2 or test_integration or test_stamp_rules"


def test_colcon_test_runs_the_suite_with_pytest(colcon_ws: Path) -> None:
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "AMENT_PREFIX_PATH")}
    env["PATH"] = f"{BIN}:{env.get('PATH', '')}"
    done = subprocess.run(
        [str(BIN / "colcon"), "test", "--packages-select", "diffdrive_odom",
         "--return-code-on-test-failure", "--event-handlers", "console_direct+",
         "--pytest-args", "-q", "-p", "no:cacheprovider", "-m",
         "not dds and not process and not slow", "-k", SUBSET],
        cwd=colcon_ws, capture_output=True, text=True, env=env, timeout=300)
    assert done.returncode == 0, done.stdout + done.stderr
    report = ElementTree.parse(colcon_ws / "build" / "diffdrive_odom" / "pytest.xml")
    suite = report.getroot()
    suite = suite if suite.tag == "testsuite" else suite.find("testsuite")  # type: ignore[assignment]
    assert suite is not None
    tests, failures = int(suite.get("tests", "0")), int(suite.get("failures", "0"))
    assert tests >= 50 and failures == 0 and int(suite.get("errors", "0")) == 0, (tests, failures)
    names = {case.get("classname", "") for case in suite.iter("testcase")}
    assert any("test_stamp_rules" in n for n in names), sorted(names)[:5]
