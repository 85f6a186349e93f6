"""The plugin guide's packaging example: its pyproject.toml builds a package that installs."""

import importlib.metadata
import os
import shutil
import subprocess
import sys

import pytest
from _paths import ROOT

EXAMPLES = ROOT / "docs" / "examples"


@pytest.mark.slow
def test_the_guide_pyproject_builds_a_plugin_that_spherex_reduce_lists(tmp_path):
    """Build a wheel from the guide's pyproject.toml and its example module, install it on
    its own, and find its strategy with ``spherex-reduce plugins`` (the guide's first
    version had no version and no build-system: pip failed with a setuptools traceback)."""
    pytest.importorskip("build")
    package = tmp_path / "my-spherex-plugin"
    (package / "my_package").mkdir(parents=True)
    shutil.copy(EXAMPLES / "pyproject.toml", package / "pyproject.toml")
    (package / "my_package" / "__init__.py").write_text("")
    shutil.copy(EXAMPLES / "reference_median.py", package / "my_package" / "reference_median.py")
    dist = tmp_path / "dist"
    r = subprocess.run([sys.executable, "-m", "build", "--wheel", "--outdir", str(dist),
                        str(package)], capture_output=True, text=True)
    if r.returncode != 0 and "Could not find a version" in r.stderr + r.stdout:
        pytest.skip("no package index for the isolated build")
    assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-2000:]
    site = tmp_path / "site"
    subprocess.run([sys.executable, "-m", "pip", "install", "--no-deps", "--no-index",
                    "--target", str(site), str(next(dist.glob("my_spherex_plugin-*.whl")))],
                   check=True, capture_output=True)
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    env["PYTHONPATH"] = str(site)
    outer = [ep.name for ep in importlib.metadata.entry_points(group="spherex_reduce")]
    env["SPHEREX_REDUCE_BLOCK_PLUGINS"] = ",".join(outer)  # only the new plugin's names
    r = subprocess.run([sys.executable, "-m", "spherex_reduce.cli", "plugins"], env=env,
                       capture_output=True, text=True, cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    (line,) = [line for line in r.stdout.splitlines()
               if line.split()[:2] == ["strategy", "reference/refmedian"]]
    assert "my-spherex-plugin" in line and "0.1.0" in line, line
