"""settings.dependencies: its table against what the package imports and setup.py's extras.

The line a missing library gets (``missing_text``) is run as a user meets it in
test/system/test_plain_install.py; here, that the table behind it is whole: every
library the package imports is a requirement, a ROS package or in an extra the table
names, and each extra it names holds that library (as the installed distribution
declares it, from setup.py).
"""

from __future__ import annotations

import re
from importlib import metadata
from pathlib import Path

import pytest

import diffdrive_odom
from diffdrive_odom.settings import dependencies

from importscan import ament_packages, imported_names, tops

REQUIRED = {"numpy": "numpy", "yaml": "pyyaml"}  # install_requires: module -> distribution


def _imported() -> dict[str, str]:
    """Each third-party top-level module the package imports -> a file importing it."""
    package = Path(diffdrive_odom.__file__).parent
    found: dict[str, str] = {}
    for path in sorted(package.rglob("*.py")):
        for top in tops(imported_names(path)[0]):
            found.setdefault(top, path.name)
    return found


def _name(requirement: str) -> str:
    """A requirement's distribution name, normalised (PEP 503)."""
    name = re.match(r"[A-Za-z0-9._-]+", requirement)
    assert name is not None, requirement
    return re.sub(r"[-_.]+", "-", name.group(0)).lower()


def _distributions(module: str) -> set[str]:
    return {_name(d) for d in metadata.packages_distributions().get(module, [])}


def test_every_library_the_package_imports_is_required_ros_or_in_an_extra() -> None:
    imported = _imported()
    assert {"rclpy", "numpy", "rosbags", "scipy", "matplotlib"} <= set(imported), imported
    unplaced = {m: f for m, f in imported.items()
                if m not in REQUIRED and m not in ament_packages()
                and m not in dependencies.EXTRAS and m not in dependencies.ROS_PACKAGES}
    assert not unplaced, f"imported, but no requirement, ROS package or extra: {unplaced}"


def test_install_requires_are_what_the_nodes_need_besides_ros() -> None:
    requires = [r for r in metadata.requires(dependencies.DISTRIBUTION) or []
                if "extra ==" not in r]
    assert sorted(_name(r) for r in requires) == sorted(REQUIRED.values())  # no setuptools


@pytest.mark.parametrize("module", sorted(dependencies.EXTRAS))
def test_the_extra_the_table_names_holds_the_library(module: str) -> None:
    extra = dependencies.EXTRAS[module]
    declared = {_name(r.partition(";")[0]) for r in metadata.requires(dependencies.DISTRIBUTION)
                or [] if re.search(rf"""extra\s*==\s*["']{extra}["']""", r)}
    assert _distributions(module) & declared, (module, extra, declared)


def test_the_line_names_the_extra_and_its_libraries_or_the_extra_alone(
        monkeypatch: pytest.MonkeyPatch) -> None:
    line = dependencies.missing_text("scipy.optimize", "diffdrive-odom calibrate")
    assert line == ("diffdrive-odom calibrate needs scipy: pip install 'diffdrive_odom[tools]' "
                    "(or its libraries alone: pip install 'rosbags<0.12,>=0.11.9' orjson "
                    "matplotlib scipy threadpoolctl)")
    assert dependencies.missing_text("sympy", "x") is None  # not an optional library
    monkeypatch.setattr(dependencies, "DISTRIBUTION", "diffdrive_odom_never_installed")
    assert dependencies.missing_text("scipy", "x") == (
        "x needs scipy: pip install 'diffdrive_odom_never_installed[tools]'")
