"""The package keeps its layers: imports go one way, and no module grows past 600 lines.

The layers are declared once, as an import-linter contract in ``pyproject.toml``
(``[tool.importlinter]``); docs/architecture.rst explains them.
"""

import os
import re
import shutil
import subprocess
import sys

import pytest
from _paths import ROOT

PACKAGE = ROOT / "spherex_reduce"
MAX_LINES = 600

_LINT = (
    "import sys; from importlinter.cli import lint_imports; "
    "sys.exit(lint_imports(config_filename='pyproject.toml', no_cache=True))"
)


def _lint(root):
    """Run the contract of ``root/pyproject.toml`` on ``root/spherex_reduce``."""
    pytest.importorskip(
        "importlinter", reason='the layers check needs import-linter: '
        'python -m pip install -e ".[test]" installs it')
    env = dict(os.environ, PYTHONPATH=str(root))
    env.pop("PYTHONWARNINGS", None)
    return subprocess.run([sys.executable, "-c", _LINT], cwd=root, env=env,
                          capture_output=True, text=True, timeout=120)


def test_imports_follow_the_layers():
    result = _lint(ROOT)
    assert result.returncode == 0, result.stdout + result.stderr
    assert re.search(r"Contracts: [1-9]\d* kept, 0 broken", result.stdout), result.stdout


def _copy(tmp_path):
    shutil.copy(ROOT / "pyproject.toml", tmp_path)
    pkg = tmp_path / "spherex_reduce"
    shutil.copytree(PACKAGE, pkg, ignore=shutil.ignore_patterns("__pycache__"))
    return pkg


def test_an_upward_import_breaks_the_contract(tmp_path):
    # The check can fail: a copy of the package where a core module imports a
    # step inside a function (where it would dodge an import cycle) is refused.
    pkg = _copy(tmp_path)
    with open(pkg / "core" / "geometry.py", "a") as f:
        f.write("\n\ndef _upward():\n    from ..reduce.steps import unchop\n\n    return unchop\n")
    result = _lint(tmp_path)
    assert result.returncode != 0
    assert "spherex_reduce.core is not allowed to import spherex_reduce.reduce" in result.stdout
    assert "spherex_reduce.core.geometry -> spherex_reduce.reduce.steps.unchop" in result.stdout


def test_a_module_outside_the_layers_breaks_the_contract(tmp_path):
    # and so is a new top-level module that no layer names
    pkg = _copy(tmp_path)
    (pkg / "unplaced.py").write_text("X = 1\n")
    result = _lint(tmp_path)
    assert result.returncode != 0
    assert "- spherex_reduce.unplaced" in result.stdout


def test_no_module_over_600_lines():
    sizes = {p.relative_to(ROOT).as_posix(): len(p.read_text(encoding="utf-8").splitlines())
             for p in sorted(PACKAGE.rglob("*.py"))}
    assert len(sizes) > 50  # the walk found the package
    offenders = {name: n for name, n in sizes.items() if n > MAX_LINES}
    assert not offenders, f"modules over {MAX_LINES} lines: {offenders}"
