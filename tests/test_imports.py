"""The tree's layers and the absence of import circles, kept by import-linter (its contracts are in
pyproject.toml: layers mechanics ← config ← protocol ← runtime, recording ← services ← tools; no I/O
library in the math; no circle among a package's modules) and by grimp, import-linter's graph, for circles
that pass through a parent package (which the sibling contract does not look at)."""

from __future__ import annotations

import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import grimp
import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("cdpr", "cdpr_sim", "cdpr_controller", "cdpr_trajectory", "cdpr_clock", "cdpr_recorder")


def _lint_imports() -> str:
    tool = shutil.which("lint-imports", path=str(Path(sys.executable).parent)) or shutil.which("lint-imports")
    assert tool is not None, "import-linter is part of the test extra: pip install -e '.[test]'"
    return tool


def import_circles(graph: grimp.ImportGraph) -> list[list[str]]:
    """One circle (as a list of modules, the first repeated at the end) per import that closes one."""
    circles, seen = [], set()
    for importer in sorted(graph.modules):
        for imported in sorted(graph.find_modules_directly_imported_by(importer)):
            back = graph.find_shortest_chain(importer=imported, imported=importer)
            if back is not None and frozenset(back) not in seen:
                seen.add(frozenset(back))
                circles.append([importer, *back])
    return circles


def test_the_tree_keeps_its_import_contracts() -> None:
    proc = subprocess.run([_lint_imports(), "--no-cache"], cwd=ROOT, capture_output=True, text=True, check=False)
    assert proc.returncode == 0, proc.stdout[-4000:] + proc.stderr[-2000:]
    assert "0 broken" in proc.stdout


def test_no_import_circle_in_the_tree() -> None:
    circles = import_circles(grimp.build_graph(*PACKAGES, cache_dir=None))
    assert circles == [], "import circles: " + "; ".join(" → ".join(c) for c in circles)


@pytest.fixture
def bad_tree(tmp_path: Path) -> Path:
    """A small package whose lowest layer imports its top one, through its parent package too."""
    pkg = tmp_path / "badpkg"
    for sub in ("mechanics", "tools"):
        (pkg / sub).mkdir(parents=True)
    (pkg / "__init__.py").write_text("from badpkg import tools\n")
    (pkg / "mechanics" / "__init__.py").write_text("")
    (pkg / "mechanics" / "robot.py").write_text("import badpkg.tools.cli\n")
    (pkg / "tools" / "__init__.py").write_text("from badpkg.tools import cli\nVALUE = 1\n")
    (pkg / "tools" / "cli.py").write_text("import badpkg.mechanics.robot\nfrom badpkg.tools import VALUE\n")
    (tmp_path / "pyproject.toml").write_text(textwrap.dedent("""\
        [tool.importlinter]
        root_packages = ["badpkg"]

        [[tool.importlinter.contracts]]
        name = "layers"
        type = "layers"
        layers = ["badpkg.tools", "badpkg.mechanics"]
    """))
    return tmp_path


def test_the_checks_find_a_broken_layer_and_a_circle(bad_tree: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    proc = subprocess.run([_lint_imports(), "--no-cache"], cwd=bad_tree, capture_output=True, text=True, check=False,
                          env={"PYTHONPATH": str(bad_tree), "PATH": "/usr/bin:/bin"})
    assert proc.returncode == 1, proc.stdout
    assert "badpkg.mechanics.robot -> badpkg.tools.cli" in proc.stdout
    monkeypatch.syspath_prepend(str(bad_tree))
    circles = import_circles(grimp.build_graph("badpkg", cache_dir=None))
    flat = {" → ".join(c) for c in circles}
    # the layer break closes a circle here; so does a package and the module of its own that imports it
    assert flat == {"badpkg.mechanics.robot → badpkg.tools.cli → badpkg.mechanics.robot",
                    "badpkg.tools → badpkg.tools.cli → badpkg.tools"}
