"""The package's shape: the one-way import graph (import-linter) and no private names across modules."""

from __future__ import annotations

import ast
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

import drivesense

SRC = Path(drivesense.__file__).parent
ROOT = Path(__file__).resolve().parent.parent       # the checkout (drivesense may be installed elsewhere)
#: import-linter's command: on PATH, or beside this Python (a virtual environment that is not activated)
LINT_IMPORTS = shutil.which("lint-imports") or shutil.which("lint-imports", path=str(Path(sys.executable).parent))


def _modules():
    for path in sorted(SRC.rglob("*.py")):
        yield path, ast.parse(path.read_text(encoding="utf-8"), filename=str(path))


def test_no_private_names_imported_across_modules():
    bad = []
    for path, tree in _modules():
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom):
                for alias in node.names:
                    if alias.name.startswith("_") and not alias.name.startswith("__"):
                        bad.append(f"{path.relative_to(SRC)}:{node.lineno} imports {alias.name} from "
                                   f"{'.' * node.level}{node.module or ''}")
    assert not bad, "private names imported across modules:\n" + "\n".join(bad)


@pytest.mark.skipif(LINT_IMPORTS is None or not (ROOT / "pyproject.toml").is_file(),
                    reason="import-linter not installed (pip install '.[test]') or not a source checkout")
def test_import_graph_is_one_way():
    res = subprocess.run([LINT_IMPORTS, "--no-cache"], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stdout[-4000:] + res.stderr[-2000:]
    assert "0 broken" in res.stdout
