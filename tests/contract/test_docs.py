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


#: A small stand-in for the README's ``simulate`` of the paper's case (1.3 GB of ramps).
_SMALL_SCENE = """\
geometry: {nrows: 64, ncols: 64, nchannels: 2, ref_border: 4}
readout: {skip: 4, ref_reads: 4, phantom_reads: 2, nframes: 3, frame_overhead: 10}
seed: 1
"""


def _readme_blocks(language):
    import re

    text = (ROOT / "README.md").read_text(encoding="utf-8")
    return re.findall(rf"```{language}\n(.*?)```", text, re.S)


def test_readme_python_snippet_runs_after_its_commands(tmp_path, monkeypatch, capsys):
    """A newcomer runs the README's commands, then its Python snippet, in one directory: the
    snippet stopped on a FileExistsError (it wrote the command's reduced.fits again), and it
    read the whole raw file into memory where ``Pipeline.run(path)`` streams it."""
    import shlex

    import numpy as np

    import spherex_reduce as sr
    from spherex_reduce.cli import main

    commands = next(b for b in _readme_blocks("bash") if "spherex-reduce reduce " in b)
    (reduce_line,) = [line.split("#")[0] for line in commands.splitlines()
                      if line.startswith("spherex-reduce reduce ")]
    monkeypatch.chdir(tmp_path)
    (tmp_path / "scene.yaml").write_text(_SMALL_SCENE)
    assert main(["-q", "simulate", "scene.yaml", "--mode", "ramps", "-o", "raw.fits"]) == 0
    argv = shlex.split(reduce_line)[1:]
    assert argv[:2] == ["reduce", "raw.fits"]
    assert main(["-q", *argv]) == 0
    command_output = tmp_path / argv[argv.index("-o") + 1]
    before = command_output.read_bytes()
    capsys.readouterr()

    def whole_file(*args, **kwargs):
        raise AssertionError("the README's snippet reads the whole raw file into memory")

    monkeypatch.setattr(sr, "read", whole_file)
    (snippet,) = _readme_blocks("python")
    namespace = {}
    exec(compile(snippet, "README.md", "exec"), namespace)
    assert "2072 reads/frame" in capsys.readouterr().out  # what its comment says
    assert command_output.read_bytes() == before  # the command's output is left alone
    monkeypatch.undo()
    np.testing.assert_array_equal(namespace["reduced"].data.data.astype(np.float32),
                                  sr.read(command_output).data.data)  # the file's float32
    written = sorted(p.name for p in tmp_path.glob("*.fits"))
    assert len(written) == 3, written  # raw, the command's and the snippet's
