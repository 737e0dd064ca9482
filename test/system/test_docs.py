"""The README's parameter tables and the shipped YAML say what the code declares."""

from __future__ import annotations

import importlib.util
import subprocess
import sys
from pathlib import Path

import pytest

from diffdrive_odom.settings.registry import TABLES

from rosutil import ROOT


def _script(name: str) -> object:
    spec = importlib.util.spec_from_file_location(name, ROOT / "scripts" / f"{name}.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_readme_parameter_tables_are_current() -> None:
    tables = _script("param_tables")
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    for name in (t.name for t in TABLES):
        body = tables.rendered(name)  # type: ignore[attr-defined]
        assert f"<!-- {name} -->\n{body}\n" in readme, (
            f"README table '{name}' is stale: run scripts/param_tables.py --update-readme")


@pytest.mark.process
def test_shipped_yaml_is_current() -> None:
    out = subprocess.run([sys.executable, str(ROOT / "scripts" / "gen_config.py")],
                         capture_output=True, text=True, check=True)
    shipped = (ROOT / "config" / "diffdrive_odom.yaml").read_text(encoding="utf-8")
    assert out.stdout == shipped, "config is stale: run scripts/gen_config.py"


def test_readme_starts_with_the_two_commands() -> None:
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    first_block = readme.split("```bash\n", 1)[1].split("```", 1)[0]
    commands = [ln.split("#")[0].strip() for ln in first_block.splitlines() if ln.strip()]
    assert commands == ["make demo", "make test"]
    assert Path(ROOT / "Makefile").read_text(encoding="utf-8").count("\ndemo:") == 1
