"""The command line against hostile input: outputs that are inputs, bad numbers, full
disks, signals, broken plugins.  Each case: one line on stderr, exit 2, nothing written,
the input unchanged."""

import errno
import os
import signal
import subprocess
import sys
import time
import warnings

import pytest
from _cli_helpers import digest, one_line_error, run

from spherex_reduce.cli import main
from spherex_reduce.io import atomic_output

SCENE = """\
geometry: {nrows: 64, ncols: 64, nchannels: 4, ref_border: 4}
readout: {skip: 4, ref_reads: 4, phantom_reads: 2, nframes: 4}
seed: 1
"""

@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """A scene, its raw ramps, a reduced image, a pipeline naming it as a dark."""
    d = tmp_path_factory.mktemp("hostile")
    (d / "scene.yaml").write_text(SCENE)
    assert run("-q", "simulate", d / "scene.yaml", "--mode", "ramps", "-o", d / "raw.fits") == 0
    assert run("-q", "reduce", d / "raw.fits", "-c", "spherex-default", "-o", d / "red.fits") == 0
    (d / "pipe.yaml").write_text(f"steps:\n  - unchop: {{}}\n  - fit_ramp: {{}}\n"
                                 f"  - subtract_dark: {{dark: {d / 'red.fits'}}}\n")
    (d / "sweep.yaml").write_text("scene: scene.yaml\ngrid: {skip: [4]}\nrealizations: 1\n")
    (d / "design.yaml").write_text("scene: scene.yaml\nband: {kmin: 0.3, kmax: 1.5}\n"
                                   "search: {iterations: 0}\nrealizations: 0\n")
    return d


def _spellings(d, name):
    """The same file named four ways: as is, ./x, a symbolic link, a hard link."""
    link, hard = d / f"link-{name}", d / f"hard-{name}"
    if not link.exists():
        link.symlink_to(d / name)
        os.link(d / name, hard)
    return [d / name, f"{d}/./{name}", link, hard]


CASES = [  # (command line with IN/OUT placeholders, the input that OUT names)
    ("reduce {raw} -c spherex-default -o {out}", "raw.fits"),
    ("reduce {raw} -c {pipe} -o {out}", "pipe.yaml"),
    ("reduce {raw} -c {pipe} -o {out}", "red.fits"),  # the pipeline's dark
    ("simulate {scene} -o {out}", "scene.yaml"),
    ("spectrum {red} -o {out}", "red.fits"),
    ("spectrum {red} -o {d}/s.ecsv --plot {out}", "red.fits"),
    ("forecast {scene} -c unchop -o {out}", "scene.yaml"),
    ("forecast {scene} -c {pipe} -o {out}", "pipe.yaml"),
    ("forecast {scene} -c unchop -o {d}/f.ecsv --plot {out}", "scene.yaml"),
    ("combine {red} {red} -o {out}", "red.fits"),
    ("fit-noise {raw} -o {out}", "raw.fits"),
    ("readout --config {scene} -o {out}", "scene.yaml"),
    ("readout --config {scene} --plot {out}", "scene.yaml"),
    ("sweep {sweep} --scheduler serial -o {out}", "sweep.yaml"),
    ("sweep {sweep} --scheduler serial -o {out}", "scene.yaml"),  # the scene it names
    ("design-readout {design} -o {out}", "design.yaml"),
    ("design-readout {design} -o {out}", "scene.yaml"),  # the scene it names
    ("design-readout {design} -o {d}/best.yaml --report {out}", "design.yaml"),
    ("design-readout {design} -o {d}/best.yaml --plot {out}", "scene.yaml"),
]


@pytest.mark.parametrize("spelling", range(4))
@pytest.mark.parametrize(("line", "victim"), CASES)
def test_output_that_is_an_input_is_refused(files, line, victim, spelling, capsys):
    d = files
    out = _spellings(d, victim)[spelling]
    before = {p.name: digest(p) for p in d.iterdir() if p.is_file()}
    args = line.format(raw=d / "raw.fits", red=d / "red.fits", pipe=d / "pipe.yaml",
                       scene=d / "scene.yaml", sweep=d / "sweep.yaml",
                       design=d / "design.yaml", d=d, out=out).split()
    assert run("-q", *args, "--overwrite") == 2
    one_line_error(capsys, "is the input")
    after = {p.name: digest(p) for p in d.iterdir() if p.is_file()}
    assert after == before  # nothing replaced, nothing new (no temporary file left)


