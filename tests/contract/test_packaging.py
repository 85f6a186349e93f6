"""The package as users get it: a wheel in a fresh environment, and the README's promises."""

import importlib.metadata
import os
import re
import shlex
import shutil
import subprocess
import sys
import sysconfig
from pathlib import Path

import pytest
from _paths import ROOT


def _sources(tmp_path):
    """A copy of the checkout without build outputs: builds write ``build/`` and
    ``*.egg-info`` beside the sources, which must not change under tests running in
    parallel (the checkout's egg-info is the installed package's metadata)."""
    src = tmp_path / "src"
    shutil.copytree(ROOT, src, ignore=shutil.ignore_patterns(
        ".git", ".venv*", "build", "dist", "*.egg-info", "__pycache__", "_build", ".*_cache"))
    return src


def _quick_start():
    text = (ROOT / "README.md").read_text()
    block = re.search(r"## Quick start\s+```bash\n(.*?)```", text, re.S)
    assert block, "README must start with a Quick start code block"
    return text, [line for line in block.group(1).splitlines() if line.strip()]


def test_readme_quick_start_is_two_commands_and_ci_runs_the_second():
    text, commands = _quick_start()
    assert len(commands) == 2
    assert "spherex-reduce demo" in commands[0]
    assert "pytest" in commands[1] and ".[test]" in commands[1]
    assert commands[1] in (ROOT / ".ci" / "run").read_text().splitlines()
    assert text.index("## Quick start") < 40


def test_ci_runs_the_readme_line_in_a_stock_venv_with_nothing_before_it():
    """A newcomer's venv has the pip ``python3 -m venv`` ships; CI must not upgrade it."""
    script = (ROOT / ".ci" / "run").read_text().splitlines()
    steps = [line for line in script if line.strip() and not line.lstrip().startswith("#")]
    venv = next(i for i, line in enumerate(steps) if "-m venv" in line)
    test = steps.index(_quick_start()[1][1])
    between = steps[venv + 1:test]
    assert all(line.startswith("source ") for line in between), between
    assert not any(re.search(r"\bpip\b", line) for line in steps[:test]), steps[:test]


@pytest.mark.slow
def test_readme_test_command_resolves_with_the_pip_a_stock_venv_ships(tmp_path):
    """Resolve the README's install line with the pip of a fresh ``python -m venv``.

    pip 23.2 (what Python 3.11 ships) did not accept a local ``.[test]`` as the
    ``spherex-reduce`` the local plugin packages depend on, when the plugins were
    given as plain paths; the line must resolve with that pip, not only with a
    newer one.  A dry run resolves everything and installs nothing.
    """
    install = shlex.split(_quick_start()[1][1].split("&&")[0])
    assert install[:4] == ["python", "-m", "pip", "install"], install
    env_dir = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", str(env_dir)], check=True)
    py = env_dir / "bin" / "python"
    # nothing of this environment may satisfy a requirement (a PYTHONPATH would)
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
    r = subprocess.run([py, "-m", "pip", "install", "--dry-run", "--quiet", *install[4:]],
                       cwd=_sources(tmp_path), env=env, capture_output=True, text=True)
    out = r.stdout + r.stderr
    if r.returncode != 0 and re.search(r"No matching distribution found for (?!spherex)", out):
        pytest.skip("no package index reachable to resolve the dependencies")
    assert r.returncode == 0, out[-3000:]


@pytest.mark.slow
def test_wheel_in_fresh_venv_runs_from_another_directory(tmp_path):
    """Build a wheel, install it alone in a new venv, run the CLI elsewhere.

    The new venv sees the current environment's dependencies through a plain
    path entry (no .pth processing), so only the wheel provides spherex_reduce.
    """
    pytest.importorskip("build")
    dist = tmp_path / "dist"
    r = subprocess.run([sys.executable, "-m", "build", "--wheel", "--outdir", str(dist),
                        str(_sources(tmp_path))], capture_output=True, text=True)
    if r.returncode != 0 and "Could not find a version" in r.stderr + r.stdout:
        pytest.skip("no package index for the isolated build")
    assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-2000:]
    wheel = next(dist.glob("spherex_reduce-*.whl"))
    env_dir = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(env_dir)], check=True)
    py = env_dir / "bin" / "python"
    site = subprocess.run([py, "-c", "import sysconfig; print(sysconfig.get_path('purelib'))"],
                          capture_output=True, text=True, check=True).stdout.strip()
    (Path(site) / "deps.pth").write_text(sysconfig.get_path("purelib") + "\n")
    subprocess.run([sys.executable, "-m", "pip", "install", "--no-deps", "--no-index",
                    "--target", site, str(wheel)], check=True, capture_output=True)
    work = tmp_path / "elsewhere"
    work.mkdir()
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
    env["MPLBACKEND"] = "Agg"
    # plugins of the outer environment are not part of this test (their code is not on the path)
    outer = [ep.name for ep in importlib.metadata.entry_points(group="spherex_reduce")]
    env["SPHEREX_REDUCE_BLOCK_PLUGINS"] = ",".join(outer)
    where = subprocess.run([py, "-c", "import spherex_reduce; print(spherex_reduce.__file__)"],
                           cwd=work, env=env, capture_output=True, text=True, check=True)
    assert where.stdout.startswith(site), where.stdout
    exe = shutil.which("spherex-reduce", path=str(env_dir / "bin"))
    cli = [exe] if exe else [str(py), "-m", "spherex_reduce.cli"]
    r = subprocess.run([*cli, "show-config", "--list"], cwd=work, env=env, capture_output=True,
                       text=True)
    assert r.returncode == 0 and "unchop" in r.stdout.split(), r.stderr
    r = subprocess.run([*cli, "-q", "demo", "-o", "out", "--size", "64", "--nframes", "3"],
                       cwd=work, env=env,
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    assert (work / "out" / "reduced_chopped.fits").is_file()
