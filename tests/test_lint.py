"""ruff with the project's own rule sets (pyproject.toml: pyflakes, pycodestyle, import sorting, bugbear,
pyupgrade, simplify, ruff, naming, pytest style) over the whole tree."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_ruff_passes_on_the_whole_tree() -> None:
    ruff = shutil.which("ruff", path=str(Path(sys.executable).parent)) or shutil.which("ruff")
    assert ruff is not None, "ruff is part of the test extra: pip install -e '.[test]'"
    proc = subprocess.run([ruff, "check", "--no-cache", "--output-format", "concise", "."],
                          cwd=ROOT, capture_output=True, text=True, check=False)
    assert proc.returncode == 0, proc.stdout[-4000:]
    # Import sorting is part of it, with the project's packages seen as first-party (folders are import names).
    config = (ROOT / "pyproject.toml").read_text(encoding="utf-8")
    assert '"I"' in config
