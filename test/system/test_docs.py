"""The documentation (doc/, README.md) and the shipped YAML say what the code declares.

The parameter tables on the pages are rendered from the registry at build time
(``doc/_ext/param_tables.py``): checked here are that every table is placed on its
node's page, that the directive renders exactly the declared rows, that the pages name
each node's topics, that every core module has its API page, and that ``make docs``'s
build (``sphinx-build -W -n``: warnings, broken links and anchors fail) passes.
"""

from __future__ import annotations

import importlib.util
import re
import shutil
import subprocess
import sys
from pathlib import Path
from types import ModuleType

import pytest

from diffdrive_odom.settings.params import yaml_text
from diffdrive_odom.settings.registry import TABLES, table

from rosutil import ROOT

DOC = ROOT / "doc"
# Each node's page and the registry tables it shows (its own, then rows it shares).
NODE_TABLES = {
    "odometry_node": ("geometry", "odometry"),
    "cmd_vel_node": ("cmd_vel", "geometry"),
    "sim_node": ("sim",),
    "path_follower_node": ("follower",),
}
# The topics and services each node's page lists (what its --help prints: test_cli.py).
NODE_TOPICS = {
    "odometry_node": ("joint_states", "imu", "odom", "/tf", "/diagnostics",
                      "~/reset_odometry", "~/set_pose", "~/geometry_estimate"),
    "cmd_vel_node": ("cmd_vel", "wheel_commands", "cmd_vel_out"),
    "sim_node": ("wheel_commands", "joint_states", "ground_truth/odom", "/clock", "imu",
                 "/diagnostics"),
    "path_follower_node": ("odom", "path", "cmd_vel", "~/cross_track_error", "~/progress",
                           "~/done", "/diagnostics"),
}
DIRECTIVE = re.compile(r"^```\{param-table\} (\S+)\s*$", re.MULTILINE)


def _pages() -> dict[str, str]:
    """Every page Sphinx builds (doc/incoming holds drafts and is not built)."""
    return {p.relative_to(DOC).as_posix(): p.read_text(encoding="utf-8")
            for p in sorted(DOC.rglob("*")) if p.suffix in (".md", ".rst")
            and not p.relative_to(DOC).as_posix().startswith(("incoming/", "_build/"))}


