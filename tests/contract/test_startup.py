"""Start-up: ``import spherex_reduce`` and the short commands load no heavy module.

Every command starts a new interpreter, so what it imports is paid on every run
(``benchmarks/bench_startup.py`` times it).  Each test runs the code in a fresh
interpreter and looks at ``sys.modules`` afterwards: the public names are
attached lazily (SPEC 1, ``lazy_loader``), ``--help`` and ``--version`` import no
command's module, and a command imports what it uses only.
"""

import json
import os
import subprocess
import sys

import numpy as np
import pytest
from astropy.io import fits

#: Never loaded by ``import spherex_reduce``, ``--help`` or ``--version``.
HEAVY = ("numpy", "astropy", "scipy", "astropy.nddata", "astropy.wcs", "scipy.optimize",
         "scipy.signal", "matplotlib", "dask", "distributed", "tqdm",
         "spherex_reduce.reduce.steps.reference.wiener", "spherex_reduce.simulation",
         "spherex_reduce.analysis", "spherex_reduce.io.readers.fits_read")

#: Never loaded by ``reduce``: plotting, dask, the simulator and the analysis.
NOT_FOR_REDUCE = ("matplotlib", "dask", "distributed", "scipy.signal", "scipy.optimize",
                  "spherex_reduce.simulation.simulator", "spherex_reduce.simulation.engine",
                  "spherex_reduce.simulation.scene", "spherex_reduce.analysis",
                  "spherex_reduce.io.plotting", "spherex_reduce.reduce.batch",
                  "spherex_reduce.reduce.scheduler")

PROBE = """\
import contextlib, io, json, sys
with contextlib.redirect_stdout(io.StringIO()):
{code}
print(json.dumps(sorted(sys.modules)))
"""


def modules_after(code, cwd=None):
    """The names in ``sys.modules`` after a fresh interpreter ran ``code`` (its output dropped)."""
    env = {k: v for k, v in os.environ.items() if k != "EAGER_IMPORT"}  # lazy_loader's switch
    body = "\n".join("    " + line for line in code.splitlines())
    done = subprocess.run([sys.executable, "-c", PROBE.format(code=body)], cwd=cwd, env=env,
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    return set(json.loads(done.stdout.splitlines()[-1]))


def cli(*argv):
    """Code that runs ``spherex-reduce ARGV`` as the entry point does (exits as it would)."""
    return ("from spherex_reduce.cli import main\n"
            "try:\n"
            f"    code = main({list(argv)!r})\n"
            "except SystemExit as exc:\n"
            "    code = exc.code\n"
            "assert code in (0, None), code")


def test_the_probe_sees_a_heavy_import():
    loaded = modules_after("import spherex_reduce\nspherex_reduce.simulate")
    assert {"scipy.signal", "spherex_reduce.simulation.engine"} <= loaded


def test_import_spherex_reduce_loads_nothing_heavy():
    loaded = modules_after("import spherex_reduce")
    assert "spherex_reduce" in loaded
    assert sorted(loaded.intersection(HEAVY)) == []


@pytest.mark.parametrize("argv", [["--version"], ["--help"]])
def test_version_and_help_load_nothing_heavy(argv):
    loaded = modules_after(cli(*argv))
    assert sorted(loaded.intersection(HEAVY)) == []
    commands = {m for m in loaded if m.startswith("spherex_reduce.cli.")}
    assert commands == set(), "--help and --version import no command's module"


def test_help_lists_each_command_as_its_module_describes_it():
    from spherex_reduce.cli import COMMANDS, build_parser

    assert build_parser(commands=()).format_help() == build_parser().format_help()
    (sub,) = [a for a in build_parser()._actions if hasattr(a, "_choices_actions")]
    assert {a.dest: a.help for a in sub._choices_actions} == COMMANDS


def test_a_command_imports_its_own_module_only():
    loaded = modules_after(cli("readout"))
    assert {m for m in loaded if m.startswith("spherex_reduce.cli.")} == {
        "spherex_reduce.cli.readout", "spherex_reduce.cli._common"}
    assert sorted(loaded.intersection((*NOT_FOR_REDUCE, "astropy.nddata", "tqdm"))) == []


def lab_dark(directory):
    """A 40 x 40 lab dark in uint16 ADU (5 reads 2 s apart, two channels; 3 ADU/s on the
    active pixels, none on the reference rows and columns) and the config to read it."""
    rng = np.random.default_rng(3)
    signal = np.zeros((40, 40))
    signal[4:, 4:] = 3.0
    adu = 1000 + signal * 2.0 * np.arange(5)[:, None, None] + rng.normal(0, 2, (5, 40, 40))
    fits.HDUList([fits.PrimaryHDU(), fits.ImageHDU(np.round(adu).astype(np.uint16),
                                                   name="SCI")]).writeto(directory / "lab.fits")
    (directory / "lab.yaml").write_text(
        "input: {unit: adu, gain: 2.0}\n"
        "geometry: {nrows: 40, ncols: 40, nchannels: 2, pixel_rate: 1.0e+5,\n"
        "           ref_border: {top: 4, left: 4}}\n"
        "readout: {skip: 1, ref_reads: 0, ref_mode: none, phantom_reads: 0, nframes: 5,\n"
        "          frame_time: 2.0}\n"
        "steps: [unchop, {correct_reference: {strategy: mean}}, fit_ramp]\n")


@pytest.mark.parametrize("quiet", [[], ["-q"]])
def test_reduce_loads_no_plotting_dask_simulator_or_analysis(tmp_path, quiet):
    lab_dark(tmp_path)
    loaded = modules_after(cli(*quiet, "reduce", "lab.fits", "-c", "lab.yaml", "-o", "out.fits"),
                           cwd=tmp_path)
    assert "spherex_reduce.reduce.pipeline" in loaded
    with fits.open(tmp_path / "out.fits") as hdul:  # the reduction ran: 3 ADU/s x 2 e/ADU
        assert np.nanmedian(hdul["SCI"].data[4:, 4:]) == pytest.approx(6.0, abs=0.1)
    assert sorted(loaded.intersection(NOT_FOR_REDUCE)) == []


def test_a_command_that_imports_astropy_as_it_runs_works(tmp_path):
    # main() sets astropy's logger aside while a command runs: looked up by name before
    # astropy was imported (simulate imports it in its run), that made a plain logger
    # which astropy's import then failed on
    (tmp_path / "scene.yaml").write_text(
        "geometry: {nrows: 64, ncols: 64, nchannels: 4, ref_border: 4}\nreadout: {nframes: 3}\n")
    done = subprocess.run([sys.executable, "-m", "spherex_reduce.cli", "-q", "simulate",
                           "scene.yaml", "-o", "sim.fits", "--mode", "slopes"], cwd=tmp_path,
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    with fits.open(tmp_path / "sim.fits") as hdul:  # 64 rows of 64 columns + 24 reference reads
        assert hdul["SCI"].data.shape == (88, 64)