def test_two_outputs_that_are_one_file_are_refused(files, tmp_path, capsys):
    out = tmp_path / "s.ecsv"
    assert run("spectrum", files / "red.fits", "-o", out, "--plot", out) == 2
    one_line_error(capsys, "same file")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("argv", [
    "spectrum {red} -o {out} --pixel-scale nan",
    "spectrum {red} -o {out} --pixel-scale inf",
    "spectrum {red} -o {out} --pixel-scale -1",
    "spectrum {red} -o {out} --photocurrent nan",
    "spectrum {red} -o {out} --photocurrent inf",
    "spectrum {red} -o {out} --integration-time nan",
    "spectrum {red} -o {out} --integration-time inf",
    "spectrum {red} -o {out} --kmin nan",
    "spectrum {red} -o {out} --bins 1e8",
    "spectrum {red} -o {out} --bins 0",
    "forecast -c unchop -o {out} --kmax nan",
    "forecast -c unchop -o {out} --pixel-scale 0",
    "forecast -c unchop -o {out} --bins 1e8",
    "combine {red} {red} -o {out} --sigma -1",
    "combine {red} {red} -o {out} --sigma nan",
    "fit-noise {raw} -o {out} --exponent nan",
    "fit-noise {raw} -o {out} --exponent inf",
    "fit-noise {raw} -o {out} --nbins 100000000",
    "fit-noise {raw} -o {out} --nperseg 1e30",
    "readout --nrows 3e8",
    "readout --nrows 300000000",
    "readout --nframes 1e12",
    "readout --pixel-rate 0",
    "readout --frame-time nan",
    "demo -o {out} --size 1e9",
    "demo -o {out} --nframes 1e9",
    "figures -o {out} --realizations 0",
    "figures -o {out} --workers -1",
    "figures -o {out} --workers 0",
    "sweep {sweep} -o {out} --workers 0",
])
def test_bad_numbers_are_usage_errors_naming_the_option(files, tmp_path, argv, capsys):
    out = tmp_path / "out"
    args = argv.format(red=files / "red.fits", raw=files / "raw.fits",
                       sweep=files / "sweep.yaml", out=out).split()
    t0 = time.perf_counter()
    assert run("-q", *args) == 2
    assert time.perf_counter() - t0 < 10
    option = next(a for a in args if a.startswith("--") and a not in ("--overwrite",))
    one_line_error(capsys, f"argument {option}")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize(("text", "key"), [
    ("search: {iterations: .nan}", "search.iterations"),
    ("search: {iterations: 1e9}", "search.iterations"),  # YAML 1.1: a string
    ("search: {iterations: 100000000}", "search.iterations"),
    ("search: {finalists: 0}", "search.finalists"),
    ("search: {skips: [0]}", "search.skips"),
    ("search: {ref_reads: [-1]}", "search.ref_reads"),
    ("search: {phantom_reads: [.inf]}", "search.phantom_reads"),
    ("search: {seed: -1}", "search.seed"),
    ("realizations: -1", "realizations"),
    ("realizations: .inf", "realizations"),
    ("realizations: 100000000", "realizations"),
    ("seed: 1.5", "seed"),
    ("bins: 0", "bins"),
    ("bins: 100000000", "bins"),
    ("band: {kmin: .nan}", "band.kmin"),
    ("band: {kmax: 4.0}", "band.kmax"),
    ("budget: {frame_time: .nan}", "budget.frame_time"),
    ("budget: {frame_time: .inf}", "budget.frame_time"),
    ("budget: {frame_time: 0}", "budget.frame_time"),
    ("baseline: {skip: 0}", "baseline.skip"),
    ("baseline: {skip: 100000000}", "baseline.skip"),
    ("baseline: {ref_reads: -1}", "baseline.ref_reads"),
])
def test_bad_numbers_in_a_design_file_are_one_line_naming_the_key(tmp_path, text, key, capsys):
    design = tmp_path / "design.yaml"
    design.write_text(text + "\n")
    t0 = time.perf_counter()
    assert run("-q", "design-readout", design, "-o", tmp_path / "best.yaml", "--report",
               tmp_path / "r.ecsv", "--plot") == 2
    assert time.perf_counter() - t0 < 10
    one_line_error(capsys, f"{design}: {key}")
    assert [p.name for p in tmp_path.iterdir()] == ["design.yaml"]
    assert design.read_text() == text + "\n"


