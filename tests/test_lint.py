"""`make lint`: ruff with the project's own rule sets (pyproject.toml: pyflakes, pycodestyle, import sorting,
bugbear, pyupgrade, simplify, ruff, naming, pytest style), the import contracts (tests/test_imports.py) and
mypy over the whole tree. It passes on the tree and fails on a lint error or a type error."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
VENV_BIN = Path(sys.executable).parent


def _tool(name: str) -> str:
    tool = shutil.which(name, path=str(VENV_BIN)) or shutil.which(name)
    assert tool is not None, f"{name} is part of the test extra: pip install -e '.[test]'"
    return tool


def test_ruff_passes_on_the_whole_tree() -> None:
    proc = subprocess.run([_tool("ruff"), "check", "--no-cache", "--output-format", "concise", "."],
                          cwd=ROOT, capture_output=True, text=True, check=False)
    assert proc.returncode == 0, proc.stdout[-4000:]
    # Import sorting is part of it, with the project's packages seen as first-party (folders are import names).
    config = (ROOT / "pyproject.toml").read_text(encoding="utf-8")
    assert '"I"' in config


def test_mypy_passes_on_the_whole_tree() -> None:
    proc = subprocess.run([_tool("mypy")], cwd=ROOT, capture_output=True, text=True, check=False)
    assert proc.returncode == 0, proc.stdout[-4000:]
    assert "Success: no issues found" in proc.stdout


def _make_lint(tree: Path) -> subprocess.CompletedProcess[str]:
    """`make lint` in ``tree`` with this interpreter's virtualenv (the Makefile's VENV is .venv beside it)."""
    env = {**os.environ, "PATH": f"{VENV_BIN}:{os.environ.get('PATH', '')}"}
    return subprocess.run(["make", "--no-print-directory", "-o", ".venv", "-o", ".venv/.installed", "lint",
                           f"VENV={VENV_BIN.parent}"], cwd=tree, capture_output=True, text=True, env=env, check=False)


@pytest.fixture(scope="module")
def tree_copy(tmp_path_factory: pytest.TempPathFactory) -> Path:
    tree = tmp_path_factory.mktemp("lint") / "cdpr"
    # what .gitignore keeps out of the tree (ruff reads .gitignore only in a git repository, this copy is not one),
    # but mypy's cache: test_mypy_passes_on_the_whole_tree has just filled it for these very files
    ignore = shutil.ignore_patterns(".venv", "__pycache__", ".pytest_cache", "runs", "*.rrd", ".git",
                                    "build", "*.egg-info", ".hypothesis", "test-artifacts")
    shutil.copytree(ROOT, tree, ignore=ignore)
    return tree


@pytest.mark.skipif(shutil.which("make") is None, reason="make is not installed")
def test_make_lint_passes_on_the_tree_and_fails_on_a_lint_or_type_error(tree_copy: Path) -> None:
    proc = _make_lint(tree_copy)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    module = tree_copy / "shared" / "cdpr" / "mechanics" / "rotation.py"
    clean = module.read_text(encoding="utf-8")
    try:
        module.write_text(clean + "\n\nimport os\n", encoding="utf-8")  # an unused import, out of place
        proc = _make_lint(tree_copy)
        assert proc.returncode != 0
        assert "rotation.py" in proc.stdout, proc.stdout
        assert "F401" in proc.stdout or "E402" in proc.stdout, proc.stdout
        module.write_text(clean + '\n\ndef half(x: float) -> int:\n    return x / 2\n', encoding="utf-8")
        proc = _make_lint(tree_copy)
        assert proc.returncode != 0
        assert "rotation.py:" in proc.stdout, proc.stdout[-3000:]
        assert "[return-value]" in proc.stdout, proc.stdout[-3000:]
    finally:
        module.write_text(clean, encoding="utf-8")
