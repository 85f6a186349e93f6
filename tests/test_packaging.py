"""The package as users get it: a wheel in a fresh environment, and the README's promises."""

import importlib.metadata
import os
import re
import shutil
import subprocess
import sys
import sysconfig
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def test_readme_quick_start_is_two_commands_and_ci_runs_the_second():
    text = (ROOT / "README.md").read_text()
    block = re.search(r"## Quick start\s+```bash\n(.*?)```", text, re.S)
    assert block, "README must start with a Quick start code block"
    commands = [line for line in block.group(1).splitlines() if line.strip()]
    assert len(commands) == 2
    assert "spherex-reduce demo" in commands[0]
    assert "pytest" in commands[1] and ".[test]" in commands[1]
    assert commands[1] in (ROOT / ".ci" / "run").read_text().splitlines()
    assert text.index("## Quick start") < 40


@pytest.mark.slow
def test_wheel_in_fresh_venv_runs_from_another_directory(tmp_path):
    """Build a wheel, install it alone in a new venv, run the CLI elsewhere.

    The new venv sees the current environment's dependencies through a plain
    path entry (no .pth processing), so only the wheel provides spherex_reduce.
    """
    pytest.importorskip("build")
    dist = tmp_path / "dist"
    r = subprocess.run([sys.executable, "-m", "build", "--wheel", "--outdir", str(dist),
                        str(ROOT)], capture_output=True, text=True)
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
