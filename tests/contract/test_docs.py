"""The Sphinx documentation builds without warnings, and its examples are true."""

import doctest
import importlib.util
import os
import shutil
import subprocess
import sys

import pytest
from _paths import ROOT

DOCS = ROOT / "docs"

#: Pages whose ``>>>`` examples are run as doctests (add pages here as they
#: gain examples that need no external files; use ``# doctest: +SKIP`` for
#: lines that do).
DOCTEST_PAGES = [
    "overview.rst",
    "measured_darks.rst",
    "readout.rst",
    "reduction.rst",
    "fits.rst",
    "yaml.rst",
    "cli.rst",
    "plugins.rst",
    "judging.rst",
    "forecast.rst",
]

_BUILD_MODULES = ["sphinx", "sphinx_automodapi", "numpydoc", "matplotlib"]


def _missing_build_modules():
    return [m for m in _BUILD_MODULES if importlib.util.find_spec(m) is None]


@pytest.mark.slow
def test_sphinx_build_is_warning_free(tmp_path):
    missing = _missing_build_modules()
    if missing:
        pytest.skip(
            f"docs build needs {', '.join(missing)}: "
            'python -m pip install -e ".[test]" installs them'
        )
    # Build from a copy so that generated files (automodapi's api/ pages) never
    # land in the checkout, and a concurrent build of docs/ is not disturbed.
    src = tmp_path / "docs"
    shutil.copytree(DOCS, src, ignore=shutil.ignore_patterns("_build", "api", "__pycache__"))
    # the performance page includes the benchmark reports from ../benchmarks
    shutil.copytree(ROOT / "benchmarks", tmp_path / "benchmarks",
                    ignore=shutil.ignore_patterns("*.py", "__pycache__"))
    env = dict(
        os.environ,
        MPLBACKEND="Agg",
        PYTHONPATH=os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]),
    )
    env.pop("PYTHONWARNINGS", None)
    cmd = [
        sys.executable,
        "-m",
        "sphinx",
        "-W",
        "--keep-going",
        "-q",
        "-b",
        "html",
        str(src),
        str(tmp_path / "html"),
    ]
    proc = subprocess.run(cmd, cwd=tmp_path, env=env, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, (
        f"sphinx-build -W failed (exit {proc.returncode}):\n{proc.stderr}\n{proc.stdout[-3000:]}"
    )
    html = tmp_path / "html"
    for page in [
        "index",
        "overview",
        "readout",
        "fits",
        "measured_darks",
        "yaml",
        "cli",
        "plugins",
        "api",
        "performance",
        "simulation",
        "reduction",
        "analysis",
    ]:
        assert (html / f"{page}.html").is_file(), f"{page}.html was not built"
    figures = list((html / "_images").glob("readout-*.png"))
    assert figures, "the read-order figure of readout.rst was not generated"
    api = (html / "api.html").read_text(encoding="utf-8")
    for name in ["ReadoutSchedule", "register_steps", "plot_read_order", "DO_NOT_USE"]:
        assert name in api, f"{name} is missing from the API reference"


@pytest.mark.parametrize("page", DOCTEST_PAGES)
def test_page_examples(page, tmp_path, monkeypatch):
    path = DOCS / page
    if not path.is_file():
        pytest.skip(f"docs/{page} does not exist")
    monkeypatch.chdir(tmp_path)
    result = doctest.testfile(
        str(path),
        module_relative=False,
        verbose=False,
        optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE,
    )
    assert result.failed == 0, f"{result.failed} example(s) in docs/{page} failed (see above)"


def test_every_subcommand_is_documented():
    import argparse

    from spherex_reduce.cli import build_parser

    parser = build_parser()
    (sub,) = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    text = (DOCS / "cli.rst").read_text(encoding="utf-8")
    missing = [name for name in sub.choices if f".. spherex-reduce-help:: {name}\n" not in text]
    assert not missing, (
        f"docs/cli.rst has no section for {missing}: add a section with "
        "'.. spherex-reduce-help:: NAME' and a sentence on what it does"
    )
