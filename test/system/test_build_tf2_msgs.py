"""scripts/build_tf2_msgs.sh on the CMake exports of every Python's ROS wheels.

The wheels' CMake files carry the wheel builder's interpreter paths, one per Python
(``/opt/python/cp311-cp311/...`` in the 3.11 wheels, ``cp312-cp312`` in the 3.12 ones):
the script points them at the venv's. On 3.12 it used to look for cp311 only, find
nothing and end silently (``set -e`` on grep's exit status): ``make demo`` printed
``Error 1`` and nothing else. Here the venv is a stand-in whose ``python`` answers the
script's questions (tf2_msgs missing, pip a no-op, the include paths) and which has no
cmake, so the script stops right after the rewrite; it must say why, whatever stops it.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from paths import ROOT

pytestmark = [pytest.mark.process]

SCRIPT = ROOT / "scripts" / "build_tf2_msgs.sh"
PYINC, NPINC = "/venv/include/python3.X", "/venv/site-packages/numpy/_core/include"

EXPORT = ('set(_exported_include_dirs "{builder}/include/python{v};'
          '{builder}/lib/python{v}/site-packages/numpy/_core/include")\n')


def fake_venv(tmp_path: Path) -> Path:
    venv = tmp_path / "venv"
    (venv / "bin").mkdir(parents=True)
    (venv / "share" / "rosidl_generator_py" / "cmake").mkdir(parents=True)
    python = venv / "bin" / "python"
    python.write_text(f"""#!/bin/bash
case "$*" in
  *"import tf2_msgs"*) exit 1 ;;
  "-m pip"*) exit 0 ;;
  *sysconfig*) echo {PYINC} ;;
  *numpy*) echo {NPINC} ;;
  *) exec {sys.executable} "$@" ;;
esac
""")
    python.chmod(0o755)
    return venv


def run(venv: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run(["bash", str(SCRIPT), str(venv)], capture_output=True, text=True,
                          timeout=60, check=False)


@pytest.mark.parametrize("version", ["3.10", "3.11", "3.12"])
def test_the_builder_paths_of_every_python_are_rewritten(tmp_path: Path, version: str) -> None:
    venv = fake_venv(tmp_path)
    tag = "cp" + version.replace(".", "")
    export = venv / "share" / "rosidl_generator_py" / "cmake" / "export.cmake"
    export.write_text(EXPORT.format(builder=f"/opt/python/{tag}-{tag}", v=version))
    done = run(venv)
    assert export.read_text() == f'set(_exported_include_dirs "{PYINC};{NPINC}")\n'
    # No cmake in the stand-in: it stops there, and says where.
    assert done.returncode != 0
    assert "build_tf2_msgs.sh: configuring tf2_msgs failed" in done.stderr
    assert "bin/cmake" in done.stderr


def test_a_builder_path_it_cannot_rewrite_is_named(tmp_path: Path) -> None:
    venv = fake_venv(tmp_path)
    export = venv / "share" / "rosidl_generator_py" / "cmake" / "export.cmake"
    export.write_text('set(_dirs "/opt/python/cp313-cp313/lib/libpython3.13.so")\n')
    done = run(venv)
    assert done.returncode == 1
    assert "build paths this script does not know how to replace" in done.stderr
    assert "/opt/python/cp313-cp313/lib/libpython3.13.so" in done.stderr