def test_demo_size_beyond_memory_is_refused_before_allocating(tmp_path, capsys):
    assert run("-q", "demo", "-o", tmp_path / "d", "--size", 65536) == 2
    one_line_error(capsys, "--size 65536", "of memory")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize(("address", "words"), [
    ("not a url", "not a dask scheduler address"),
    ("tcp://127.0.0.1:1", "no dask scheduler answered"),  # nothing listens on port 1
])
@pytest.mark.parametrize("command", ["figures", "sweep"])
def test_bad_scheduler_fails_fast(files, tmp_path, command, address, words, capsys):
    args = ([files / "sweep.yaml"] if command == "sweep" else []) + ["-o", tmp_path / "o"]
    t0 = time.perf_counter()
    assert run("-q", command, *args, "--scheduler", address) == 2
    assert time.perf_counter() - t0 < 8
    one_line_error(capsys, "--scheduler", words)
    assert list(tmp_path.iterdir()) == []


def test_fit_noise_of_a_constant_stream_is_an_input_error(files, tmp_path, capsys):
    from astropy.io import fits

    zero = tmp_path / "zero.fits"
    with fits.open(files / "raw.fits") as hdul:
        for hdu in hdul:
            if hdu.is_image and hdu.data is not None:
                hdu.data = hdu.data * 0
        hdul.writeto(zero, checksum=True)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the PSD of zeros divides by zero on the way
        assert run("-q", "fit-noise", zero, "-o", tmp_path / "f.ecsv") == 2
    one_line_error(capsys, "zero at every frequency")
    assert not (tmp_path / "f.ecsv").exists()


@pytest.mark.parametrize("content", [b"# %ECSV 1.0\n# ---\n# datatype: [\n", b"garbage\x00\xff",
                                     b""])
def test_damaged_sweep_results_are_an_input_error(files, tmp_path, content, capsys):
    res = tmp_path / "res.ecsv"
    res.write_bytes(content)
    assert run("-q", "sweep", files / "sweep.yaml", "--scheduler", "serial", "-o", res) == 2
    one_line_error(capsys, "res.ecsv")
    assert res.read_bytes() == content


# --- output names, temporary files, signals ------------------------------------------------

@pytest.mark.parametrize("overwrite", [[], ["--overwrite"]])
def test_output_that_is_a_directory_is_refused(files, tmp_path, overwrite, capsys):
    (tmp_path / "d").mkdir()
    for out in (tmp_path / "d", f"{tmp_path}/new/"):
        assert run("-q", "reduce", files / "raw.fits", "-c", "spherex-default",
                   "-o", out, *overwrite) == 2
        one_line_error(capsys, "names a directory")
    assert [p.name for p in tmp_path.iterdir()] == ["d"] and not any((tmp_path / "d").iterdir())


def test_atomic_output_removes_its_temporary_file_when_the_rename_fails(tmp_path, monkeypatch):
    out = tmp_path / "x.txt"

    def fail(src, dst):
        raise OSError(errno.EXDEV, "Invalid cross-device link")

    monkeypatch.setattr(os, "replace", fail)
    monkeypatch.setattr(os, "link", fail)  # how an output that must not replace is renamed
    with pytest.raises(OSError), atomic_output(out) as tmp:
        tmp.write_text("x")
    assert list(tmp_path.iterdir()) == []