def _extension() -> ModuleType:
    pytest.importorskip("docutils")
    spec = importlib.util.spec_from_file_location("param_tables", DOC / "_ext" / "param_tables.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_every_parameter_table_is_on_its_node_page() -> None:
    placed = {page: DIRECTIVE.findall(text) for page, text in _pages().items()}
    for node, names in NODE_TABLES.items():
        assert tuple(placed[f"nodes/{node}.md"]) == names, node
    everywhere = {name for names in placed.values() for name in names}
    assert everywhere == {t.name for t in TABLES}, "a registry table on no page, or an unknown one"


def test_param_table_directive_renders_the_declared_rows() -> None:
    from docutils import nodes

    ext = _extension()
    for t in TABLES:
        rendered = ext.table_node(t.name)  # type: ignore[attr-defined]
        rows = [[cell.astext() for cell in row.findall(nodes.entry)]
                for row in rendered.findall(nodes.row)]
        assert rows[0] == ["parameter", "type", "default", "meaning"]
        assert rows[1:] == [[s.name, s.kind, yaml_text(s.default), s.description]
                            for s in table(t.name).own], t.name


def test_node_pages_list_their_topics() -> None:
    pages = _pages()
    for node, topics in NODE_TOPICS.items():
        section = pages[f"nodes/{node}.md"].split("\n## Topics", 1)[1].split("\n## ", 1)[0]
        for topic in topics:
            assert f"| `{topic}`" in section, (node, topic)


def test_every_core_module_has_an_api_page() -> None:
    api = "\n".join(text for page, text in _pages().items() if page.startswith("api/"))
    for path in sorted((ROOT / "diffdrive_odom" / "core").rglob("*.py")):
        parts = path.relative_to(ROOT).with_suffix("").parts
        module = ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
        if parts[-1] != "__init__" or module.count(".") == 2:
            assert f".. automodule:: {module}\n" in api, module


def test_conf_finds_the_package_from_rosdoc2s_copy(tmp_path: Path,
                                                   monkeypatch: pytest.MonkeyPatch) -> None:
    """rosdoc2 runs its own conf.py in a build folder that exec's doc/conf.py by path."""
    monkeypatch.setattr(sys, "path", list(sys.path))
    conf = (DOC / "conf.py").resolve()
    wrapper = tmp_path / "conf.py"
    wrapper.write_text(f'exec(open("{conf}").read())\n', encoding="utf-8")
    namespace: dict[str, object] = {"__file__": str(wrapper)}
    exec(compile(wrapper.read_text(encoding="utf-8"), str(wrapper), "exec"), namespace)
    assert namespace["ROOT"] == ROOT.resolve()
    assert namespace["release"] and str(ROOT.resolve()) in sys.path
    assert "incoming" in namespace["exclude_patterns"]  # type: ignore[operator]


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


def test_readme_is_short_and_its_links_resolve() -> None:
    """Sphinx checks the pages' links; the README's (GitHub renders it) are checked here."""
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    assert len(readme.splitlines()) <= 220, "the manual is doc/: move the detail there"
    anchors = {re.sub(r"[^a-z0-9 _-]", "", h.lower()).replace(" ", "-")
               for h in re.findall(r"^#+ (.+)$", readme, re.MULTILINE)}
    for target in re.findall(r"\]\(([^)\s]+)\)", readme):
        path, _, anchor = target.partition("#")
        if path.startswith(("http://", "https://")):
            continue
        if path:
            assert (ROOT / path).exists(), target
        else:
            assert anchor in anchors, target
    assert not (ROOT / "docs").exists(), "the images and references live in doc/"


def _parity_table(text: str) -> list[str]:
    rows = text.split("| | diff_drive_controller | diffdrive_odom |", 1)[1].split("\n\n", 1)[0]
    return [re.sub(r"\]\((?:\.\./)*(?:doc/)?", "](", row) for row in rows.splitlines()]


def test_readme_and_ddc_page_show_one_parity_table() -> None:
    """The README's table against diff_drive_controller is the ddc page's, row for row."""
    readme = _parity_table((ROOT / "README.md").read_text(encoding="utf-8"))
    page = _parity_table((DOC / "ddc.md").read_text(encoding="utf-8"))
    assert readme == page and len(page) >= 10


@pytest.fixture(scope="module")
def built(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """`make docs`'s build, on a copy of doc/ with a broken draft in doc/incoming: its html."""
    pytest.importorskip("sphinx")
    pytest.importorskip("myst_parser")
    tmp_path = tmp_path_factory.mktemp("docs")
    src = tmp_path / "doc"
    shutil.copytree(DOC, src, ignore=shutil.ignore_patterns("_build"))
    shutil.copy(ROOT / "package.xml", tmp_path / "package.xml")
    (src / "incoming").mkdir(exist_ok=True)
    (src / "incoming" / "draft.md").write_text("# Draft\n\n[broken](nowhere.md#nothing)\n")
    out = tmp_path / "html"
    done = subprocess.run(
        [sys.executable, "-m", "sphinx", "-W", "--keep-going", "-n", "-E", "-q", "-b", "html",
         str(src), str(out)], capture_output=True, text=True, timeout=240, cwd=ROOT)
    assert done.returncode == 0, done.stdout + done.stderr
    return out


@pytest.mark.slow
@pytest.mark.process
def test_docs_build_with_warnings_as_errors(built: Path) -> None:
    out = built
    assert not (out / "incoming").exists()
    for node, names in NODE_TABLES.items():
        # A name may break after its underscores (<wbr>, param_tables.py).
        html = (out / "nodes" / f"{node}.html").read_text(encoding="utf-8").replace("<wbr>", "")
        for name in names:
            for spec in table(name).own:
                assert f">{spec.name}<" in html, (node, spec.name)
    assert (out / "_images" / "trajectory.png").is_file()
    assert "diffdrive_odom.core.geometry.integration" in (
        out / "api" / "geometry.html").read_text(encoding="utf-8")
    # Program output is plain text, not coloured as Python.
    demo = (out / "tools" / "demo.html").read_text(encoding="utf-8")
    block = ('<div class="wide-output highlight-text notranslate"><div class="highlight">'
             '<pre><span></span>')
    assert f"{block}umbmark" in demo  # wide-output: tables.css fits its 160 columns
    assert "highlight-default" not in demo and "highlight-python" not in demo


# Reports, for each table of a page as a browser lays it out, how far its right edge is
# past the text column's (the theme's .wy-nav-content less its padding); a second after
# load, as the theme's script wraps each table in its scrolling div after the page's own.
_MEASURE = """<script>
window.addEventListener('load', function () { setTimeout(function () {
  var col = document.querySelector('.wy-nav-content');
  var edge = col.getBoundingClientRect().right - parseFloat(getComputedStyle(col).paddingRight);
  var out = [];
  document.querySelectorAll('table.docutils').forEach(function (t) {
    out.push(Math.round(t.getBoundingClientRect().right - edge));
  });
  var pre = document.createElement('pre');
  pre.id = 'MEASURED';
  pre.textContent = out.join(' ');
  document.body.appendChild(pre);
}, 1000); });
</script>"""
# Pages whose tables were wider than the column (cells kept on one line by the theme).
WIDE_TABLE_PAGES = ("ddc.html", "robot.html", "nodes/odometry_node.html",
                    "nodes/cmd_vel_node.html", "nodes/sim_node.html",
                    "nodes/path_follower_node.html", "concepts/calibration.html",
                    "benchmarks.html")


@pytest.mark.slow
@pytest.mark.process
def test_every_table_fits_the_column_in_a_browser(built: Path) -> None:
    """The pages in headless Chromium at 1280 x 900: no table reaches past the text column
    (so none scrolls sideways); the sphinx_rtd_theme's nowrap cells did (ddc.md's
    diffdrive_odom column off-screen, a parameter's meaning cut after a few words)."""
    browser = shutil.which("chromium") or shutil.which("chromium-browser")
    if browser is None:
        pytest.skip("no chromium on PATH (Debian: apt-get install chromium)")
    if "wy-nav-content" not in (built / "ddc.html").read_text(encoding="utf-8"):
        pytest.skip("built without sphinx_rtd_theme (the layout measured is its own)")
    for page in WIDE_TABLE_PAGES:
        src = built / page
        probe = src.with_name(f"_probe_{src.name}")
        probe.write_text(src.read_text(encoding="utf-8").replace("</body>", _MEASURE + "</body>"),
                         encoding="utf-8")
        dom = subprocess.run(
            [browser, "--headless", "--no-sandbox", "--disable-gpu", "--window-size=1280,900",
             "--virtual-time-budget=5000", "--dump-dom", probe.as_uri()],
            capture_output=True, text=True, timeout=120).stdout
        found = re.search(r'<pre id="MEASURED">([^<]*)</pre>', dom)
        assert found is not None, (page, dom[-500:])
        past = [int(v) for v in found.group(1).split()]
        assert past and max(past) <= 1, (page, past)