def test_stale_temporary_files_of_a_killed_writer_are_removed(tmp_path):
    out = tmp_path / "x.txt"
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    host = atomic_output.HOST
    stale = tmp_path / f".x.txt.{host}-{dead.pid}.abcd1234.tmp"
    alive = tmp_path / f".x.txt.{host}-{os.getppid()}.efgh5678.tmp"  # a running writer's
    other = tmp_path / f".y.txt.{host}-{dead.pid}.abcd1234.tmp"  # another output's
    longer = tmp_path / f".x.txt.1.{host}-{dead.pid}.abcd1234.tmp"  # output x.txt.1's
    remote = tmp_path / f".x.txt.0badc0de-{dead.pid}.abcd1234.tmp"  # another host's writer
    for p in (stale, alive, other, longer, remote):
        p.write_text("partial")
    with atomic_output(out) as tmp:
        assert tmp.name.startswith(f".x.txt.{host}-{os.getpid()}.")
        tmp.write_text("done")
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(
        ["x.txt", alive.name, other.name, longer.name, remote.name])


def test_sigterm_during_a_write_removes_the_temporary_file(files, tmp_path):
    """A command killed with SIGTERM while writing leaves nothing (as with SIGINT)."""
    out = tmp_path / "red.fits"
    code = ("import sys, time\n"
            "import spherex_reduce.cli.reduce as r\n"
            "from spherex_reduce.cli import main\n"
            "real = r.write\n"
            "def slow(result, path, overwrite=False, images=None):\n"
            "    from spherex_reduce.io import atomic_output\n"
            "    with atomic_output(path, overwrite) as tmp:\n"
            "        tmp.write_bytes(b'partial')\n"
            "        print('writing', flush=True)\n"
            "        time.sleep(30)\n"
            "r.write = slow\n"
            "sys.exit(main(sys.argv[1:]))\n")
    p = subprocess.Popen([sys.executable, "-c", code, "-q", "reduce", str(files / "raw.fits"),
                          "-c", "spherex-default", "-o", str(out)],
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    assert p.stdout.readline().strip() == "writing"
    assert any(tmp_path.iterdir())  # the temporary file is there
    p.send_signal(signal.SIGTERM)
    _, err = p.communicate(timeout=30)
    assert p.returncode == 128 + signal.SIGTERM and "terminated" in err and "Traceback" not in err
    assert list(tmp_path.iterdir()) == []


# --- environment errors ------------------------------------------------------------------------

def _no_space(*args, **kwargs):
    raise OSError(errno.ENOSPC, "No space left on device")


def test_full_disk_is_an_environment_error_naming_the_output(files, tmp_path, monkeypatch,
                                                             capsys):
    from astropy.io import fits

    monkeypatch.setattr(fits.HDUList, "writeto", _no_space)
    out = tmp_path / "red.fits"
    assert run("-q", "reduce", files / "raw.fits", "-c", "spherex-default", "-o", out) == 2
    one_line_error(capsys, str(out), "No space left on device")
    assert list(tmp_path.iterdir()) == []


def test_read_only_file_system_is_an_environment_error(files, tmp_path, monkeypatch, capsys):
    import tempfile

    def read_only(*args, dir=None, **kwargs):
        raise OSError(errno.EROFS, "Read-only file system", str(dir / ".s.ecsv.1.x.tmp"))

    monkeypatch.setattr(tempfile, "mkstemp", read_only)
    assert run("-q", "readout", "-o", tmp_path / "s.ecsv") == 2
    one_line_error(capsys, f"{tmp_path / 's.ecsv'}: Read-only file system")


@pytest.mark.parametrize("command", ["spectrum", "forecast"])
@pytest.mark.parametrize("fail", ["table", "plot"])
def test_spectrum_outputs_are_all_or_nothing(files, tmp_path, monkeypatch, fail, command,
                                             capsys):
    import matplotlib.figure
    from astropy.table import Table

    if fail == "plot":
        monkeypatch.setattr(matplotlib.figure.Figure, "savefig", _no_space)
    else:
        monkeypatch.setattr(Table, "write", _no_space)
    out, png = tmp_path / "s.ecsv", tmp_path / "s.png"
    what = [files / "red.fits"] if command == "spectrum" else [files / "scene.yaml", "-c",
                                                                "unchop"]
    assert run("-q", command, *what, "-o", out, "--plot", png) == 2
    one_line_error(capsys, "No space left on device")
    assert list(tmp_path.iterdir()) == []  # neither output, no temporary file


# The fixture's 64² dark of 4 frames fits the phantom's 1/f^1.3 term 3 sigma below zero
# on its seed (about 1 seed in 12): the fit's warning is not what this test is about.
@pytest.mark.filterwarnings("ignore:implausible noise fit")
def test_readout_and_fit_noise_outputs_are_all_or_nothing(files, tmp_path, monkeypatch, capsys):
    import matplotlib.figure

    monkeypatch.setattr(matplotlib.figure.Figure, "savefig", _no_space)
    assert run("-q", "readout", "-o", tmp_path / "s.ecsv", "--plot", tmp_path / "s.png") == 2
    one_line_error(capsys, "No space left on device")
    assert run("-q", "fit-noise", files / "raw.fits", "-o", tmp_path / "f.ecsv",
               "--plot") == 2
    one_line_error(capsys, "No space left on device")
    assert list(tmp_path.iterdir()) == []


# --- warnings --------------------------------------------------------------------------------

def test_warnings_are_one_line_each_and_shown_once(tmp_path):
    code = ("import sys, warnings, numpy as np\n"
            "from astropy.utils.exceptions import AstropyWarning\n"
            "import spherex_reduce.cli.readout as r\n"
            "from spherex_reduce.cli import main\n"
            "real = r.schedule_from_args\n"
            "def noisy(args):\n"
            "    for _ in range(3):\n"
            "        warnings.warn(AstropyWarning('an astropy warning'))\n"
            "        np.log(np.zeros(2))\n"
            "    import logging\n"
            "    logging.getLogger('spherex_reduce.x').warning('logged  by\\nus')\n"
            "    from astropy import log\n"
            "    log.warning('logged by astropy')\n"
            "    return real(args)\n"
            "r.schedule_from_args = noisy\n"
            "sys.exit(main(sys.argv[1:]))\n")
    r = subprocess.run([sys.executable, "-c", code, "readout"], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    lines = r.stderr.splitlines()
    assert [x for x in lines if "logged by astropy" in x] == [lines.pop()]  # once, not twice
    assert lines == [
        "spherex-reduce readout: warning: an astropy warning",
        "spherex-reduce readout: warning: divide by zero encountered in log",
        "spherex-reduce readout: warning: logged by us",
    ]


# --- plugins -----------------------------------------------------------------------------------

PLUGIN = """\
import sys
from spherex_reduce.reduce.hookspecs import hookimpl
from spherex_reduce.reduce.step import Simulator, Step

{at_import}

class Explode(Step):
    name, keyword = "explode", "S_EXPLOD"

    def run(self, exposure):
        {in_run}

class Boom(Simulator):
    name = "boom"

    def simulate(self, scene, *, mode=None, seed=None):
        raise ZeroDivisionError("boom simulator broke")

@hookimpl
def register_steps():
    return [Explode]

@hookimpl
def register_simulators():
    return [Boom]
"""


def _install_plugin(tmp_path, monkeypatch, at_import="", in_run="return exposure"):
    """A plugin distribution ``spherex-reduce-explode 0.1.0`` on a path of its own."""
    site = tmp_path / "site"
    site.mkdir()
    (site / "explode_plugin.py").write_text(PLUGIN.format(at_import=at_import, in_run=in_run))
    info = site / "spherex_reduce_explode-0.1.0.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: spherex-reduce-explode\n"
                                   "Version: 0.1.0\n")
    (info / "entry_points.txt").write_text("[spherex_reduce]\nexplode = explode_plugin\n")
    monkeypatch.syspath_prepend(str(site))
    monkeypatch.delitem(sys.modules, "explode_plugin", raising=False)
    return site


@pytest.mark.parametrize(("in_run", "kind"), [
    ("raise RuntimeError('explode step blew up')", "RuntimeError: explode step blew up"),
    ("return {}['no such key']", "KeyError"),
])
def test_plugin_failing_at_run_time_is_named(files, tmp_path, monkeypatch, capsys, in_run, kind):
    _install_plugin(tmp_path, monkeypatch, in_run=in_run)
    cfg = tmp_path / "p.yaml"
    cfg.write_text("steps:\n  - unchop: {}\n  - explode: {}\n  - fit_ramp: {}\n")
    out = tmp_path / "o.fits"
    assert run("-q", "reduce", files / "raw.fits", "-c", cfg, "-o", out) == 2
    one_line_error(capsys, "plugin 'explode' (spherex-reduce-explode 0.1.0)",
                   "in step 'explode'", kind, "SPHEREX_REDUCE_BLOCK_PLUGINS=explode")
    assert not out.exists()


def test_plugin_exiting_at_import_is_named_and_does_not_end_the_command(
        tmp_path, monkeypatch, capsys):
    _install_plugin(tmp_path, monkeypatch, at_import="sys.exit(3)")
    assert run("show-config", "spherex-default") == 2
    one_line_error(capsys, "plugin 'explode' (spherex-reduce-explode 0.1.0", "SystemExit: 3",
                   "failed to load")
    monkeypatch.setenv("SPHEREX_REDUCE_BLOCK_PLUGINS", "explode")
    assert run("show-config", "spherex-default") == 0


def test_key_error_of_our_own_is_not_an_input_error(tmp_path, monkeypatch, capsys):
    import spherex_reduce.cli.readout as readout

    def broken(args):
        return {}["bug"]

    monkeypatch.setattr(readout, "schedule_from_args", broken)
    assert run("readout") == 1
    assert "unexpected failure: KeyError" in capsys.readouterr().err


def test_unknown_step_is_still_a_one_line_input_error(tmp_path, capsys):
    cfg = tmp_path / "p.yaml"
    cfg.write_text("steps:\n  - nosuch: {}\n")
    assert run("show-config", cfg) == 2
    one_line_error(capsys, "unknown step 'nosuch'; valid:")


def test_plugin_simulator_failing_is_named(tmp_path, monkeypatch, capsys):
    _install_plugin(tmp_path, monkeypatch)
    scene = tmp_path / "scene.yaml"
    scene.write_text(SCENE + "synthesis: {simulator: boom}\n")
    out = tmp_path / "o.fits"
    assert run("-q", "simulate", scene, "-o", out) == 2
    one_line_error(capsys, "plugin 'explode' (spherex-reduce-explode 0.1.0)",
                   "ZeroDivisionError: boom simulator broke")
    assert not out.exists()


def test_plugins_listing_survives_a_plugin_with_damaged_metadata(monkeypatch, capsys):
    """A distribution whose METADATA has no Version: ``plugins`` still lists, exit 0."""
    import importlib.metadata

    class Damaged:
        name = "damaged-plugin"

        @property
        def version(self):
            raise KeyError("Version")

    class EntryPoint:
        name, group, value = "damaged", "spherex_reduce", "no_such_module_xyz"
        dist = Damaged()

    real = importlib.metadata.entry_points

    def entry_points(**kw):
        found = real(**kw)
        return [*found, EntryPoint()] if kw.get("group") == "spherex_reduce" else found

    monkeypatch.setattr(importlib.metadata, "entry_points", entry_points)
    monkeypatch.setenv("SPHEREX_REDUCE_BLOCK_PLUGINS", "damaged")  # listed, never imported
    assert run("plugins") == 0, capsys.readouterr().err
    out = capsys.readouterr().out
    assert "correct_reference" in out and "damaged-plugin" not in out


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["simulate", "{scene}", "--seed", "-1", "-o", "a.fits"], "non-negative"),
        (["demo", "-o", "d", "--size", "64", "--nframes", "1"], "--nframes must be >= 2"),
        (["spectrum", "{image}", "-o", "s.ecsv", "--pixel-scale", "0"], "--pixel-scale"),
        (["spectrum", "{image}", "-o", "s.ecsv", "--integration-time", "0"],
         "--integration-time"),
        (["spectrum", "{image}", "-o", "s.ecsv", "--photocurrent", "-1"], "--photocurrent"),
    ],
)
def test_cli_rejects_bad_numbers(tmp_path, monkeypatch, capsys, args, message):
    monkeypatch.chdir(tmp_path)
    scene = tmp_path / "scene.txt"  # not .yaml: read as a file all the same
    scene.write_text("geometry: {nrows: 64, ncols: 64, nchannels: 1}\nreadout: {nframes: 3}\n")
    image = tmp_path / "img.fits"
    if "{image}" in args:
        assert main(["-q", "simulate", str(scene), "-o", str(image)]) == 0
    argv = [a.format(scene=scene, image=image) for a in args]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err
