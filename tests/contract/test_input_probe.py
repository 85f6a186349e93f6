"""The input probe: hostile input to every command, checked against the error contract.

Every case runs ``spherex-reduce`` in a child process (see ``tests/_probe.py``)
capped at 2 GiB of address space and `_probe.TIMEOUT` seconds, in a fresh
directory holding copies of small inputs made once per session by the package
itself (a 64 x 64, 2-channel, 3-frame scene: ``scene.yaml``, raw ramps
``raw.fits``, their reduction ``red.fits``, a second reduction ``red2.fits``, a
one-step pipeline ``fit.yaml``, a serial sweep ``sweep.yaml`` and its results
``res.ecsv``).  The case damages what it needs, then runs the command with
``-q`` and the directory as working directory.

A **refused** case must meet the contract of bad input (``docs/cli.rst``):

* exit code 2, within the time limit and the memory cap;
* stderr is exactly one non-empty line, ``spherex-reduce COMMAND: error: ...``
  (no traceback, no warning lines), naming the problem where the case says
  what the message must mention;
* no file appears in, or disappears from, the directory (no partial output,
  no leftover ``.NAME.*.tmp``), and every file's bytes are unchanged (so no
  input is ever modified).

A **working** case (for example integer FITS data, which must be read right)
exits 0 and its check compares the result with an independent computation.

Adding a case
=============
Append to the list of the right section below:

* ``refused("command-what", [ARGV...], setup=FUNC, mentions=REGEX)`` for input
  that must be refused.  ``ARGV`` is the command line without ``-q``; ``{dir}``
  in an argument is replaced by the absolute path of the case's directory.
  ``setup(d)`` receives that directory (a `pathlib.Path` holding the copies) and
  damages or creates files in it; `_probe.cut`, `_probe.flip_byte`,
  `_probe.edit_cards` and `_probe.span` help with FITS files, `write` with text.
  ``mentions`` is a regular expression (case-insensitive) the error line must
  contain; give it only where any correct message must contain it (an option
  or keyword name).
* ``works("command-what", [ARGV...], setup=FUNC, check=FUNC)`` for input that
  must be processed: ``check(d, result, run)`` asserts on the outputs and may
  run more commands (``run(argv)``) to compare with.

Give ids as ``command-what-is-wrong``.  Keep inputs small: the whole module
should run in well under a minute once every case holds.  Run one case with
``pytest tests/contract/test_input_probe.py -k ID``; set ``SPHEREX_PROBE_SPAWN=1`` to run
each case as ``python -m spherex_reduce.cli`` instead of through the fork
server.

Names the cases rely on that may not exist yet: ``--ignore-checksum`` (an option
of the subcommand) to read a file whose checksum fails, recorded in the
output header.
"""

import contextlib
import os
import re
import resource
import shutil
import signal
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import _probe
import numpy as np
import pytest
from astropy.io import fits
from astropy.table import Table

SCENE = """\
geometry: {nrows: 64, ncols: 64, nchannels: 2, ref_border: 4}
readout: {skip: 4, ref_reads: 4, phantom_reads: 2, nframes: 3, frame_overhead: 10}
seed: 1
"""
SWEEP = """\
scene: {geometry: {nrows: 64, ncols: 64, nchannels: 2}, readout: {skip: 4, ref_reads: 4,
        phantom_reads: 2, nframes: 3, frame_overhead: 10}}
pipeline: spherex-default
grid: {skip: [1, 4]}
realizations: 1
seed: 1
"""
FIT = "steps:\n  - fit_ramp: {weighting: uniform}\n"
DEFAULT_STEPS = """\
steps:
  - unchop: {}
  - subtract_phantom: {}
  - correct_reference: {strategy: mean, sigma: 3.0, maxiters: 5}
  - fit_ramp: {weighting: uniform}
"""
REDUCE = ["reduce", "raw.fits", "-c", "spherex-default", "-o", "out.fits"]
SPECTRUM = ["spectrum", "red.fits", "-o", "sp.ecsv"]
FIT_NOISE = ["fit-noise", "raw.fits", "-o", "fit.ecsv"]
COMBINE = ["combine", "red.fits", "red2.fits", "-o", "master.fits"]
SERIAL = ["--scheduler", "serial"]
ERROR_LINE = re.compile(r"^spherex-reduce [\w-]+: error: \S")


# -- the session's inputs ----------------------------------------------------------------------

@pytest.fixture(scope="module")
def runner():
    r = _probe.Runner()
    yield r
    r.close()


@pytest.fixture(scope="module")
def inputs(runner, tmp_path_factory):
    """Small inputs made by the command line itself, shared by every case (read-only)."""
    d = tmp_path_factory.mktemp("probe-inputs")
    (d / "scene.yaml").write_text(SCENE)
    (d / "sweep.yaml").write_text(SWEEP)
    (d / "fit.yaml").write_text(FIT)
    for argv in (["simulate", "scene.yaml", "--mode", "ramps", "-o", "raw.fits"],
                 ["simulate", "scene.yaml", "--mode", "ramps", "--seed", "2", "-o", "raw2.fits"],
                 ["reduce", "raw.fits", "-c", "spherex-default", "-o", "red.fits"],
                 ["reduce", "raw2.fits", "-c", "spherex-default", "-o", "red2.fits"],
                 ["sweep", "sweep.yaml", "-o", "res.ecsv", *SERIAL]):
        result = runner.run(["-q", *argv], d, timeout=120)
        assert result.rc == 0, result.describe()
    (d / "raw2.fits").unlink()
    return d


# -- cases -------------------------------------------------------------------------------------

@dataclass
class Case:
    argv: list
    setup: object = None
    mentions: str = None
    check: object = None  # None: must be refused
    timeout: float = _probe.TIMEOUT


def refused(id, argv, setup=None, mentions=None, timeout=_probe.TIMEOUT, marks=()):
    return pytest.param(Case(list(argv), setup, mentions, None, timeout), id=id, marks=marks)


def works(id, argv, setup=None, check=None, timeout=_probe.TIMEOUT, marks=()):
    return pytest.param(Case(list(argv), setup, None, check, timeout), id=id, marks=marks)


def write(name, text):
    """Setup: write ``text`` (str or bytes) to ``name``."""
    def setup(d):
        path = d / name
        if isinstance(text, bytes):
            path.write_bytes(text)
        else:
            path.write_text(text)
    return setup


def chain(*setups):
    def setup(d):
        for s in setups:
            s(d)
    return setup


def cards(name, hdu="PRIMARY", **values):
    """Setup: rewrite raw header cards (`_probe.edit_cards`) of ``name``."""
    def setup(d):
        _probe.edit_cards(d / name, hdu, values)
    return setup


def cut_data(name, hdu, fraction=0.5):
    """Setup: truncate ``name`` inside the data of ``hdu``."""
    def setup(d):
        _, _, start, size = _probe.span(d / name, hdu)
        assert size > 0
        _probe.cut(d / name, start + int(size * fraction))
    return setup


def cut_last_hdu(name):
    """Setup: truncate ``name`` inside its last HDU (its data, or its header if it has none)."""
    def setup(d):
        _, head, start, size = _probe.hdu_spans(d / name)[-1]
        _probe.cut(d / name, start + size // 2 if size else head + (start - head) // 2)
    return setup


def drop_last_hdu(name):
    """Setup: cut ``name`` exactly before its last HDU (a valid FITS file, one HDU short)."""
    def setup(d):
        _probe.cut(d / name, _probe.hdu_spans(d / name)[-1][1])
    return setup


def flip_sci(name):
    """Setup: flip the lowest bit of the first SCI value (CHECKSUM/DATASUM are present)."""
    def setup(d):
        with fits.open(d / name) as hdul:
            assert "DATASUM" in hdul["SCI"].header
            itemsize = hdul["SCI"].data.dtype.itemsize
        _, _, start, _ = _probe.span(d / name, "SCI")
        _probe.flip_byte(d / name, start + itemsize - 1)
    return setup


def link(name, target):
    def setup(d):
        (d / name).symlink_to(target)
    return setup


def mkdir(name):
    def setup(d):
        (d / name).mkdir()
    return setup


def rewrite_hdus(src, dst, change):
    """Copy FITS file ``src`` to ``dst`` (fresh checksums) after ``change(hdul)``."""
    with fits.open(src) as hdul:
        hdul = fits.HDUList([h.copy() for h in hdul])
    change(hdul)
    hdul.writeto(dst, checksum=True, overwrite=True)


def billion_laughs(key):
    """``key:`` holding a YAML alias bomb: 9 levels of 9 aliases (9**9 strings expanded)."""
    items = ['&l0 ["lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol"]']
    items += [f"&l{i} [" + ", ".join([f"*l{i - 1}"] * 9) + "]" for i in range(1, 9)]
    return f"{key}: [" + ", ".join(items) + "]"


def deep_list(key, depth=5000):
    return f"{key}: " + "[" * depth + "]" * depth + "\n"


# Header values astropy would never write; each is a raw card value.
HEADER_CASES = [
    ("nrows-1e15", {"NROWS": "1000000000000000"}, None),
    ("nrows-1e999", {"NROWS": "1E999"}, None),
    ("nrows-minus-1e999", {"NROWS": "-1E999"}, None),
    ("tframe-1e999", {"TFRAME": "1E999"}, None),
    ("tframe-nan", {"TFRAME": "NAN"}, None),
    ("chanw-abc", {"CHANW": "'abc'"}, "CHANW"),
    ("nframes-3.5", {"NFRAMES": "3.5"}, "NFRAMES"),  # the data have 3 frames
    ("nrows-string", {"NROWS": "'abc'"}, "NROWS"),
    ("nrows-logical", {"NROWS": "T"}, "NROWS"),
    ("ncols-logical", {"NCOLS": "T"}, "NCOLS"),
]

FITS_DAMAGE = [
    refused("reduce-truncated-last-hdu", REDUCE, cut_last_hdu("raw.fits")),
    refused("reduce-truncated-mid-data", REDUCE, cut_data("raw.fits", "SCI")),
    refused("reduce-truncated-in-phantom", REDUCE, cut_data("raw.fits", "PHANTOM")),
    refused("spectrum-truncated-last-hdu", SPECTRUM, cut_last_hdu("red.fits")),
    refused("spectrum-truncated-mid-data", SPECTRUM, cut_data("red.fits", "SCI")),
    refused("spectrum-reduced-missing-last-hdu", SPECTRUM, drop_last_hdu("red.fits")),
    refused("combine-truncated-mid-data", COMBINE, cut_data("red2.fits", "SCI")),
    refused("fit-noise-truncated-mid-data", FIT_NOISE, cut_data("raw.fits", "SCI")),
    refused("reduce-checksum-flipped-byte", REDUCE, flip_sci("raw.fits"), mentions="checksum"),
    refused("spectrum-checksum-flipped-byte", SPECTRUM, flip_sci("red.fits"),
            mentions="checksum"),
    refused("fit-noise-checksum-flipped-byte", FIT_NOISE, flip_sci("raw.fits"),
            mentions="checksum"),
    *[refused(f"reduce-header-{name}", REDUCE, cards("raw.fits", **values), mentions=mention)
      for name, values, mention in HEADER_CASES],
    refused("spectrum-header-nrows-1e15", SPECTRUM, cards("red.fits", NROWS="1000000000000000")),
    refused("spectrum-header-tframe-nan", SPECTRUM, cards("red.fits", TFRAME="NAN")),
    refused("spectrum-sci-disagrees-with-header", SPECTRUM, cards("red.fits", NROWS="32")),
]


def _check_checksum_warning(d, result, run):
    with fits.open(d / "out.fits", checksum=True) as hdul:
        header = hdul[0].header
        noted = [c for c in header.cards if c.keyword not in ("CHECKSUM", "DATASUM")
                 and "checksum" in f"{c.keyword} {c.value} {c.comment}".lower()]
        assert noted, "the output header does not record that a checksum failed"
        assert hdul["SCI"].data.shape == (64, 64)


CHECKSUM_OPT_OUT = [
    # Needs the opt-out option of the fix (name assumed: --ignore-checksum).
    works("reduce-checksum-flipped-byte-ignored", [*REDUCE, "--ignore-checksum"],
          flip_sci("raw.fits"), _check_checksum_warning),
]


# -- integer FITS data: must be read right (scaled by BZERO/BSCALE) ----------------------------

def _integer_raw(kind):
    """Setup: int.fits (integer SCI and PHANTOM) and flt.fits (the same values as floats)."""
    def setup(d):
        def change(hdul):
            for name in ("SCI", "PHANTOM"):
                if kind == "uint16":  # unsigned: BITPIX 16, BZERO 32768
                    hdul[name].data = (np.round(hdul[name].data * 10) + 1000).astype(np.uint16)
                else:  # int16 with BSCALE 0.5, BZERO 1000
                    hdul[name].data = np.round(hdul[name].data * 20) * 0.5 + 1000
                    hdul[name].scale("int16", bscale=0.5, bzero=1000)

        rewrite_hdus(d / "raw.fits", d / "int.fits", change)
        with fits.open(d / "int.fits") as hdul:
            h = hdul["SCI"].header
            assert h["BITPIX"] == 16 and h["BZERO"] in (32768, 1000)
            assert kind == "uint16" or h["BSCALE"] == 0.5
            physical = {n: hdul[n].data.astype(np.float32) for n in ("SCI", "PHANTOM")}

        def as_float(hdul):
            for name, values in physical.items():
                hdul[name].data = values

        rewrite_hdus(d / "int.fits", d / "flt.fits", as_float)
    return setup


def _integer_reduced(*names):
    """Setup: X-int.fits (uint16 SCI) and X-flt.fits (the same values as floats) per name."""
    def setup(d):
        for name in names:
            stem = name.removesuffix(".fits")
            with fits.open(d / name) as hdul:
                values = np.nan_to_num(np.round(hdul["SCI"].data) + 2000, nan=0.0)
            assert 0 <= values.min() and values.max() < 2**16

            def to_int(hdul, values=values):
                hdul["SCI"].data = values.astype(np.uint16)

            def to_float(hdul, values=values):
                hdul["SCI"].data = values.astype(np.float64)

            rewrite_hdus(d / name, d / f"{stem}-int.fits", to_int)
            rewrite_hdus(d / name, d / f"{stem}-flt.fits", to_float)
    return setup


def _lstsq_slopes(path):
    """Least-squares slope of every pixel over the frames, from the scaled FITS values."""
    with fits.open(path) as hdul:
        ramps = hdul["SCI"].data.astype(np.float64)  # astropy applies BSCALE/BZERO
        tframe = hdul[0].header["TFRAME"]
    n = ramps.shape[0]
    design = np.vstack([np.arange(n) * tframe, np.ones(n)]).T
    coef = np.linalg.lstsq(design, ramps.reshape(n, -1), rcond=None)[0]
    return coef[0].reshape(ramps.shape[1:]), np.abs(ramps).max() / tframe


def _check_fit_ramp(d, result, run):
    expected, scale = _lstsq_slopes(d / "int.fits")
    with fits.open(d / "out.fits") as hdul:
        np.testing.assert_allclose(hdul["SCI"].data, expected, rtol=0, atol=1e-5 * scale)


def _same_column_values(a, b):
    ta, tb = Table.read(a), Table.read(b)
    assert ta.colnames == tb.colnames and len(ta) == len(tb)
    for name in ta.colnames:
        if ta[name].dtype.kind == "f":
            np.testing.assert_allclose(np.asarray(ta[name]), np.asarray(tb[name]), rtol=1e-9,
                                       equal_nan=True, err_msg=name)


def _rerun(argv):
    def check(d, result, run):
        again = run(argv)
        assert again.rc == 0, again.describe()
        return again
    return check


def _check_same_fits(argv_float, out, out_float):
    def check(d, result, run):
        _rerun(argv_float)(d, result, run)
        with fits.open(d / out) as a, fits.open(d / out_float) as b:
            np.testing.assert_allclose(a["SCI"].data, b["SCI"].data, rtol=1e-6, equal_nan=True)
    return check


def _check_same_table(argv_float, out, out_float):
    def check(d, result, run):
        _rerun(argv_float)(d, result, run)
        _same_column_values(d / out, d / out_float)
    return check


INTEGER_DATA = [
    works("reduce-uint16-bzero-fit-ramp", ["reduce", "int.fits", "-c", "fit.yaml", "-o",
          "out.fits"], _integer_raw("uint16"), _check_fit_ramp),
    works("reduce-int16-bscale-fit-ramp", ["reduce", "int.fits", "-c", "fit.yaml", "-o",
          "out.fits"], _integer_raw("int16"), _check_fit_ramp),
    works("reduce-uint16-bzero-unchop", ["reduce", "int.fits", "-c", "unchop", "-o", "out.fits"],
          _integer_raw("uint16"),
          _check_same_fits(["reduce", "flt.fits", "-c", "unchop", "-o", "ref.fits"],
                           "out.fits", "ref.fits")),
    works("fit-noise-uint16-bzero", ["fit-noise", "int.fits", "-o", "fit.ecsv"],
          _integer_raw("uint16"),
          _check_same_table(["fit-noise", "flt.fits", "-o", "ref.ecsv"], "fit.ecsv", "ref.ecsv")),
    works("spectrum-uint16-bzero", ["spectrum", "red-int.fits", "-o", "sp.ecsv"],
          _integer_reduced("red.fits"),
          _check_same_table(["spectrum", "red-flt.fits", "-o", "ref.ecsv"], "sp.ecsv",
                            "ref.ecsv")),
    works("combine-uint16-bzero", ["combine", "red-int.fits", "red2-int.fits", "-o", "m.fits"],
          _integer_reduced("red.fits", "red2.fits"),
          _check_same_fits(["combine", "red-flt.fits", "red2-flt.fits", "-o", "ref.fits"],
                           "m.fits", "ref.fits")),
]


# -- a DQ written by other software: a 2-D pixel mask over 3-D ramps ------------------------------

def _with_dq(src, dst, mask, foreign=True):
    """Copy ``src`` to ``dst`` with a ``DQ`` extension ``mask`` (and, for a file as other
    software writes it, without the ``READOUT`` table)."""
    def change(hdul):
        if foreign:
            del hdul["READOUT"]
        hdul.insert(2, fits.ImageHDU(mask, name="DQ"))
    rewrite_hdus(src, dst, change)


def _dq_setup(shape, dtype=np.uint32):
    """Setup: lab.fits, raw.fits without READOUT and with a DQ of ``shape`` (bits 0 and 3 at
    rows 10 and 40, bit 2 alone at row 21), and lab-copy.fits to compare its bytes with."""
    def setup(d):
        mask = np.zeros(shape, dtype)
        if shape == (64, 64):
            mask[10, 5] = mask[40, 33] = 1 | 8
            mask[21, 7] = 4
        _with_dq(d / "raw.fits", d / "lab.fits", mask)
        shutil.copyfile(d / "lab.fits", d / "lab-copy.fits")
    return setup


def _check_foreign_dq(d, result, run):
    """Every read of rows 10 and 40 (bits 0 and 3) masked, row 21 (bit 2) too except with
    --dq-bits 9;
    the other slopes are numpy's least squares; lab.fits unchanged."""
    with fits.open(d / "raw.fits") as hdul:
        rows = np.asarray(hdul["READOUT"].data["row"])
    expected, scale = _lstsq_slopes(d / "lab.fits")
    for out, cells in (("out.fits", [(10, 5), (40, 33), (21, 7)]),
                       ("out9.fits", [(10, 5), (40, 33)])):
        if out == "out9.fits":
            again = run(["reduce", "lab.fits", "-c", "fit.yaml", "-o", out, "--dq-bits", "9"])
            assert again.rc == 0, again.describe()
        masked = np.zeros(expected.shape, bool)
        for r, c in cells:
            masked[rows == r, c] = True
        assert not any(masked[r, c] for r, c in cells)  # chopped: read i is not row i
        with fits.open(d / out) as hdul:
            slopes = hdul["SCI"].data
        assert np.isnan(slopes[masked]).all() and np.isfinite(slopes[~masked]).all()
        np.testing.assert_allclose(slopes[~masked], expected[~masked], rtol=0,
                                   atol=1e-5 * scale)
    assert (d / "lab.fits").read_bytes() == (d / "lab-copy.fits").read_bytes()


FOREIGN_DQ = [
    works("reduce-2d-dq-over-3d-sci", ["reduce", "lab.fits", "-c", "fit.yaml", "-o", "out.fits"],
          _dq_setup((64, 64)), _check_foreign_dq),
    refused("reduce-dq-shape-disagrees", ["reduce", "lab.fits", "-c", "fit.yaml", "-o",
                                          "out.fits"], _dq_setup((10, 64)),
            mentions=r"DQ has shape \(10, 64\), SCI has shape \(3, \d+, 64\)"),
    refused("reduce-dq-float", ["reduce", "lab.fits", "-c", "fit.yaml", "-o", "out.fits"],
            _dq_setup((64, 64), np.float32), mentions="DQ"),
    refused("reduce-dq-bits-negative", [*REDUCE, "--dq-bits", "-1"], mentions="dq-bits"),
    refused("reduce-dq-bits-33-bits", [*REDUCE, "--dq-bits", "0x100000000"], mentions="dq-bits"),
]


def _split_reads(numbers=(1, 2, 10), change=None):
    """Setup: frame ``k`` of ``raw.fits`` (its SCI and PHANTOM) into ``read_{numbers[k]}.fits``,
    each with the primary header and the READOUT table; ``change(k, hdul)`` before writing."""
    def setup(d):
        with fits.open(d / "raw.fits") as hdul:
            header = hdul[0].header.copy()
            for key in ("NEXTEND", "CHECKSUM", "DATASUM"):
                header.remove(key, ignore_missing=True)
            for k, n in enumerate(numbers):
                hdus = fits.HDUList([fits.PrimaryHDU(header=header),
                                     fits.ImageHDU(hdul["SCI"].data[k], name="SCI"),
                                     fits.ImageHDU(hdul["PHANTOM"].data[k], name="PHANTOM"),
                                     hdul["READOUT"].copy()])
                if change is not None:
                    change(k, hdus)
                hdus.writeto(d / f"read_{n}.fits", checksum=True)
    return setup


def _crop_second(k, hdul):
    if k == 1:
        hdul["SCI"].data = hdul["SCI"].data[:, :32]


def _check_reads_as_raw(d, result, run):
    """The read files reduce as raw.fits does (same pipeline), bit for bit."""
    again = run(["reduce", "raw.fits", "-c", "spherex-default", "-o", "one.fits"])
    assert again.rc == 0, again.describe()
    with fits.open(d / "out.fits") as a, fits.open(d / "one.fits") as b:
        np.testing.assert_array_equal(a["SCI"].data, b["SCI"].data)
        assert a[0].header["NFRAMES"] == 3 and a[0].header["S_PHANTM"] == "COMPLETE"


READS = ["reduce", "--reads", "read_*.fits", "-c", "spherex-default", "-o", "out.fits"]
READ_FILES = [
    works("reduce-reads-files-as-one-ramp", READS, _split_reads(), _check_reads_as_raw),
    refused("reduce-reads-match-no-file", READS, mentions="matches no file"),
    refused("reduce-reads-one-file", READS, _split_reads((1,)), mentions="one file"),
    refused("reduce-reads-shapes-differ", READS, _split_reads(change=_crop_second),
            mentions="read_2.fits"),
    refused("reduce-reads-truncated-file", READS,
            chain(_split_reads(), cut_data("read_10.fits", "SCI")), mentions="read_10.fits"),
    refused("reduce-reads-and-an-input", ["reduce", "raw.fits", *READS[1:]], mentions="--reads"),
    refused("reduce-no-input", ["reduce", "-c", "spherex-default", "-o", "out.fits"],
            mentions="--reads"),
]


# -- YAML ----------------------------------------------------------------------------------------

NOT_UTF8 = b"steps:\n  - unchop: {}\nname: caf\xe9 \xff\xfe\n"
BOMB_NAME = billion_laughs("name") + "\nsteps:\n  - unchop: {}\n"
BOMB_DESCRIPTION = billion_laughs("description") + "\nsteps:\n  - unchop: {}\n"
BOMB_SCENE = "noise: {" + billion_laughs("components") + "}\n"
BOMB_SWEEP = ("pipeline: {" + billion_laughs("description") + ", steps: [{fit_ramp: {}}]}\n"
              "scene: scene.yaml\ngrid: {skip: [1]}\n")


def scene(extra):
    """Setup: bad.yaml = the session's scene plus ``extra`` (YAML text)."""
    def setup(d):
        (d / "bad.yaml").write_text(SCENE + extra)
    return setup


def scene_with(section, text):
    """Setup: bad.yaml = the session's scene with ``text`` added to flow mapping ``section``."""
    def setup(d):
        lines = []
        for line in SCENE.splitlines():
            if line.startswith(f"{section}: {{"):
                line = line[:-1] + f", {text}}}"
            lines.append(line)
        if not any(line.startswith(f"{section}:") for line in lines):
            lines.append(f"{section}: {{{text}}}")
        (d / "bad.yaml").write_text("\n".join(lines) + "\n")
    return setup


def scene_replace(old, new):
    """Setup: bad.yaml = the session's scene with ``old`` replaced by ``new``."""
    def setup(d):
        assert old in SCENE
        (d / "bad.yaml").write_text(SCENE.replace(old, new))
    return setup


SIMULATE_BAD = ["simulate", "bad.yaml", "-o", "out.fits"]
REDUCE_BAD = ["reduce", "raw.fits", "-c", "bad.yaml", "-o", "out.fits"]

YAML = [
    refused("reduce-config-not-utf8", REDUCE_BAD, write("bad.yaml", NOT_UTF8)),
    refused("show-config-not-utf8", ["show-config", "bad.yaml"], write("bad.yaml", NOT_UTF8)),
    refused("simulate-scene-not-utf8", SIMULATE_BAD, write("bad.yaml", NOT_UTF8)),
    refused("readout-config-not-utf8", ["readout", "--config", "bad.yaml"],
            write("bad.yaml", NOT_UTF8)),
    refused("sweep-file-not-utf8", ["sweep", "bad.yaml", "-o", "new.ecsv", *SERIAL],
            write("bad.yaml", NOT_UTF8)),
    refused("reduce-fits-file-as-config", ["reduce", "red.fits", "-c", "raw.fits", "-o",
                                           "out.fits"]),
    refused("simulate-fits-file-as-scene", ["simulate", "raw.fits", "-o", "out.fits"]),
    refused("readout-fits-file-as-config", ["readout", "--config", "raw.fits"]),
    refused("show-config-alias-bomb-in-name", ["show-config", "bad.yaml"],
            write("bad.yaml", BOMB_NAME)),
    refused("reduce-config-alias-bomb-in-description", REDUCE_BAD,
            write("bad.yaml", BOMB_DESCRIPTION)),
    refused("simulate-scene-alias-bomb", SIMULATE_BAD, write("bad.yaml", BOMB_SCENE)),
    refused("sweep-alias-bomb-in-pipeline", ["sweep", "bad.yaml", "-o", "new.ecsv", *SERIAL],
            write("bad.yaml", BOMB_SWEEP)),
    refused("show-config-5000-deep-list", ["show-config", "bad.yaml"],
            write("bad.yaml", deep_list("steps"))),
    refused("simulate-scene-5000-deep-list", SIMULATE_BAD, write("bad.yaml", deep_list("noise"))),
    refused("reduce-config-not-yaml", REDUCE_BAD, write("bad.yaml", "steps: [unchop\n")),
    refused("reduce-config-duplicate-key", REDUCE_BAD,
            write("bad.yaml", "steps:\n  - unchop: {}\nsteps:\n  - fit_ramp: {}\n"),
            mentions="steps"),
    refused("show-config-duplicate-step-parameter", ["show-config", "bad.yaml"],
            write("bad.yaml", "steps:\n  - correct_reference: {sigma: 3.0, sigma: 4.0}\n"),
            mentions="sigma"),
    refused("simulate-scene-duplicate-key", SIMULATE_BAD, scene("seed: 2\n"), mentions="seed"),
    refused("reduce-config-sigma-nan", REDUCE_BAD,
            write("bad.yaml", DEFAULT_STEPS + "  - sigma_clip: {sigma: .nan}\n"),
            mentions="sigma"),
    refused("show-config-readout-frame-time-nan", ["show-config", "bad.yaml"],
            write("bad.yaml", "readout: {frame_time: .nan}\nsteps:\n  - unchop: {}\n"),
            mentions="frame_time"),
    refused("simulate-frame-time-nan", SIMULATE_BAD,
            scene_replace("frame_overhead: 10", "frame_time: .nan"),
            mentions="frame_time"),
    refused("simulate-pixel-rate-zero", SIMULATE_BAD, scene_with("geometry", "pixel_rate: 0"),
            mentions="pixel_rate"),
    refused("simulate-photocurrent-nan", SIMULATE_BAD, scene_with("scene", "photocurrent: .nan"),
            mentions="photocurrent"),
    refused("simulate-dark-current-inf", SIMULATE_BAD, scene_with("scene", "dark_current: .inf"),
            mentions="dark_current"),
    refused("simulate-leakage-minus-1e300", SIMULATE_BAD, scene_with("scene", "leakage: -1.0e+300"),
            mentions="leakage"),
    refused("simulate-one-frame-slopes", [*SIMULATE_BAD, "--mode", "slopes"],
            scene_with("readout", "nframes: 1"), mentions="nframes"),
    refused("simulate-nframes-1e12", SIMULATE_BAD, scene_with("readout", "nframes: 1000000000000")),
    refused("simulate-padding-1e12", SIMULATE_BAD, scene_with("synthesis", "padding: 1.0e+12")),
    refused("simulate-frame-time-1e12", SIMULATE_BAD,
            scene_replace("frame_overhead: 10", "frame_time: 1.0e+12")),
    refused("sweep-realizations-1e11", ["sweep", "bad.yaml", "-o", "new.ecsv", *SERIAL],
            write("bad.yaml", SWEEP.replace("realizations: 1", "realizations: 100000000000")),
            mentions="realizations"),
]


# -- numbers on the command line ----------------------------------------------------------------

def _all_zero_raw(d):
    def change(hdul):
        for name in ("SCI", "PHANTOM"):
            hdul[name].data = np.zeros_like(hdul[name].data)
    rewrite_hdus(d / "raw.fits", d / "zero.fits", change)


CLI_NUMBERS = [
    *[refused(f"spectrum-{opt}-{value}", [*SPECTRUM, f"--{opt}", value],
              mentions=opt.replace("-", "[-_ ]"))
      for opt in ("pixel-scale", "photocurrent", "integration-time") for value in ("nan", "inf")],
    refused("spectrum-bins-1e8", [*SPECTRUM, "--bins", "100000000"], mentions="bins"),
    refused("combine-sigma-negative", [*COMBINE, "--sigma", "-1"], mentions="sigma"),
    refused("combine-sigma-nan", [*COMBINE, "--sigma", "nan"], mentions="sigma"),
    refused("fit-noise-exponent-nan", [*FIT_NOISE, "--exponent", "nan"], mentions="exponent"),
    refused("fit-noise-exponent-inf", [*FIT_NOISE, "--exponent", "inf"], mentions="exponent"),
    refused("fit-noise-nbins-1e8", [*FIT_NOISE, "--nbins", "100000000"], mentions="nbins"),
    refused("fit-noise-all-zero-data", ["fit-noise", "zero.fits", "-o", "fit.ecsv"],
            _all_zero_raw),
    refused("figures-realizations-zero", ["figures", "-o", "figs", "--quick",
                                          "--realizations", "0"], mentions="realizations"),
    refused("figures-workers-negative", ["figures", "-o", "figs", "--workers", "-1"],
            mentions="workers"),
    refused("figures-workers-zero", ["figures", "-o", "figs", "--workers", "0"],
            mentions="workers"),
    refused("figures-scheduler-not-a-url", ["figures", "-o", "figs", "--scheduler", "not a url"],
            mentions="scheduler"),
    refused("sweep-scheduler-not-a-url", ["sweep", "sweep.yaml", "-o", "new.ecsv",
                                          "--scheduler", "not a url"], mentions="scheduler"),
    refused("sweep-scheduler-unreachable", ["sweep", "sweep.yaml", "-o", "new.ecsv",
                                            "--scheduler", "tcp://127.0.0.1:9"],
            mentions="scheduler|127.0.0.1", timeout=60, marks=pytest.mark.slow),
    refused("readout-nrows-3e8", ["readout", "--nrows", "300000000"]),
    refused("readout-frame-time-nan", ["readout", "--frame-time", "nan"],
            mentions="frame[-_ ]time"),
    refused("readout-pixel-rate-zero", ["readout", "--pixel-rate", "0"],
            mentions="pixel[-_ ]rate"),
    refused("demo-size-huge", ["demo", "-o", "d", "--size", "1048576"]),
]


# -- an output must never be an input ----------------------------------------------------------

DARK_CONFIG = DEFAULT_STEPS + "  - subtract_dark: {dark: red2.fits}\n"

OUTPUT_IS_INPUT = [
    refused("reduce-output-is-input", ["reduce", "raw.fits", "-c", "spherex-default", "-o",
                                       "raw.fits", "--overwrite"]),
    refused("reduce-output-is-input-dot-slash", ["reduce", "raw.fits", "-c", "spherex-default",
                                                 "-o", "./raw.fits", "--overwrite"]),
    refused("reduce-output-is-input-absolute", ["reduce", "raw.fits", "-c", "spherex-default",
                                                "-o", "{dir}/raw.fits", "--overwrite"]),
    refused("reduce-output-is-input-dot-dot", ["reduce", "raw.fits", "-c", "spherex-default",
                                               "-o", "sub/../raw.fits", "--overwrite"],
            mkdir("sub")),
    refused("reduce-output-is-input-via-symlink", ["reduce", "lnk.fits", "-c", "spherex-default",
                                                   "-o", "raw.fits", "--overwrite"],
            link("lnk.fits", "raw.fits")),
    refused("reduce-output-is-symlink-to-input", ["reduce", "raw.fits", "-c", "spherex-default",
                                                  "-o", "lnk.fits", "--overwrite"],
            link("lnk.fits", "raw.fits")),
    refused("reduce-output-is-pipeline-config", ["reduce", "raw.fits", "-c", "fit.yaml", "-o",
                                                 "fit.yaml", "--overwrite"]),
    refused("reduce-output-is-dark", ["reduce", "raw.fits", "-c", "dark.yaml", "-o",
                                      "red2.fits", "--overwrite"],
            write("dark.yaml", DARK_CONFIG)),
    refused("simulate-output-is-scene", ["simulate", "scene.yaml", "-o", "scene.yaml",
                                         "--overwrite"]),
    refused("spectrum-output-is-input", ["spectrum", "red.fits", "-o", "red.fits",
                                         "--overwrite"]),
    refused("spectrum-output-is-input-via-symlink", ["spectrum", "lnk.fits", "-o", "red.fits",
                                                     "--overwrite"],
            link("lnk.fits", "red.fits")),
    refused("spectrum-plot-is-input", [*SPECTRUM, "--plot", "red.fits", "--overwrite"]),
    refused("spectrum-output-is-compare", ["spectrum", "red.fits", "--compare", "red2.fits",
                                           "-o", "red2.fits", "--overwrite"]),
    refused("combine-output-is-input", ["combine", "red.fits", "red2.fits", "-o",
                                        "./red2.fits", "--overwrite"]),
    refused("fit-noise-output-is-input", ["fit-noise", "raw.fits", "-o", "{dir}/raw.fits",
                                          "--overwrite"]),
    refused("fit-noise-plot-is-input", [*FIT_NOISE, "--plot", "raw.fits", "--overwrite"]),
    refused("readout-output-is-config", ["readout", "--config", "scene.yaml", "-o",
                                         "scene.yaml", "--overwrite"]),
    refused("readout-plot-is-config", ["readout", "--config", "scene.yaml", "--plot",
                                       "scene.yaml", "--overwrite"]),
    refused("sweep-output-is-sweep-file", ["sweep", "sweep.yaml", "-o", "sweep.yaml",
                                           "--overwrite", *SERIAL]),
    refused("sweep-output-is-its-scene", ["sweep", "bad.yaml", "-o", "scene.yaml",
                                          "--overwrite", *SERIAL],
            write("bad.yaml", "scene: scene.yaml\npipeline: spherex-default\n"
                              "grid: {skip: [1]}\n")),
    refused("sweep-plot-is-sweep-file", ["sweep", "sweep.yaml", "-o", "new.ecsv", "--plot",
                                         "sweep.yaml", "--overwrite", *SERIAL]),
]


# -- where outputs go ----------------------------------------------------------------------------

def _damage_results(kind):
    def setup(d):
        path = d / "res.ecsv"
        if kind == "truncated":
            _probe.cut(path, len(path.read_bytes()) // 2)
        else:
            path.write_bytes(bytes(range(256)) * 8)
    return setup


OUTPUT_PLACES = [
    refused("reduce-output-existing-dir-overwrite", [*REDUCE[:-1], "outdir", "--overwrite"],
            mkdir("outdir")),
    refused("reduce-output-trailing-slash", [*REDUCE[:-1], "out/"]),
    refused("simulate-output-trailing-slash", ["simulate", "scene.yaml", "-o", "out/"]),
    refused("spectrum-output-existing-dir-overwrite", [*SPECTRUM[:-1], "outdir", "--overwrite"],
            mkdir("outdir")),
    refused("sweep-damaged-results-truncated", ["sweep", "sweep.yaml", "-o", "res.ecsv", *SERIAL],
            _damage_results("truncated")),
    refused("sweep-damaged-results-garbage", ["sweep", "sweep.yaml", "-o", "res.ecsv", *SERIAL],
            _damage_results("garbage")),
]


# -- -c PIPELINE.yaml of fit-noise and spectrum ---------------------------------------------------

#: The session's schedule as a pipeline config (what a file stripped of its keywords lacks).
LAB = """\
geometry: {nrows: 64, ncols: 64, nchannels: 2, ref_border: 4, pixel_rate: 100000.0}
readout: {skip: 4, ref_reads: 4, ref_mode: distributed, phantom_reads: 2, nframes: 3,
          frame_overhead: 10}
steps:
  - unchop: {}
"""


def _stripped(name, bare="bare.fits"):
    """Setup: ``bare`` = ``name`` without any geometry or readout keyword or READOUT table,
    and ``lab.yaml`` = `LAB`."""
    def setup(d):
        from spherex_reduce.core.fields import FIELDS

        def strip(hdul):
            del hdul["READOUT"]
            for hdu in hdul:
                for key in [f.keyword for f in FIELDS] + ["NEXTEND"]:
                    hdu.header.remove(key, ignore_missing=True)

        rewrite_hdus(d / name, d / bare, strip)
        (d / "lab.yaml").write_text(LAB)
    return setup


def _small_image(d):
    hdu = fits.PrimaryHDU(np.random.default_rng(0).normal(0, 1, (32, 32)))
    hdu.header["BUNIT"] = "electron / s"
    hdu.writeto(d / "small.fits")


def _check_band_missing(d, result, run):
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("spherex-reduce spectrum: warning: "), \
        result.describe()
    assert "small.fits" in lines[0] and "0.03 <= k <= 0.13" in lines[0], lines[0]
    t = Table.read(d / "sp.ecsv")
    assert len(t) > 0 and t.meta["band_power"] is None and t.meta["band_power_err"] is None
    assert "no Fourier mode" in t.meta["band_power_missing"]
    assert "missing" in result.stdout


FIT_NOISE_C = [*FIT_NOISE, "-c", "bad.yaml"]
SPECTRUM_C = [*SPECTRUM, "-c", "bad.yaml"]

INPUT_CONFIG = [
    refused("fit-noise-config-missing-file", [*FIT_NOISE, "-c", "none.yaml"],
            mentions="none.yaml"),
    refused("spectrum-config-missing-file", [*SPECTRUM, "-c", "none.yaml"], mentions="none.yaml"),
    refused("spectrum-config-no-such-shipped-name", [*SPECTRUM, "-c", "nosuchconfig"],
            mentions="nosuchconfig"),
    refused("fit-noise-config-not-a-mapping", FIT_NOISE_C, write("bad.yaml", "- 1\n- 2\n"),
            mentions="mapping"),
    refused("spectrum-config-not-a-mapping", SPECTRUM_C, write("bad.yaml", "- 1\n- 2\n"),
            mentions="mapping"),
    refused("spectrum-config-not-utf8", SPECTRUM_C, write("bad.yaml", NOT_UTF8)),
    refused("fit-noise-config-not-yaml", FIT_NOISE_C, write("bad.yaml", "steps: [unchop\n")),
    refused("spectrum-config-unknown-step", SPECTRUM_C,
            write("bad.yaml", "steps:\n  - nosuchstep: {}\n"), mentions="nosuchstep"),
    refused("fit-noise-config-readout-frame-time-nan", FIT_NOISE_C,
            write("bad.yaml", "readout: {frame_time: .nan}\nsteps:\n  - unchop: {}\n"),
            mentions="frame_time"),
    refused("spectrum-fits-file-as-config", [*SPECTRUM, "-c", "raw.fits"]),
    refused("fit-noise-config-wrong-geometry", ["fit-noise", "bare.fits", "-c", "bad.yaml", "-o",
                                                "fit.ecsv"],
            lambda d: (_stripped("raw.fits")(d),
                       (d / "bad.yaml").write_text(LAB.replace("nrows: 64", "nrows: 128")))),
    refused("fit-noise-stripped-without-config", ["fit-noise", "bare.fits", "-o", "fit.ecsv"],
            _stripped("raw.fits"), mentions="missing readout keyword"),
    refused("spectrum-output-is-config", ["spectrum", "red.fits", "-c", "fit.yaml", "-o",
                                          "fit.yaml", "--overwrite"]),
    refused("fit-noise-output-is-config", ["fit-noise", "raw.fits", "-c", "fit.yaml", "-o",
                                           "fit.yaml", "--overwrite"]),
    refused("fit-noise-plot-is-config", [*FIT_NOISE, "-c", "fit.yaml", "--plot", "fit.yaml",
                                         "--overwrite"]),
    refused("spectrum-output-is-file-config-names", ["spectrum", "red.fits", "-c", "dark.yaml",
                                                     "-o", "red2.fits", "--overwrite"],
            write("dark.yaml", DARK_CONFIG)),
    works("fit-noise-config-supplies-stripped-keywords",
          ["fit-noise", "bare.fits", "-c", "lab.yaml", "-o", "fit.ecsv"], _stripped("raw.fits"),
          _check_same_table([*FIT_NOISE[:-1], "ref.ecsv"], "fit.ecsv", "ref.ecsv")),
    works("spectrum-config-supplies-stripped-keywords",
          ["spectrum", "bare.fits", "-c", "lab.yaml", "-o", "sp.ecsv"], _stripped("red.fits"),
          _check_same_table([*SPECTRUM[:-1], "ref.ecsv"], "sp.ecsv", "ref.ecsv")),
    works("spectrum-small-image-band-missing", ["spectrum", "small.fits", "-o", "sp.ecsv"],
          _small_image, _check_band_missing),
]


# -- the input: section of a pipeline config ------------------------------------------------------

def _input_yaml(section):
    return write("bad.yaml", f"input: {section}\nsteps:\n  - fit_ramp: {{weighting: uniform}}\n")


def _check_gain_two(d, result, run):
    expected, scale = _lstsq_slopes(d / "int.fits")
    with fits.open(d / "out.fits") as hdul:
        assert hdul[0].header["BUNIT"] == "electron / s" and hdul[0].header["GAIN"] == 2.0
        np.testing.assert_allclose(hdul["SCI"].data, 2 * expected, rtol=0, atol=2e-5 * scale)


INPUT_SECTION = [
    refused("reduce-input-gain-zero", REDUCE_BAD, _input_yaml("{gain: 0}"),
            mentions=r"input\.gain: must be > 0, got 0"),
    refused("reduce-input-gain-negative", REDUCE_BAD, _input_yaml("{gain: -1.8}"),
            mentions=r"input\.gain: must be > 0"),
    refused("reduce-input-gain-per-channel-count", REDUCE_BAD, _input_yaml("{gain: [1, 2, 3]}"),
            mentions=r"input\.gain: 3 values for 2 readout channels"),
    refused("reduce-input-unknown-key", REDUCE_BAD, _input_yaml("{gian: 2}"),
            mentions=r"input\.gian: unknown parameter"),
    refused("reduce-input-header-not-a-choice", REDUCE_BAD, _input_yaml("{header: merge}"),
            mentions=r"input\.header"),
    refused("reduce-input-drop-all-reads", REDUCE_BAD, _input_yaml("{drop_first_reads: 2}"),
            mentions="at least 2 frames must remain"),
    refused("reduce-input-fill-disagrees-with-file", REDUCE_BAD,
            write("bad.yaml", "geometry: {nrows: 128}\nsteps:\n  - fit_ramp: {}\n"),
            mentions="keyword NROWS is 64 in the file but nrows is 128 in the config"),
    refused("spectrum-input-gain-on-electrons", SPECTRUM_C, _input_yaml("{gain: 2.0}"),
            mentions="input.gain converts ADU to electrons"),
    refused("fit-noise-input-unit-disagrees", FIT_NOISE_C, _input_yaml("{unit: adu}"),
            mentions="keyword BUNIT is 'electron' in the file but unit is 'adu'"),
    works("reduce-uint16-input-gain", ["reduce", "int.fits", "-c", "gain.yaml", "-o", "out.fits"],
          chain(_integer_raw("uint16"),
                write("gain.yaml", "input: {unit: adu, gain: 2.0, header: override}\n"
                                   "steps:\n  - fit_ramp: {weighting: uniform}\n")),
          _check_gain_two),
]


# -- what the user sees besides errors -----------------------------------------------------------

def _warning_text(line):
    line = re.sub(r"^WARNING(:| astropy:)\s*", "", line.strip())
    return re.sub(r"\s*\[[\w.]+\]$", "", line)


def _check_warnings_once(d, result, run):
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    assert not [line for line in lines if line[0].isspace() or re.search(r"\.py:\d+:", line)], \
        "warnings show source lines"
    texts = [_warning_text(line) for line in lines]
    assert len(texts) == len(set(texts)), "a warning is printed more than once"


MESSAGES = [
    works("combine-warnings-once", COMBINE, check=_check_warnings_once),
]


# == round two: the features added since the first probe (issue "Faults and hostile input, round
# two").  Each list holds the cases of one part; each case failed on the code before its fix.

# -- round two: reads given as files, and names that cannot go into a FITS card -------------------

def _rowskip_in_second(k, hdul):
    """ROWSKIP 8 in read_2.fits, with the READOUT table of that readout (a file that agrees
    with itself, not with read_1.fits)."""
    from spherex_reduce.core.readout.schedule import ReadoutSchedule

    if k == 1:
        hdul[0].header["ROWSKIP"] = 8
        table = fits.table_to_hdu(ReadoutSchedule.from_header(hdul[0].header).to_table())
        table.name = "READOUT"
        hdul[3] = table


def _frame_overhead_in_third(k, hdul):
    """FRMOVH 12 (and no TFRAME, no READOUT table) in read_10.fits."""
    if k == 2:
        hdul[0].header["FRMOVH"] = 12
        del hdul[0].header["TFRAME"]
        del hdul[3]


def _copy(src, dst):
    def setup(d):
        shutil.copyfile(d / src, d / dst)
    return setup


def _check_names(out, history=(), cards=()):
    """``out`` written, with each name recorded so that it decodes back exactly: in a
    ``HISTORY`` line (``(pattern, name)``: the pattern's group is the recorded name) or a card
    (``(keyword, name)``)."""
    def check(d, result, run):
        from spherex_reduce.io.header_text import name_from_header

        with fits.open(d / out) as hdul:
            header = hdul[0].header
            assert hdul["SCI"].data.ndim == 2  # slopes (in readout order after fit_ramp alone)
        lines = [str(line) for line in header.get("HISTORY", [])]
        for pattern, name in history:
            found = [name_from_header(m.group(1)) for line in lines
                     if (m := re.match(pattern, line))]
            assert name in found, (name, found, lines)
        for keyword, name in cards:
            assert name_from_header(header[keyword]) == name, (keyword, header[keyword])
    return check


def _check_reads_named(d, result, run):
    from spherex_reduce.io.header_text import name_from_header

    with fits.open(d / "out.fits") as hdul:
        lines = [str(h) for h in hdul[0].header["HISTORY"] if str(h).startswith("ramp of 3")]
    assert len(lines) == 1, lines
    first, last = lines[0].split(": ", 1)[1].split(" ... ")
    assert (name_from_header(first), name_from_header(last)) == ("réad_1.fits", "réad_10.fits")


def _non_ascii_reads(d):
    _split_reads()(d)
    for n in (1, 2, 10):
        (d / f"read_{n}.fits").rename(d / f"réad_{n}.fits")


def _noise_table(name):
    def setup(d):
        import importlib.resources

        source = importlib.resources.files("spherex_reduce") / "data" / "spherex-table2.ecsv"
        (d / name).write_bytes(source.read_bytes())
        (d / "w.yaml").write_text("steps:\n  - unchop: {}\n  - correct_reference: {strategy: "
                                  f"wiener, noise: {name}, domain: slopes}}\n"
                                  "  - fit_ramp: {weighting: uniform}\n")
    return setup


NEWLINE_YAML = "fit\nramp.yaml"
PIPELINE = r"pipeline (\S+?): \{"

ROUND2_READS_AND_NAMES = [
    refused("reduce-reads-superscript-digit", READS, _split_reads((1, "1²1", 3)),
            mentions=r"read_1²1\.fits.*ASCII"),
    refused("reduce-reads-full-width-digit", READS, _split_reads((1, "１", 3)),
            mentions=r"read_１\.fits.*ASCII"),
    refused("reduce-reads-duplicate-read-number", READS, _split_reads((1, 2, "02")),
            mentions=r"read_2\.fits and read_02\.fits|read_02\.fits and read_2\.fits"),
    # the same, the names differing also in their suffixes (a compressed copy, upper case)
    refused("reduce-reads-duplicate-read-number-other-suffix",
            ["reduce", "--reads", "read_*", "-c", "spherex-default", "-o", "out.fits"],
            chain(_split_reads((1, 2, "02")),
                  lambda d: (d / "read_02.fits").rename(d / "read_02.FITS")),
            mentions=r"read_0?2\.fits and read_0?2\.FITS|read_02\.FITS and read_2\.fits"),
    refused("reduce-reads-rowskip-differs", READS, _split_reads(change=_rowskip_in_second),
            mentions=r"read_2\.fits: keyword ROWSKIP is 8, but read_1\.fits has 4"),
    refused("reduce-reads-frame-overhead-differs", READS,
            _split_reads(change=_frame_overhead_in_third),
            mentions=r"read_10\.fits: keyword FRMOVH is 12, but read_1\.fits has 10"),
    works("reduce-reads-names-non-ascii", [*READS[:2], "réad_*.fits", *READS[3:]],
          _non_ascii_reads, _check_reads_named),
    works("reduce-config-name-non-ascii", ["reduce", "raw.fits", "-c", "é.yaml", "-o", "out.fits"],
          _copy("fit.yaml", "é.yaml"), _check_names("out.fits", [(PIPELINE, "é.yaml")])),
    works("reduce-config-name-newline", ["reduce", "raw.fits", "-c", NEWLINE_YAML, "-o",
                                         "out.fits"],
          _copy("fit.yaml", NEWLINE_YAML),
          _check_names("out.fits", [(PIPELINE, NEWLINE_YAML)])),
    works("reduce-dark-name-non-ascii", ["reduce", "raw.fits", "-c", "dark.yaml", "-o",
                                         "out.fits"],
          chain(_copy("red2.fits", "dàrk.fits"),
                write("dark.yaml", DEFAULT_STEPS + "  - subtract_dark: {dark: dàrk.fits}\n")),
          _check_names("out.fits", cards=[("DARKFILE", "dàrk.fits"),
                                          ("HIERARCH SXR SUBTRACT_DARK DARK", "dàrk.fits")])),
    works("reduce-noise-file-name-non-ascii", ["reduce", "raw.fits", "-c", "w.yaml", "-o",
                                               "out.fits"],
          _noise_table("brüit.ecsv"),
          _check_names("out.fits", cards=[("HIERARCH SXR CORRECT_REFERENCE NOISE",
                                           "brüit.ecsv")])),
    works("reduce-foreign-dq-name-non-ascii", ["reduce", "lâb.fits", "-c", "fit.yaml", "-o",
                                               "out.fits"],
          chain(_dq_setup((64, 64)), _copy("lab.fits", "lâb.fits")),
          _check_names("out.fits", [(r"DQ of (\S+) not written", "lâb.fits")])),
    works("reduce-checksum-ignored-name-non-ascii", ["reduce", "rãw.fits", "-c", "fit.yaml",
                                                     "-o", "out.fits", "--ignore-checksum"],
          chain(flip_sci("raw.fits"), _copy("raw.fits", "rãw.fits")),
          _check_names("out.fits", [(r"checksum of SCI in (\S+) did not", "rãw.fits")])),
    works("combine-input-name-non-ascii", ["combine", "rèd.fits", "red2.fits", "-o", "m.fits"],
          _copy("red.fits", "rèd.fits"),
          _check_names("m.fits", [(r"combine input: (\S+)$", "rèd.fits")])),
]


# -- round two: integrations (4-D), PROVENANCE of an input, files changed under us ----------------

def _four_d(integrations=2, extensions=None, phantom_4d=True):
    """Setup: uncal.fits, raw.fits as ``integrations`` integrations (a 4-D SCI, integration
    ``k`` the ramps times ``k + 1``) with a 4-D PHANTOM (or raw.fits' 3-D one); then
    ``extensions`` ``{name: integrations}``: a 4-D DQ (zeros), ERR (ones) or PHANTOM with that
    many."""
    def setup(d):
        def change(hdul):
            sci, phantom = hdul["SCI"].data, hdul["PHANTOM"].data
            some = max(integrations, 1)  # (0 integrations: a stack of one, cut to none)
            hdul["SCI"].data = np.stack([sci * (k + 1) for k in range(some)])[:integrations]
            if phantom_4d:
                hdul["PHANTOM"].data = np.stack([phantom] * some)[:integrations]
            for name, n in (extensions or {}).items():
                if name == "PHANTOM":
                    hdul["PHANTOM"].data = np.stack([phantom] * n)
                else:
                    fill = np.zeros if name == "DQ" else np.ones
                    hdul.insert(2, fits.ImageHDU(fill((n, *sci.shape),
                                                      np.uint32 if name == "DQ" else np.float32),
                                                 name=name))
            hdul[0].header.remove("NEXTEND", ignore_missing=True)
        rewrite_hdus(d / "raw.fits", d / "uncal.fits", change)
    return setup


def _damaged_provenance(name, kind):
    """Setup: add to ``name`` a PROVENANCE table (red.fits') whose ``elapsed`` is ``kind``:
    text, two numbers per row or variable-length arrays."""
    def setup(d):
        rows = Table.read(d / "red.fits", hdu="PROVENANCE")
        n = len(rows)
        elapsed = {"string": fits.Column("elapsed", "8A", array=np.array(["slow"] * n)),
                   "2d": fits.Column("elapsed", "2D", dim="(2)", array=np.ones((n, 2))),
                   "varlen": fits.Column("elapsed", "PD()", array=np.array(
                       [np.ones(k + 1) for k in range(n)], dtype=object))}[kind]
        cols = [fits.Column(c, f"{max(len(str(v)) for v in rows[c]) or 1}A",
                            array=np.array([str(v) for v in rows[c]]))
                for c in rows.colnames if c != "elapsed"]
        table = fits.BinTableHDU.from_columns([*cols[:5], elapsed, *cols[5:]], name="PROVENANCE")

        def change(hdul):
            hdul.append(table)
            hdul[0].header.remove("NEXTEND", ignore_missing=True)
        rewrite_hdus(d / name, d / name, change)
    return setup


UNCAL = ["reduce", "uncal.fits", "-c", "spherex-default", "-o", "out.fits"]
WHOLE = ["reduce", "lab.fits", "-c", "fit.yaml", "-o", "out.fits"]  # a DQ: read whole
PROVENANCE_DAMAGE = ("string", "2d", "varlen")

ROUND2_INTEGRATIONS = [
    refused("reduce-4d-zero-integrations", UNCAL, _four_d(0), mentions="no integration"),
    *[refused(f"reduce-4d-{name.lower()}-{which}-integrations", UNCAL,
              _four_d(sci, {name: other}),
              mentions=rf"{name} has shape \({other}, 3, 60, \d+\), SCI has shape "
                       rf"\({sci}, 3, 60, 64\)")
      for name in ("DQ", "ERR", "PHANTOM")
      for which, sci, other in (("fewer", 3, 2), ("more", 2, 3))],
    refused("reduce-4d-3d-phantom", UNCAL, _four_d(2, phantom_4d=False),
            mentions=r"PHANTOM has shape \(3, 60, 2\), SCI has shape \(2, 3, 60, 64\)"),
    *[refused(f"reduce-streamed-provenance-{kind}", REDUCE, _damaged_provenance("raw.fits", kind),
              mentions="raw.fits: table PROVENANCE.*elapsed") for kind in PROVENANCE_DAMAGE],
    *[refused(f"reduce-whole-provenance-{kind}", WHOLE,
              chain(_dq_setup((64, 64)), _damaged_provenance("lab.fits", kind)),
              mentions="lab.fits: table PROVENANCE.*elapsed") for kind in PROVENANCE_DAMAGE],
    *[refused(f"reduce-4d-provenance-{kind}", UNCAL,
              chain(_four_d(2), _damaged_provenance("uncal.fits", kind)),
              mentions="uncal.fits: table PROVENANCE.*elapsed") for kind in PROVENANCE_DAMAGE],
]


@pytest.mark.parametrize("kind", PROVENANCE_DAMAGE)
def test_batch_input_with_damaged_provenance(kind, inputs, runner, tmp_path):
    """In a batch, the input with a damaged PROVENANCE fails alone with one line naming it
    (exit 2, as for that file alone); the other input is reduced.  One kind runs without -q:
    the progress bar is not written to a stderr that is not a terminal."""
    d = tmp_path / "case"
    shutil.copytree(inputs, d, symlinks=True)
    shutil.copyfile(d / "raw.fits", d / "good.fits")
    _damaged_provenance("raw.fits", kind)(d)
    quiet = [] if kind == "string" else ["-q"]
    result = runner.run([*quiet, "reduce", "raw.fits", "good.fits", "-c", "spherex-default",
                         "-o", "outdir", *SERIAL], d)
    assert result.rc == 2 and "Traceback" not in result.stderr, result.describe()
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and ERROR_LINE.match(lines[0]), result.describe()
    assert re.search(r"raw\.fits: table PROVENANCE is damaged: column 'elapsed'", lines[0])
    assert (d / "outdir" / "good_reduced.fits").is_file()
    assert not (d / "outdir" / "raw_reduced.fits").exists()


#: Run in a child: reduce argv[1] with config argv[2] and change the file at a fixed point of
#: the run: once integration 0 of a 4-D file is reduced (from inside Pipeline.run), or once
#: the input of a file read whole is in memory (argv[3] "integration" or "source"): truncate
#: it to argv[4] bytes, or rewrite its bytes in place (argv[4] == "rewrite").
_CHANGED_UNDER_US = """\
import os, sys
from spherex_reduce import cli
from spherex_reduce.io import sources
from spherex_reduce.reduce.pipeline import Pipeline
path, config, when, how = sys.argv[1:5]

def change():
    if how == "rewrite":  # same size, other bytes: what a writer still at work does
        data = open(path, "rb").read()
        with open(path, "r+b") as f:
            f.write(data[:-8] + bytes(8))
        os.utime(path, ns=(0, os.stat(path).st_mtime_ns + 10**9))
    else:
        os.truncate(path, int(how))

def after(method):
    def changing(self, *args, **kwargs):
        out = method(self, *args, **kwargs)
        change()
        return out
    return changing

if when == "integration":
    Pipeline.run = after(Pipeline.run)
else:
    sources.MemorySource.__init__ = after(sources.MemorySource.__init__)
sys.exit(cli.main(["-q", "reduce", path, "-c", config, "-o", "out.fits"]))
"""


def _run_changing(d, path, config, when, how):
    import resource
    import subprocess
    import sys

    def limit():
        resource.setrlimit(resource.RLIMIT_AS, (_probe.MEMORY_LIMIT, _probe.MEMORY_LIMIT))

    return subprocess.run([sys.executable, "-c", _CHANGED_UNDER_US, path, config, when, how],
                          cwd=d, env=_probe.child_env(), capture_output=True, text=True,
                          timeout=_probe.TIMEOUT, preexec_fn=limit)


@pytest.mark.parametrize("how", ["truncate", "rewrite"])
def test_4d_input_changed_while_reduced(how, inputs, tmp_path):
    """A 4-D input truncated (or rewritten) between two integrations ends in one line, exit
    2, no output; before, its pixels were memory-mapped and the truncation killed the process
    with SIGBUS.  The change is made from inside the run (after integration 0's pipeline), so
    it always falls at the same point."""
    d = tmp_path / "case"
    shutil.copytree(inputs, d, symlinks=True)
    _four_d(4)(d)
    _, _, start, size = _probe.span(d / "uncal.fits", "SCI")
    cut = "rewrite" if how == "rewrite" else str(start + size // 4 + 100)  # in integration 1
    done = _run_changing(d, "uncal.fits", "spherex-default", "integration", cut)
    assert done.returncode == 2, (done.returncode, done.stderr[-2000:])
    lines = [line for line in done.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and ERROR_LINE.match(lines[0]), done.stderr
    assert "uncal.fits changed while it was read" in lines[0], lines[0]
    assert not (d / "out.fits").exists()


def test_whole_input_truncated_after_it_is_read(inputs, tmp_path):
    """A file read whole (a raw file with a DQ) is in memory once read: truncating it then
    changes nothing, the output is that of the untouched file; before, its pixels were
    memory-mapped views and the truncation killed the process with SIGBUS."""
    d = tmp_path / "case"
    shutil.copytree(inputs, d, symlinks=True)
    _dq_setup((64, 64))(d)
    _, _, start, _ = _probe.span(d / "lab.fits", "SCI")
    done = _run_changing(d, "lab.fits", "fit.yaml", "source", str(start + 100))
    assert done.returncode == 0 and not done.stderr.strip(), (done.returncode, done.stderr)
    expected, scale = _lstsq_slopes(d / "lab-copy.fits")
    with fits.open(d / "out.fits") as hdul:
        got = hdul["SCI"].data
    with fits.open(d / "raw.fits") as hdul:
        rows = np.asarray(hdul["READOUT"].data["row"])
    masked = np.zeros(got.shape, bool)
    for r, c in [(10, 5), (40, 33), (21, 7)]:  # the DQ's pixels (every bit masks)
        masked[rows == r, c] = True
    assert np.array_equal(np.isnan(got), masked)
    np.testing.assert_allclose(got[~masked], expected[~masked], rtol=0, atol=1e-5 * scale)


# -- round two: wiener, compare-strategies, plugin strategies, long runs --------------------------

# A third-party reference strategy, installed in the case's directory (the first folder of the
# command's sys.path): ``toy`` estimates offsets, ``oldtoy`` corrects the whole exposure; its
# ``mode`` says what they return.
TOY_PLUGIN = """\
import numpy as np
from spherex_reduce.plugin import Parameter, ReferenceOffsets, Strategy, hookimpl

MODE = (Parameter("mode", "ok", (str,), "what to return"),)


class Toy(Strategy):
    kind, name, parameters = "reference", "toy", MODE

    def estimate(self, side, context, exposure=None):
        mode, nframes = self.params["mode"], side.data.shape[0]
        if mode == "none":
            return None
        nch = context.geometry.nchannels
        shape = {"short": (1, 1, 1), "frames": (nframes + 2, nch, 1)}.get(mode,
                                                                        (nframes, nch, 1))
        offsets = np.full(shape, np.nan if mode == "nan" else 1.0)
        used = np.ones(shape, int)
        if mode == "missing":  # channel 0 without reference pixels: uncorrected, a warning
            offsets[:, 0], used[:, 0] = np.nan, 0
        return ReferenceOffsets(offsets, used, np.zeros(shape, int), [-1])


class OldToy(Strategy):
    kind, name, parameters = "reference", "oldtoy", MODE

    def __call__(self, exposure, mode):
        if mode == "array":
            return exposure.data.data
        return exposure.replace(data=exposure.data.data * np.nan)


@hookimpl
def register_strategies():
    return [Toy, OldToy]
"""
SMALL_SCENE = ("{geometry: {nrows: 64, ncols: 64, nchannels: 2, ref_border: 4}, readout: "
               "{skip: 4, ref_reads: 4, phantom_reads: 2, nframes: 3, frame_overhead: 10}}")
COMPARE = ["compare-strategies", "cmp.yaml", "-o", "cmp.ecsv", *SERIAL]


def _toy_plugin(d):
    """Setup: install `TOY_PLUGIN` (distribution ``spherex-reduce-toy 0.1.0``) in ``d``,
    compiled now so that importing it writes nothing."""
    import py_compile

    (d / "toy_strategy.py").write_text(TOY_PLUGIN)
    py_compile.compile(str(d / "toy_strategy.py"), doraise=True)
    info = d / "spherex_reduce_toy-0.1.0.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: spherex-reduce-toy\n"
                                   "Version: 0.1.0\n")
    (info / "entry_points.txt").write_text("[spherex_reduce]\ntoy = toy_strategy\n")


def _toy_pipeline(strategy, mode):
    """Setup: the plugin, and ``bad.yaml`` reducing with its strategy in ``mode``."""
    return chain(_toy_plugin, write("bad.yaml", f"steps:\n  - unchop: {{}}\n  - correct_reference: "
                                                f"{{strategy: {strategy}, mode: {mode}}}\n"
                                                "  - fit_ramp: {}\n"))


def _toy_comparison(*modes, extra=""):
    """Setup: the plugin, and ``cmp.yaml`` comparing pipelines of ``(strategy, mode)``."""
    pipes = "".join(f"  - {{name: {s}-{m}, steps: [{{unchop: {{}}}}, {{correct_reference: "
                    f"{{strategy: {s}, mode: {m}}}}}]}}\n" for s, m in modes)
    return chain(_toy_plugin, write("cmp.yaml", f"scene: {SMALL_SCENE}\npipelines:\n{pipes}"
                                                "measure: {kmin: 0.2, kmax: 1.0, bins: 6}\n"
                                                + extra))


def _wiener(noise):
    return write("bad.yaml", "steps:\n  - unchop: {}\n  - correct_reference: {strategy: wiener, "
                             f"noise: {noise}}}\n  - fit_ramp: {{}}\n")


def _fit_noise_table(gamma, gamma_err):
    """Setup: ``noise.ecsv``, a fit-noise result whose reference stream has this gamma."""
    def setup(d):
        t = Table({"stream": ["reference", "phantom"], "alpha": [2e-3, 1e-4],
                   "alpha_err": [4e-4, 1e-4], "beta": [3.0, 1.0], "beta_err": [8.0, 1.0],
                   "gamma": [gamma, 5.0], "gamma_err": [gamma_err, 6.0],
                   "exponent": [1.3, 1.3], "exponent_err": [0.0, 0.0]})
        t.write(d / "noise.ecsv", format="ascii.ecsv")
    return setup


def _tall_raw(d):
    """Setup: ``tall.fits``, raw ramps of a 16384 x 4 array read by one channel (0.5 MB)."""
    from spherex_reduce.simulation import simulate_to_fits

    scene = {"geometry": {"nrows": 16384, "ncols": 4, "nchannels": 1, "ref_border": 1},
             "readout": {"skip": 1, "ref_reads": 4, "phantom_reads": 1, "nframes": 2},
             "seed": 1}
    simulate_to_fits(scene, d / "tall.fits")


_UNITS = {"d": 86400, "h": 3600, "min": 60, "s": 1}


def _seconds(text):
    """``'8 h 10 min'`` -> 29400.0: a duration as the long runs print it."""
    parts = text.split()
    return sum(float(n) * _UNITS[unit] for n, unit in zip(parts[::2], parts[1::2], strict=True))


@pytest.mark.parametrize("command", ["compare", "sweep"])
def test_long_runs_print_their_expected_duration(command, runner, tmp_path):
    """Without -q a long run prints its expected duration, timed on its first task, before
    the rest runs; within a factor of 3 of the run's own duration (here 12 small tasks).
    No progress bar off a terminal, nothing with -q."""
    d = tmp_path / "case"
    d.mkdir()
    if command == "compare":
        (d / "run.yaml").write_text(f"scene: {SMALL_SCENE}\nrealizations: 12\n"
                                    "measure: {kmin: 0.2, kmax: 1.0, bins: 6}\n")
        argv, noun = ["compare-strategies", "run.yaml", "-o", "out.ecsv", *SERIAL], "realisations"
        took = re.compile(r"wrote out\.ecsv \(([\d.]+) s\)")
    else:
        (d / "run.yaml").write_text(SWEEP.replace("realizations: 1", "realizations: 6"))
        argv, noun = ["sweep", "run.yaml", "-o", "out.ecsv", *SERIAL], "cells"
        took = re.compile(r"failed \(([\d.]+) s\)")
    result = runner.run(argv, d)
    assert result.rc == 0, result.describe()
    assert result.stderr == "", result.describe()  # stderr: warnings and errors only
    lines = [line for line in result.stdout.splitlines() if line.startswith("about ")]
    assert len(lines) == 1, result.describe()
    found = re.fullmatch(rf"about (.+) for 12 {noun} \((.+) each\)", lines[0])
    assert found, result.describe()
    expected, actual = _seconds(found[1]), float(took.search(result.stdout)[1])
    assert actual / 3 <= expected <= 3 * actual + 0.3, (expected, actual)
    quiet = runner.run(["-q", *argv, "--overwrite"], d)
    assert quiet.rc == 0 and quiet.stderr == "" and "about" not in quiet.stdout, \
        quiet.describe()


def test_a_long_run_that_fails_prints_its_error_alone(runner, tmp_path):
    """Without -q too: the expected duration (printed after the first realisation, which a
    plugin's fault does not stop) is not on stderr, so the error is its only line."""
    d = tmp_path / "case"
    d.mkdir()
    _toy_comparison(("toy", "short"), extra="realizations: 3\n")(d)
    result = runner.run(COMPARE, d)
    assert result.rc == 2, result.describe()
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and ERROR_LINE.match(lines[0]) and "plugin 'toy'" in lines[0], \
        result.describe()


def _many_frames(d):
    """Setup: ``many.fits``, 30000 frames of an 8 x 8 array (7.7 MB)."""
    from spherex_reduce import DetectorGeometry, Exposure, ReadoutSchedule, write

    s = ReadoutSchedule(DetectorGeometry(8, 8, 1, ref_border=1), skip=1, ref_mode="none",
                        ref_reads=0, phantom_reads=0, nframes=30000)
    data = np.random.default_rng(1).normal(0, 1, (30000, s.n_reads, 8)).astype(np.float32)
    write(Exposure.from_arrays(data, s), d / "many.fits")


ROUND2_STRATEGIES = [
    # a plugin's strategy returning what the kernel cannot use: named, exit 2 (not a bug of ours)
    refused("plugin-reduce-estimate-none", REDUCE_BAD, _toy_pipeline("toy", "none"),
            mentions=r"strategy 'toy' of plugin 'toy' \(spherex-reduce-toy 0.1.0\) returned "
                     r"None"),
    refused("plugin-reduce-estimate-wrong-shape", REDUCE_BAD, _toy_pipeline("toy", "short"),
            mentions=r"plugin 'toy'.*offsets of shape \(1, 1, 1\); expected \(3, 2, 1\)"),
    refused("plugin-reduce-estimate-more-frames", REDUCE_BAD, _toy_pipeline("toy", "frames"),
            mentions=r"plugin 'toy'.*offsets of shape \(5, 2, 1\)"),
    refused("plugin-reduce-not-an-exposure", REDUCE_BAD, _toy_pipeline("oldtoy", "array"),
            mentions=r"strategy 'oldtoy' of plugin 'toy'.*not an Exposure"),
    # compare-strategies on slope images: offsets for 3 frames were broadcast over the one
    refused("compare-plugin-offsets-broadcast", COMPARE, _toy_comparison(("toy", "frames")),
            mentions=r"plugin 'toy'.*offsets of shape \(3, 2, 1\); expected \(1, 2, 1\)"),
    refused("compare-plugin-all-nan-exposure", COMPARE, _toy_comparison(("oldtoy", "nan")),
            mentions=r"strategy 'oldtoy' of plugin 'toy'.*without a finite pixel"),
    refused("compare-plugin-all-nan-offsets", COMPARE, _toy_comparison(("toy", "nan")),
            mentions=r"strategy 'toy' of plugin 'toy'.*NaN offsets for every channel"),
    # a warning of an earlier pipeline (channels without reference pixels) is not printed
    # before the error of a later one
    refused("compare-warning-before-error", COMPARE,
            _toy_comparison(("toy", "missing"), ("toy", "short")), mentions="plugin 'toy'"),
    # wiener's noise model
    refused("wiener-noise-pipeline-yaml", REDUCE_BAD, _wiener("fit.yaml"),
            mentions=r"correct_reference\.noise: fit\.yaml has no noise: section"),
    refused("wiener-noise-unrelated-yaml", REDUCE_BAD,
            chain(write("other.yaml", "colour: blue\n"), _wiener("other.yaml")),
            mentions=r"correct_reference\.noise"),
    refused("wiener-noise-negative-coefficient", REDUCE_BAD,
            chain(_fit_noise_table(-5000.0, 1.0), _wiener("noise.ecsv")),
            mentions=r"reference gamma = -5000 ± 1.*below zero"),
    # the kriging solve of a tall array: its memory, checked before it starts
    refused("wiener-tall-file-memory",
            ["reduce", "tall.fits", "-c", "bad.yaml", "-o", "out.fits"],
            chain(_tall_raw, _wiener("spherex-table2")),
            mentions=r"needs .* of memory; this machine can hold"),
    *[refused(f"sky-rms-{rms}", COMPARE,
              write("cmp.yaml", f"scene: {SMALL_SCENE}\nsky: {{rms: {rms}}}\n"
                                "measure: {kmin: 0.2, kmax: 1.0, bins: 6}\n"),
              mentions=r"sky\.rms: must be in \[1e-20, 1e\+20\] e/s")
      for rms in ("1e-300", "1e300")],  # the transfer was inf, NaN (exit 0)
    # solves over the reads of long ramps (30000 frames of 8 x 8, 7.7 MB): checked first
    *[refused(f"long-ramp-{step.replace('_', '-')}-memory",
              ["reduce", "many.fits", "-c", "bad.yaml", "-o", "out.fits"],
              chain(_many_frames, write("bad.yaml", f"steps:\n  - {step}: {{}}\n")),
              mentions=rf"{step}: the .* 30000 reads needs .* of memory")
      for step in ("fit_ramp", "detect_jumps")],
    # a config overriding a keyword, then refused: the override's warning is not printed
    refused("override-refused-one-line", REDUCE_BAD,
            write("bad.yaml", "input: {header: override}\ngeometry: {nrows: 128}\n"
                              "steps:\n  - fit_ramp: {}\n"), mentions="READOUT table has 60 reads"),
    # ... or refused after the header was read (a damaged table): still the error alone
    refused("override-then-damaged-table-one-line", REDUCE_BAD,
            chain(_damaged_provenance("raw.fits", "string"),
                  write("bad.yaml", "input: {header: override}\nreadout: {frame_overhead: 12}\n"
                                    "steps:\n  - unchop: {}\n  - fit_ramp: {}\n")),
            mentions="PROVENANCE"),
]


# -- round two: batches (exactly once, resumable, one line on stderr) -----------------------------

def _batch_case(inputs, tmp_path, n):
    """The case directory with ``n`` copies of ``raw.fits`` (``r00.fits``, ...) to reduce."""
    d = tmp_path / "case"
    shutil.copytree(inputs, d, symlinks=True)
    names = [f"r{i:02d}.fits" for i in range(n)]
    for name in names:
        shutil.copy(d / "raw.fits", d / name)
    return d, names


def _spawn(argv, cwd, wrap=()):
    """``spherex-reduce -q ARGV`` in a new session, capped as the probe caps its cases."""
    def limit():
        resource.setrlimit(resource.RLIMIT_AS, (_probe.MEMORY_LIMIT, _probe.MEMORY_LIMIT))

    return subprocess.Popen([*wrap, sys.executable, "-m", "spherex_reduce.cli", "-q", *argv],
                            cwd=cwd, env=_probe.child_env(), stdin=subprocess.DEVNULL,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            preexec_fn=limit, start_new_session=True)


def _finish(proc, timeout=60):
    """``(exit code, stdout, stderr lines)``; whatever the command left running is killed."""
    try:
        out, err = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        out, err = "", "TIMED OUT"
    finally:
        with contextlib.suppress(ProcessLookupError, PermissionError):
            os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()
    return proc.returncode, out, [line for line in err.splitlines() if line.strip()]


def _wait_for(test, seconds=30.0):
    """Poll ``test()`` every 2 ms until it is true (False after ``seconds``)."""
    end = time.monotonic() + seconds
    while not test():
        if time.monotonic() > end:
            return False
        time.sleep(0.002)
    return True


def _reduced(out):
    return sorted(p.name for p in out.glob("*_reduced.fits"))


def _summary_rows(out):
    """``{output name: status}`` of ``summary.ecsv``, each output listed once."""
    if not (out / "summary.ecsv").exists():
        return {}
    table = Table.read(out / "summary.ecsv", format="ascii.ecsv")
    names = [Path(p).name for p in table["output"]]
    assert len(names) == len(set(names)), f"an output listed twice: {names}"
    return dict(zip(names, table["status"], strict=True))


def _check_outputs(d, out, names):
    """Every output is there, holds the single ``reduce`` of raw.fits, and no temporary is left."""
    assert _reduced(out) == sorted(n.replace(".fits", "_reduced.fits") for n in names)
    ref = fits.getdata(d / "red.fits", "SCI")
    for name in _reduced(out):
        assert np.array_equal(fits.getdata(out / name, "SCI"), ref, equal_nan=True), name
    assert not [p.name for p in out.iterdir() if p.name.endswith(".tmp")]


#: A temporary output: ``.NAME.HOST-PID.XXXX.tmp`` (NAME and the writer's PID).
_TMP = re.compile(r"^\.(.+)\.[0-9a-f]{8}-(\d+)\.[^.]+\.tmp$")


def _worker_pids(pid):
    """The dask worker processes started by the command ``pid``."""
    psutil = pytest.importorskip("psutil")
    return [p.pid for p in psutil.Process(pid).children(recursive=True)
            if "spawn_main" in " ".join(p.cmdline())]


def _not_writable(kind, out):
    """A command prefix that runs with ``out`` read-only or full, or skips the test."""
    if os.geteuid() != 0:  # chmod bites
        if kind == "full":
            pytest.skip("a full folder needs a tmpfs, mounted as root")
        out.chmod(0o555)
        return ()
    # root ignores permissions: a private mount namespace, gone with the command
    mount = {"read-only": 'mount --bind "$0" "$0" && mount -o remount,bind,ro "$0" "$0"',
             "full": 'mount -t tmpfs -o size=64k tmpfs "$0" && '
                     '(dd if=/dev/zero of="$0/fill" bs=4k 2>/dev/null; true)'}[kind]
    wrap = ("unshare", "-m", "--propagation", "private", "sh", "-c",
            f'{mount} && exec "$@"', str(out))
    if subprocess.run([*wrap, "true"], capture_output=True).returncode != 0:
        pytest.skip("no private mount namespace here")
    return wrap


@pytest.mark.parametrize("kind", ["read-only", "full"])
def test_batch_output_folder_not_writable_is_refused_before_any_work(kind, inputs, tmp_path):
    d, names = _batch_case(inputs, tmp_path, 3)
    out = d / "out"
    out.mkdir()
    wrap = _not_writable(kind, out)
    try:
        rc, _, err = _finish(_spawn(["reduce", *names, "-c", "spherex-default", "-o", "out",
                                     *SERIAL], d, wrap))
    finally:
        out.chmod(0o755)
    assert rc == 2 and len(err) == 1 and ERROR_LINE.match(err[0]), err
    # named as the folder, before any file was reduced (not the summary after every file)
    assert re.search(r"output directory out\b.*(read-only|permission|no space)", err[0], re.I), err
    assert list(out.iterdir()) == []


def test_batch_killed_midway_keeps_its_summary_and_a_rerun_finishes(inputs, tmp_path):
    d, names = _batch_case(inputs, tmp_path, 30)
    out = d / "out"
    argv = ["reduce", *names, "-c", "spherex-default", "-o", "out", *SERIAL]
    proc = _spawn(argv, d)
    assert _wait_for(lambda: _reduced(out)), "no output appeared"
    _wait_for(lambda: _summary_rows(out), 0.5)
    os.killpg(proc.pid, signal.SIGKILL)
    _finish(proc)
    finished = _reduced(out)
    assert 1 <= len(finished) < len(names), "not killed mid-batch"
    rows = _summary_rows(out)
    assert set(rows.values()) == {"done"} and set(rows) <= set(finished), rows
    assert len(finished) - len(rows) <= 1  # at most the file finished as the kill came
    before = {n: (out / n).read_bytes() for n in finished}

    rc, stdout, err = _finish(_spawn(argv, d))
    assert rc == 0 and err == [], (stdout, err)
    assert f"{len(names) - len(finished)} reduced, {len(finished)} already done, 0 failed" in stdout
    _check_outputs(d, out, names)
    assert {n: (out / n).read_bytes() for n in finished} == before  # never rewritten
    rows = _summary_rows(out)
    assert sorted(rows) == _reduced(out)
    assert {n: rows[n] for n in finished} == dict.fromkeys(finished, "skipped")
    assert set(rows.values()) == {"done", "skipped"}


def test_batch_survives_a_killed_dask_worker(inputs, tmp_path):
    pytest.importorskip("distributed")
    d, names = _batch_case(inputs, tmp_path, 24)
    out = d / "out"
    proc = _spawn(["reduce", *names, "-c", "spherex-default", "-o", "out", "--workers", "2"], d)
    assert _wait_for(lambda: len(_reduced(out)) >= 4), "no output appeared"
    # kill the worker that has just renamed an output into place (its temporary file names
    # its process) before it hands the result over: dask runs that task again elsewhere
    workers, writing, victim = _worker_pids(proc.pid), {}, None
    end = time.monotonic() + 30
    while victim is None and time.monotonic() < end:
        now = {p.name: _TMP.match(p.name) for p in out.glob(".*.tmp")}
        victim = next((pid for tmp, (name, pid) in writing.items()
                       if tmp not in now and pid in workers and (out / name).exists()), None)
        writing = {tmp: (m[1], int(m[2])) for tmp, m in now.items() if m}
    assert victim is not None, "no worker seen writing"
    os.kill(victim, signal.SIGKILL)
    rc, stdout, err = _finish(proc)
    assert rc == 0 and err == [], (stdout, err)
    _check_outputs(d, out, names)
    rows = _summary_rows(out)
    assert sorted(rows) == _reduced(out) and set(rows.values()) == {"done"}, rows


def test_two_batches_into_one_folder_report_no_valid_output_as_failed(inputs, tmp_path):
    d, names = _batch_case(inputs, tmp_path, 30)
    out = d / "out"
    argv = ["reduce", *names, "-c", "spherex-default", "-o", "out", *SERIAL]
    first = _spawn(argv, d)
    assert _wait_for(lambda: _reduced(out)), "no output appeared"
    second = _spawn(argv, d)  # starts while the first is under way
    results = [_finish(first), _finish(second)]
    for rc, stdout, err in results:  # each finishes, or is refused in one line
        assert (rc == 0 and err == []) or (rc == 2 and len(err) == 1), (stdout, err)
    assert any(rc == 0 for rc, _, _ in results)
    _check_outputs(d, out, names)
    rows = _summary_rows(out)
    assert sorted(rows) == _reduced(out) and "failed" not in rows.values(), rows


#: A reference strategy ``gate`` that lets the first `GATE_OPEN` reductions through, then
#: marks each later one as started (``started.N`` next to it) and holds it until a file
#: ``release`` appears there (60 s at most): a batch reduced with it has, by construction,
#: work in progress when those marks appear.
GATE_PLUGIN = """\
import os
import time
from pathlib import Path

import numpy as np
from spherex_reduce.plugin import ReferenceOffsets, Strategy, hookimpl

HERE = Path(__file__).parent
GATE_OPEN = {open}


def ticket():
    n = 0
    while True:
        try:
            os.close(os.open(HERE / f"ticket.{{n}}", os.O_CREAT | os.O_EXCL | os.O_WRONLY))
            return n
        except FileExistsError:
            n += 1


class Gate(Strategy):
    kind, name, parameters = "reference", "gate", ()

    def estimate(self, side, context, exposure=None):
        n = ticket()
        if n >= GATE_OPEN:
            (HERE / f"started.{{n}}").touch()
            end = time.monotonic() + 60
            while not (HERE / "release").exists() and time.monotonic() < end:
                time.sleep(0.01)
        shape = (side.data.shape[0], context.geometry.nchannels, 1)
        return ReferenceOffsets(np.zeros(shape), np.ones(shape, int), np.zeros(shape, int),
                                [-1])


@hookimpl
def register_strategies():
    return [Gate]
"""
GATE_OPEN = 2


def _gate_plugin(d):
    """Setup: install `GATE_PLUGIN` (distribution ``spherex-reduce-gate``) in ``d`` and
    ``gate.yaml``, a pipeline reducing with it."""
    import py_compile

    (d / "gate_strategy.py").write_text(GATE_PLUGIN.format(open=GATE_OPEN))
    py_compile.compile(str(d / "gate_strategy.py"), doraise=True)
    info = d / "spherex_reduce_gate-0.1.0.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: spherex-reduce-gate\n"
                                   "Version: 0.1.0\n")
    (info / "entry_points.txt").write_text("[spherex_reduce]\ngate = gate_strategy\n")
    (d / "gate.yaml").write_text("steps:\n  - unchop: {}\n  - correct_reference: "
                                 "{strategy: gate}\n  - fit_ramp: {}\n")


@pytest.mark.parametrize(("name", "to"), [("SIGTERM", "process"), ("SIGINT", "group")])
def test_batch_on_dask_interrupted_prints_one_line(name, to, inputs, tmp_path):
    """A batch interrupted while files are being reduced exits 130 (SIGINT) or 143 (SIGTERM)
    with one line, its summary listing what was done.  The signal is sent once a file is
    done and another is held in a worker by the ``gate`` strategy (`GATE_PLUGIN`), so the
    batch cannot have finished by then, however slow this process is: before, the signal
    was sent up to a second after the first output appeared, and on a loaded machine the
    other 15 small files could all be reduced first (exit 0, nothing interrupted)."""
    pytest.importorskip("distributed")
    d, names = _batch_case(inputs, tmp_path, 16)
    _gate_plugin(d)
    out = d / "out"
    proc = _spawn(["reduce", *names, "-c", "gate.yaml", "-o", "out", "--workers", "2"], d)
    try:
        assert _wait_for(lambda: _summary_rows(out), 60), "no file was reduced"
        assert _wait_for(lambda: list(d.glob("started.*")), 60), "no file was held"
        assert proc.poll() is None, "the batch ended with a file held"
        (os.kill if to == "process" else os.killpg)(proc.pid, getattr(signal, name))
    finally:
        (d / "release").touch()  # the held files go on, if the batch still waits for them
    rc, _, err = _finish(proc)
    assert rc == 128 + getattr(signal, name) or (name == "SIGINT" and rc == 130), rc
    assert len(err) <= 1, err
    rows = _summary_rows(out)  # what finished before the signal
    assert rows and set(rows) <= set(_reduced(out)) and set(rows.values()) == {"done"}
    assert len(rows) < len(names)
    assert not [p.name for p in out.iterdir() if p.name.endswith(".tmp")]


ROUND2_BATCH = [
    refused("batch-output-made-from-another-input",
            ["reduce", "raw.fits", "copy.fits", "-c", "spherex-default", "-o", "out", *SERIAL],
            chain(mkdir("out"), lambda d: shutil.copy(d / "raw.fits", d / "copy.fits"),
                  lambda d: shutil.copy(d / "red2.fits", d / "out" / "raw_reduced.fits")),
            mentions="raw_reduced.fits.*--overwrite"),
]


# -- round two: found by the probe and fixed with the ramps issue ---------------------------------

def _no_reference_in_channel_1(d):
    """Setup: the reference reads of channel 1 (columns 32-63) of ``raw.fits`` are NaN."""
    def change(hdul):
        kind = np.char.strip(hdul["READOUT"].data.field(2).astype(str))
        sci = hdul["SCI"].data.copy()
        sci[:, kind == "reference", 32:] = np.nan
        hdul["SCI"].data = sci

    rewrite_hdus(d / "raw.fits", d / "raw.fits", change)
    (d / "uncorrected.yaml").write_text(
        "steps:\n  - unchop: {}\n  - subtract_phantom: {}\n  - fit_ramp: {weighting: uniform}\n")


def _check_channel_left_uncorrected(d, result, run):
    """Channel 1 is fitted as if no reference correction ran (the docs: "left uncorrected,
    never NaN"), flagged NO_REFERENCE; channel 0 is corrected."""
    again = run(["reduce", "raw.fits", "-c", "uncorrected.yaml", "-o", "bare.fits"])
    assert again.rc == 0, again.describe()
    with fits.open(d / "out.fits") as out, fits.open(d / "bare.fits") as bare:
        sci, dq, plain = out["SCI"].data, out["DQ"].data, bare["SCI"].data
        active = slice(4, 60)  # the reference border is 4 rows and columns
        assert np.isfinite(sci[active, 32:60]).all(), "channel 1 slopes are NaN"
        np.testing.assert_allclose(sci[active, 32:60], plain[active, 32:60], rtol=1e-6)
        assert (dq[active, 32:60] & 8).all()  # NO_REFERENCE
        assert not np.allclose(sci[active, 4:32], plain[active, 4:32], rtol=1e-6)


def _ascii_table_extension(d):
    """Setup: ``raw.fits`` with an ASCII-table extension, written with checksums by astropy."""
    notes = fits.TableHDU.from_columns(
        [fits.Column(name="note", format="A7", array=np.array(["a", "bc", "def"]))],
        name="NOTES")
    rewrite_hdus(d / "raw.fits", d / "raw.fits", lambda hdul: hdul.append(notes))


def _check_same_as_red(d, result, run):
    with fits.open(d / "out.fits") as out, fits.open(d / "red.fits") as red:
        np.testing.assert_array_equal(out["SCI"].data, red["SCI"].data)


def _one_frame(d):
    """Setup: ``raw.fits`` cut to its first frame (NFRAMES = 1)."""
    def change(hdul):
        for name in ("SCI", "PHANTOM"):
            hdul[name].data = hdul[name].data[:1].copy()
        hdul[0].header["NFRAMES"] = 1

    rewrite_hdus(d / "raw.fits", d / "raw.fits", change)


def _one_frame_integrations(d):
    """Setup: ``raw.fits`` as 2 integrations of 1 frame (4-D SCI and PHANTOM)."""
    def change(hdul):
        for name in ("SCI", "PHANTOM"):
            hdul[name].data = np.stack([hdul[name].data[:1]] * 2)
        hdul[0].header["NFRAMES"] = 1

    rewrite_hdus(d / "raw.fits", d / "raw.fits", change)


ROUND2_FIXED_EARLIER = [
    works("fixed-channel-without-reference-not-nan", REDUCE, _no_reference_in_channel_1,
          _check_channel_left_uncorrected),
    works("fixed-ascii-table-with-checksums-read", REDUCE, _ascii_table_extension,
          _check_same_as_red),
    refused("fixed-one-frame-ramps", REDUCE, _one_frame, mentions="at least 2 frames"),
    refused("fixed-one-frame-ramps-4d", REDUCE, _one_frame_integrations,
            mentions="at least 2 frames"),
]


# -- layouts other systems write ---------------------------------------------------------------

def _hst_ima(d):
    """Setup: ``ima.fits``, a ramp as HST writes it (SCI,1 ... SCI,3 with DQ,k and
    SAMPTIME, latest read first), and ``one.yaml``, a pipeline of fit_ramp for it."""
    hdus = [fits.PrimaryHDU()]
    for k in range(1, 4):
        sci = fits.ImageHDU(np.full((16, 16), 100.0 * (4 - k), np.float32), name="SCI", ver=k)
        sci.header["SAMPTIME"] = 2.9 * (3 - k)
        hdus += [sci, fits.ImageHDU(np.zeros((16, 16), np.int16), name="DQ", ver=k)]
    fits.HDUList(hdus).writeto(d / "ima.fits")
    (d / "one.yaml").write_text(
        "geometry: {nrows: 16, ncols: 16, nchannels: 1, ref_border: 0, pixel_rate: 1.0e+5}\n"
        "readout: {skip: 1, ref_reads: 0, ref_mode: none, phantom_reads: 0, nframes: 3, "
        "frame_time: 2.9}\nsteps: [fit_ramp]\n")
    (d / "ext.yaml").write_text((d / "one.yaml").read_text()
                                + "input: {reads: extensions}\n")


def _check_extension_slopes(d, result, run):
    """The reads 100, 200, 300 at SAMPTIME 0, 2.9, 5.8 s: 100 / 2.9 per second everywhere."""
    with fits.open(d / "out.fits") as hdul:
        np.testing.assert_allclose(hdul["SCI"].data, 100 / 2.9, rtol=1e-6)


LAYOUTS = [
    # SCI,1 was reduced as if it were the ramp (fit_ramp skipped, exit 0); with the config's
    # input.reads: extensions the SCI are the ramp's reads in SAMPTIME order
    works("reduce-reads-as-image-extensions", ["reduce", "ima.fits", "-c", "ext.yaml", "-o",
                                               "out.fits"], _hst_ima, _check_extension_slopes),
    # without it the file is still refused, naming what was found and what to set
    refused("reduce-image-extensions-not-asked-for", ["reduce", "ima.fits", "-c", "one.yaml",
                                                      "-o", "out.fits"], _hst_ima,
            mentions=r"3 SCI extensions .*set input.reads: extensions"),
    # a reduced image given to fit-noise: the message says what to give instead
    refused("fit-noise-reduced-image", ["fit-noise", "red.fits", "-o", "fit.ecsv"],
            mentions=r"give the raw file"),
]


# -- what held when the probe ran: keep it so -----------------------------------------------------

HELD = [
    refused("reduce-missing-file", ["reduce", "none.fits", "-c", "unchop", "-o", "out.fits"]),
    refused("reduce-zero-byte-file", REDUCE, write("raw.fits", b"")),
    refused("reduce-not-fits", REDUCE, write("raw.fits", "this is not FITS\n" * 200)),
    refused("reduce-header-missing-nrows", REDUCE, cards("raw.fits", NROWS=None),
            mentions="NROWS"),
    refused("reduce-header-rowskip-disagrees-with-readout-table", REDUCE,
            cards("raw.fits", ROWSKIP="8")),
    refused("reduce-wrong-shape", REDUCE, cards("raw.fits", NCOLS="128", CHANW="64")),
    refused("reduce-config-python-tag", REDUCE_BAD,
            write("bad.yaml", 'name: !!python/object/apply:os.system ["touch pwned"]\n'
                              "steps:\n  - unchop: {}\n")),
    refused("reduce-config-unknown-step", REDUCE_BAD,
            write("bad.yaml", "steps:\n  - nosuchstep: {}\n"), mentions="nosuchstep"),
    refused("reduce-output-exists", [*REDUCE[:-1], "red.fits"], mentions="exists"),
    refused("simulate-scene-not-a-mapping", SIMULATE_BAD, write("bad.yaml", "- 1\n- 2\n")),
]

CASES = [*FITS_DAMAGE, *CHECKSUM_OPT_OUT, *INTEGER_DATA, *FOREIGN_DQ, *READ_FILES, *YAML,
         *CLI_NUMBERS, *OUTPUT_IS_INPUT, *INPUT_CONFIG, *INPUT_SECTION, *OUTPUT_PLACES,
         *MESSAGES, *HELD, *ROUND2_READS_AND_NAMES, *ROUND2_INTEGRATIONS, *ROUND2_STRATEGIES,
         *ROUND2_BATCH, *ROUND2_FIXED_EARLIER, *LAYOUTS]


@pytest.mark.parametrize("case", CASES)
def test_input(case, inputs, runner, tmp_path):
    d = tmp_path / "case"
    shutil.copytree(inputs, d, symlinks=True)
    if case.setup is not None:
        case.setup(d)
    before = _probe.snapshot(d)
    argv = [a.replace("{dir}", str(d)) for a in case.argv]

    def run(more):
        return runner.run(["-q", *more], d, timeout=case.timeout)

    result = run(argv)
    assert not result.timed_out, f"hang: {result.describe()}"
    assert "Traceback" not in result.stderr, result.describe()
    if case.check is not None:
        assert result.rc == 0, result.describe()
        case.check(d, result, run)
        return
    assert result.rc == 2, result.describe()
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and ERROR_LINE.match(lines[0]), \
        f"stderr is not one error line: {result.describe()}"
    if case.mentions:
        assert re.search(case.mentions, lines[0], re.IGNORECASE), \
            f"the message does not name {case.mentions!r}: {lines[0]}"
    after = _probe.snapshot(d)
    assert sorted(set(after) - set(before)) == [], f"new files: {result.describe()}"
    assert sorted(set(before) - set(after)) == [], f"files gone: {result.describe()}"
    changed = sorted(k for k in before if before[k] != after[k])
    assert changed == [], f"changed: {changed}; {result.describe()}"


def test_case_ids_are_unique():
    ids = [p.id for p in CASES]
    assert len(ids) == len(set(ids))
    assert all(re.fullmatch(r"[a-z0-9][a-z0-9.-]*", i) for i in ids)


def test_probe_tools(tmp_path):
    """The damaging tools do what the cases need (a check that the probe itself is right)."""
    path = tmp_path / "x.fits"
    hdu = fits.ImageHDU(np.arange(12, dtype=">f4").reshape(3, 4), name="SCI")
    fits.HDUList([fits.PrimaryHDU(), hdu]).writeto(path, checksum=True)
    with pytest.raises(KeyError):
        _probe.edit_cards(path, "PRIMARY", {"NROWS": "1"})
    _probe.edit_cards(path, "SCI", {"NAXIS1": "4", "EXTNAME": "'SCI'"})
    with fits.open(path, checksum=True) as hdul:
        assert "CHECKSUM" not in hdul["SCI"].header and hdul["SCI"].data[2, 3] == 11
        assert hdul["SCI"].header["EXTNAME"] == "SCI" and "CHECKSUM" in hdul[0].header
    _, _, start, size = _probe.span(path, "SCI")
    assert size == 2880 and start % 2880 == 0
    flip = tmp_path / "y.fits"
    shutil.copy(path, flip)
    _probe.flip_byte(flip, start + 3)
    assert fits.getdata(flip, "SCI")[0, 0] != 0
    state = _probe.snapshot(tmp_path)
    assert state["x.fits"] != state["y.fits"]


# Round three: inputs

#: a 64 x 64 window at the corner of a 512 x 512 array of 8 outputs at 100 kHz
WINDOW = ("geometry: {nrows: 64, ncols: 64, pixel_rate: 1.0e+5}\n"
          "window: {first_row: 0, first_column: 0, full_nrows: 512, full_ncols: 512, "
          "full_nchannels: 8}\n")
#: the full readout by hand: 512 rows of 64 pixels + 4 overhead samples, then 2000 samples
#: of reset: the window's frame time (s)
WINDOW_FRAME = (512 * (64 + 4) + 2000) / 1e5
WINDOW_RATE = 7.5  # counts per second everywhere


def _window(readout):
    """Setup: ``win.fits``, 3 frames of a ramp of `WINDOW_RATE` read every `WINDOW_FRAME`
    s (no keywords), and ``win.yaml``, fit_ramp with the `WINDOW` and ``readout``."""
    def setup(d):
        t = WINDOW_FRAME * np.arange(3)[:, None, None]
        sci = fits.ImageHDU((100 + WINDOW_RATE * t + np.zeros((3, 64, 64))).astype(np.float32),
                            name="SCI")
        fits.HDUList([fits.PrimaryHDU(), sci]).writeto(d / "win.fits")
        (d / "win.yaml").write_text(
            WINDOW + "readout: {skip: 1, ref_mode: none, phantom_reads: 0, row_overhead: 4, "
            f"nframes: 3, {readout}}}\nsteps: [fit_ramp]\n")
    return setup


def _check_window_rate(d, result, run):
    """The frame time given: the slopes are the rate the ramp was made with."""
    with fits.open(d / "out.fits") as hdul:
        np.testing.assert_allclose(hdul["SCI"].data, WINDOW_RATE, rtol=1e-4)
        assert hdul[0].header["TFRAME"] == WINDOW_FRAME


def _hst_float_dq(d):
    """Setup: `_hst_ima` with DQ,2 stored as float, 0.5 on one pixel of that read."""
    _hst_ima(d)
    with fits.open(d / "ima.fits") as hdul:
        flags = np.zeros((16, 16), np.float32)
        flags[3, 4] = 0.5
        hdul["DQ", 2].data = flags
        hdul.writeto(d / "ima.fits", overwrite=True)


def _dq_int64_bit40(d):
    """Setup: lab.fits, raw.fits without READOUT and with a 3-D int64 DQ: bit 40 on frame 1
    of read 7, column 9, and bit 63 on frame 2 of read 20, column 40."""
    with fits.open(d / "raw.fits") as hdul:
        shape = hdul["SCI"].shape
    mask = np.zeros(shape, np.int64)
    mask[1, 7, 9] = 2**40
    mask[2, 20, 40] = np.array(2**63, np.uint64).view(np.int64)
    _with_dq(d / "raw.fits", d / "lab.fits", mask)


def _check_high_bits_masked(d, result, run):
    """The two flagged reads left out of their pixels' fits (numpy least squares over the
    other two frames), every other slope numpy's over the three."""
    expected, scale = _lstsq_slopes(d / "lab.fits")
    with fits.open(d / "lab.fits") as hdul:
        ramps = hdul["SCI"].data.astype(np.float64)
        tframe = hdul[0].header["TFRAME"]
    for frame, i, c in ((1, 7, 9), (2, 20, 40)):
        kept = np.delete(np.arange(3), frame)
        expected[i, c] = (ramps[kept[1], i, c] - ramps[kept[0], i, c]) / (
            (kept[1] - kept[0]) * tframe)
    with fits.open(d / "out.fits") as hdul:
        np.testing.assert_allclose(hdul["SCI"].data, expected, rtol=0, atol=1e-5 * scale)


def _float_dq_in_read(d):
    """Setup: `_split_reads`, read_2.fits with a float DQ (0.5 on one pixel), and mask.fits,
    an integer mask of one read's shape flagging nothing."""
    _split_reads()(d)
    with fits.open(d / "read_2.fits") as hdul:
        flags = np.zeros(hdul["SCI"].shape, np.float32)
        flags[5, 3] = 0.5
        hdul.append(fits.ImageHDU(flags, name="DQ"))
        hdul.writeto(d / "read_2.fits", overwrite=True, checksum=True)
        fits.PrimaryHDU(np.zeros(hdul["SCI"].shape, np.int16)).writeto(d / "mask.fits")


def _check_ran_once_recorded(d, result, run):
    """fit_ramp listed twice: the first run fitted the slopes (numpy), the second was skipped
    (slopes already); the file says fit_ramp ran, each run's row its own status."""
    expected, scale = _lstsq_slopes(d / "raw.fits")
    with fits.open(d / "out.fits") as hdul:
        assert hdul[0].header["S_RAMPFT"] == "COMPLETE"
        assert list(hdul["PROVENANCE"].data["status"]) == ["COMPLETE", "SKIPPED"]
        np.testing.assert_allclose(hdul["SCI"].data, expected, rtol=0, atol=1e-5 * scale)


ROUND3_INPUTS = [
    # frame_overhead timed the window by its own 64 rows (0.0205 s, slopes 148x too large)
    refused("reduce-window-without-frame-time",
            ["reduce", "win.fits", "-c", "win.yaml", "-o", "out.fits"],
            _window("frame_overhead: 2000"), mentions=r"window needs readout\.frame_time"),
    works("reduce-window-with-its-frame-time",
          ["reduce", "win.fits", "-c", "win.yaml", "-o", "out.fits"],
          _window(f"frame_time: {WINDOW_FRAME!r}"), _check_window_rate),
    # a float DQ,i (0.5 on a bad read) was cast to 0: the read was fitted
    refused("reduce-extension-dq-float", ["reduce", "ima.fits", "-c", "ext.yaml", "-o",
                                          "out.fits"], _hst_float_dq,
            mentions=r"'DQ',2 holds flags, which must be integers"),
    # bits 32-63 of an int64 DQ never masked (the mask was 0xffffffff)
    works("reduce-dq-int64-high-bits", ["reduce", "lab.fits", "-c", "fit.yaml", "-o",
                                        "out.fits"], _dq_int64_bit40, _check_high_bits_masked),
    # a float DQ in a read file with --reads-dq: TypeError, exit 1
    refused("reduce-reads-dq-float-dq-in-a-read-file",
            [*READS, "--reads-dq", "mask.fits"], _float_dq_in_read,
            mentions=r"read_2\.fits: HDU 'DQ' holds flags, which must be integers"),
    # the second, skipped run of a step listed twice made S_RAMPFT say SKIPPED
    works("reduce-step-listed-twice", ["reduce", "raw.fits", "-c", "twice.yaml", "-o",
                                       "out.fits"],
          write("twice.yaml", "steps: [fit_ramp, fit_ramp]\n"), _check_ran_once_recorded),
]


@pytest.mark.parametrize("case", ROUND3_INPUTS)
def test_round_three_inputs(case, inputs, runner, tmp_path):
    test_input(case, inputs, runner, tmp_path)


# Round three: newcomer

PIXEL = (20, 20)  # a light-sensitive pixel of the 64 x 64 inputs (border 4)


def _one_usable_of_three(d):
    """Setup: red3.fits, red2.fits with the pixel at 42 +- 3 unflagged; the pixel of red.fits
    and red2.fits DO_NOT_USE with a value of 0 (what other software writes there)."""
    def third(hdul):
        hdul["SCI"].data[PIXEL], hdul["ERR"].data[PIXEL], hdul["DQ"].data[PIXEL] = 42.0, 3.0, 0

    def flagged(hdul):
        hdul["SCI"].data[PIXEL], hdul["DQ"].data[PIXEL] = 0.0, 1

    rewrite_hdus(d / "red2.fits", d / "red3.fits", third)
    rewrite_hdus(d / "red.fits", d / "red.fits", flagged)
    rewrite_hdus(d / "red2.fits", d / "red2.fits", flagged)


def _check_one_usable_kept(d, result, run):
    """No warning line; the pixel is red3's value with red3's error, usable; a pixel no input
    can give (every input flagged or NaN, counted with numpy) is NaN and DO_NOT_USE."""
    assert [line for line in result.stderr.splitlines() if line.strip()] == []
    with fits.open(d / "master.fits") as hdul:
        sci, err, flags = (hdul[n].data for n in ("SCI", "ERR", "DQ"))
        counted = hdul[0].header["NCOMB0"]
    assert (sci[PIXEL], err[PIXEL], flags[PIXEL] & 1) == (42.0, 3.0, 0)
    unusable = []
    for name in ("red.fits", "red2.fits", "red3.fits"):
        with fits.open(d / name) as hdul:
            informational = 64 | 2 | 128  # JUMP, SATURATED, REFERENCE (docs/fits.rst)
            unusable.append(~np.isfinite(hdul["SCI"].data)
                            | ((hdul["DQ"].data & ~informational) != 0))
    none = np.logical_and.reduce(unusable)
    assert none.sum() == counted > 0
    assert np.isnan(sci[none]).all() and (flags[none] & 1 == 1).all()
    assert np.isfinite(sci[~none]).all() and (flags[~none] & 1 == 0).all()


NEWCOMER = [
    # one usable value of three was clipped by a median and spread of the two flagged zeros
    # (NaN), with numpy's 'Mean of empty slice' and 'Degrees of freedom <= 0' on stderr
    works("combine-one-usable-input-of-three",
          ["combine", "red.fits", "red2.fits", "red3.fits", "-o", "master.fits"],
          _one_usable_of_three, _check_one_usable_kept),
    # an existing output: astropy's words, with the command line's option
    refused("reduce-output-exists-in-astropys-words", [*REDUCE[:-1], "red.fits"],
            mentions=r"File red\.fits already exists\. If you mean to replace it then use "
                     r"the argument \"overwrite=True\" \(on the command line: --overwrite\)"),
]


@pytest.mark.parametrize("case", NEWCOMER)
def test_newcomer_input(case, inputs, runner, tmp_path):
    test_input(case, inputs, runner, tmp_path)


# Round three: forecast

FORECAST = ["forecast", "scene.yaml", "-c", "unchop", "-o", "f.ecsv"]
_WHITE_SCENE = ("geometry: {nrows: 16, ncols: 16, nchannels: 2, ref_border: 2}\n"
                "readout: {skip: 2, ref_reads: 2, phantom_reads: 2, nframes: 6, "
                "read_times: [0, 1, 2, 5, 10, 20]}\n"
                "noise: {components: [{name: w, alpha: 2.0e-3}]}\n")


def _measured(**meta):
    """Setup: ``m.ecsv``, a spectrum output of the 56 x 56 light pixels of ``scene.yaml`` in
    the default band, its meta changed by ``meta``."""
    def setup(d):
        from astropy import units as u

        unit = u.electron**2 / u.s**2 * u.pix**2
        Table({"k": [0.05, 0.1] * u.rad / u.pix, "power": [1.0, 2.0] * unit,
               "power_err": [0.1, 0.2] * unit},
              meta={"band_power": 1.5, "band_power_err": 0.1, "band_kmin": 0.03,
                    "band_kmax": 0.13, "exclude_horizontal": False, "shape": [56, 56],
                    **meta}).write(d / "m.ecsv", format="ascii.ecsv")
    return setup


def _fit_with_streams(*streams):
    """Setup: ``noise.ecsv``, a fit-noise result with rows of these streams."""
    def setup(d):
        n = len(streams)
        Table({"stream": list(streams), "alpha": [2e-3] * n, "beta": [3.0] * n,
               "gamma": [1.0] * n, "exponent": [1.3] * n}).write(d / "noise.ecsv",
                                                                 format="ascii.ecsv")
    return setup


_DESIGN = ("scene: {geometry: {nrows: 40, ncols: 16, nchannels: 2, ref_border: 4}, "
           "readout: {nframes: 4}}\nband: {kmin: 0.2, kmax: 1.0}\n"
           "baseline: {skip: 4, ref_reads: 8}\nsearch: {families: [skip], skips: [1, 4], "
           "phantom_reads: [4], ref_reads: [8], ref_modes: [distributed], iterations: 0}\n")
DESIGN = ["design-readout", "design.yaml", "-o", "best.yaml"]


def _check_read_times_forecast(d, result, run):
    """White noise of per-sample variance alpha fs / 2 read at t = 0, 1, 2, 5, 10, 20 s:
    the least-squares slope's variance sigma^2 / sum (t - tbar)^2, flat (was the variance
    of evenly read frames, 30x larger)."""
    t = np.array([0.0, 1.0, 2.0, 5.0, 10.0, 20.0])
    expect = 2e-3 * 1e5 / 2 / np.sum((t - t.mean()) ** 2)
    table = Table.read(d / "f.ecsv", format="ascii.ecsv")
    np.testing.assert_allclose(np.asarray(table["power"]), expect, rtol=1e-9)


ROUND3_FORECAST = [
    # a band below 0: refused by the option, as spectrum's band is (fixed in round two)
    refused("forecast-kmin-negative", [*FORECAST, "--kmin", "-0.1"], mentions="--kmin"),
    refused("forecast-kmax-negative", [*FORECAST, "--kmax", "-0.1"], mentions="--kmax"),
    # uneven read times: forecast at those times (was as if evenly read)
    works("forecast-read-times-uneven", FORECAST, write("scene.yaml", _WHITE_SCENE),
          _check_read_times_forecast),
    # a measurement of another band or axis was compared all the same (0.22x, -58 sigma)
    refused("forecast-compare-other-band", [*FORECAST, "--compare", "m.ecsv"],
            _measured(band_kmin=0.05, band_kmax=0.5), mentions=r"band 0\.05 to 0\.5"),
    refused("forecast-compare-exclude-horizontal", [*FORECAST, "--compare", "m.ecsv"],
            _measured(exclude_horizontal=True), mentions="--exclude-horizontal"),
    refused("forecast-compare-other-shape", [*FORECAST, "--compare", "m.ecsv"],
            _measured(shape=[64, 64]), mentions=r"64 x 64 image"),
    refused("forecast-compare-no-band", [*FORECAST, "--compare", "m.ecsv"],
            write("m.ecsv", "# %ECSV 1.0\n# ---\n# datatype:\n# - {name: k, unit: rad / pix, "
                            "datatype: float64}\n# - {name: power, unit: electron2 pix2 / s2, "
                            "datatype: float64}\n# - {name: power_err, unit: electron2 pix2 "
                            "/ s2, datatype: float64}\n# schema: astropy-2.0\nk power "
                            "power_err\n0.1 1.0 0.1\n"), mentions="band_kmin"),
    # a fit-noise row of another stream was dropped without a word
    refused("design-fit-noise-unknown-stream", DESIGN,
            chain(_fit_with_streams("reference", "phantom", "roic"),
                  write("design.yaml", _DESIGN + "noise: noise.ecsv\nrealizations: 0\n")),
            mentions=r"row 2: stream 'roic'"),
    refused("wiener-fit-noise-unknown-stream", REDUCE_BAD,
            chain(_fit_with_streams("referenc", "phantom"), _wiener("noise.ecsv")),
            mentions=r"row 0: stream 'referenc'"),
    # read times the Monte Carlo cannot simulate: refused before the search, not after it
    refused("design-read-times-monte-carlo", DESIGN,
            write("design.yaml", _DESIGN.replace("nframes: 4", "nframes: 3, read_times: "
                                                 "[0, 1, 3]") + "realizations: 2\n"),
            mentions=r"realizations: .*read_times"),
]


@pytest.mark.parametrize("case", ROUND3_FORECAST)
def test_input_round_three_forecast(case, inputs, runner, tmp_path):
    test_input(case, inputs, runner, tmp_path)


# Round three: maps and jump neighbours

_MAP_N, _MAP_T = 16, 2.0 * np.arange(6)  # a 16 x 16 stored image, 6 reads of 2 s
_JUMP = 64  # spherex_reduce.dq.JUMP
_MAP_LAYOUTS = {"rows": "{nchannels: 2, channels: rows}",
                "quadrants": "{nchannels: 4, channels: quadrants}"}


def _map_case(layout, steps, jumps=(), bunit=None):
    """Setup: ``lab.fits``, a 16 x 16 ramp of ``layout`` in the stored orientation (1000 e
    jumps before read 3 at the stored ``jumps``), a read-noise map ``rn.fits`` (3-5 e,
    ``bunit``) and a dark-current map ``dark.fits`` of the stored image, and ``maps.yaml``
    running ``steps``."""
    def setup(d):
        rng = np.random.default_rng(31)
        n = _MAP_N
        data = 1000 + rng.uniform(1, 5, (n, n)) * _MAP_T[:, None, None] \
            + rng.normal(0, 1, (6, n, n))
        for r, c in jumps:
            data[3:, r, c] += 1000.0
        fits.HDUList([fits.PrimaryHDU(), fits.ImageHDU(data, name="SCI")]).writeto(
            d / "lab.fits")
        rn = fits.PrimaryHDU(rng.uniform(3, 5, (n, n)))
        if bunit is not None:
            rn.header["BUNIT"] = bunit
        rn.writeto(d / "rn.fits")
        fits.PrimaryHDU(rng.uniform(0, 2, (n, n))).writeto(d / "dark.fits")
        (d / "maps.yaml").write_text(
            f"geometry: {{nrows: {n}, ncols: {n}, ref_border: 0, pixel_rate: 1.0e+5}}\n"
            .replace("}", f", {_MAP_LAYOUTS[layout][1:-1]}}}")
            + "readout: {skip: 1, ref_reads: 0, ref_mode: none, phantom_reads: 0, nframes: 6, "
              "frame_time: 2.0}\n" + f"steps: {steps}\n")
    return setup


def _numpy_slopes_and_errors(d):
    """np.polyfit slopes of ``lab.fits`` and their model errors from ``rn.fits`` and
    ``dark.fits``, all on the stored image."""
    data, rn, dark = (fits.getdata(d / f) for f in ("lab.fits", "rn.fits", "dark.fits"))
    t = _MAP_T
    slope = np.polyfit(t, data.reshape(6, -1), 1)[0].reshape(data.shape[1:])
    w = (t - t.mean()) / ((t - t.mean()) @ (t - t.mean()))
    pf = w @ np.minimum.outer(t, t) @ w
    from spherex_reduce.reduce.steps.fit_ramp.expected_rates import expected_rates

    # the shot noise of fit_ramp's expected rates (issue 35; tested against the truth in
    # tests/reduce/steps/fit_ramp/test_fit_ramp.py), the pixels' own where too few
    rnoise = rn ** 2 * (w @ w) + dark * pf
    rate = expected_rates(slope, rnoise, np.full(slope.shape, pf))
    rate = np.maximum(slope, 0) if rate is None else rate
    return slope, np.sqrt(rnoise + rate * pf)


def _check_map_errors(d, result, run):
    """The slopes and errors written (stored orientation) are numpy's, pixel by pixel."""
    slope, err = _numpy_slopes_and_errors(d)
    with fits.open(d / "out.fits") as hdul:
        np.testing.assert_allclose(hdul["SCI"].data, slope, rtol=0, atol=1e-6)
        np.testing.assert_allclose(hdul["ERR"].data, err, rtol=2e-6)  # float32 parts


_SEAM_JUMPS = ((3, 7), (7, 12), (8, 8), (0, 0))  # vertical, horizontal seams, two corners


def _check_seam_neighbours(d, result, run):
    """JUMP on the slope of the jumps and of their 4 neighbours on the stored image (across
    the quadrants' seams), and of no other pixel."""
    near = {(r + dr, c + dc) for r, c in _SEAM_JUMPS
            for dr, dc in ((0, 0), (-1, 0), (1, 0), (0, -1), (0, 1))
            if 0 <= r + dr < _MAP_N and 0 <= c + dc < _MAP_N}
    with fits.open(d / "out.fits") as hdul:
        flagged = {tuple(p) for p in np.argwhere(hdul["DQ"].data & _JUMP).tolist()}
    assert flagged == near


def _check_all_jump(d, result, run):
    with fits.open(d / "out.fits") as hdul:
        assert (hdul["DQ"].data & _JUMP).all()  # a radius beyond the image: every pixel


def _check_no_jump(d, result, run):
    with fits.open(d / "out.fits") as hdul:
        assert not (hdul["DQ"].data & _JUMP).any() and hdul[0].header["NJUMPS"] == 0


def _truncate(name):
    def setup(d):
        with open(d / name, "r+b") as fh:
            fh.truncate(2880 + 700)  # the header and part of the data
    return setup


_MAPS_FIT = ("[{fit_ramp: {read_noise: rn.fits, dark_current: dark.fits}}]")
_LAB = ["reduce", "lab.fits", "-c", "maps.yaml", "-o", "out.fits"]
ROUND3_MAPS = [
    # a map of the stored image was applied transposed with channels: rows (ERR wrong at
    # 3528 of 3584 pixels); a quadrant map of the stored shape was refused
    works("reduce-rows-maps-in-stored-orientation", _LAB, _map_case("rows", _MAPS_FIT),
          _check_map_errors),
    works("reduce-quadrant-maps-in-stored-shape", _LAB,
          _map_case("quadrants", "[{detect_jumps: {read_noise: rn.fits}}, "
                                 "{fit_ramp: {read_noise: rn.fits, dark_current: dark.fits}}]"),
          _check_map_errors),
    # neighbours flagged the array's far edge instead of the pixel across a quadrant seam
    works("reduce-jump-neighbours-across-quadrant-seams", _LAB,
          _map_case("quadrants", "[{detect_jumps: {read_noise: 1.0, threshold: 6.0, "
                                 "neighbours: true}}, fit_ramp]", jumps=_SEAM_JUMPS),
          _check_seam_neighbours),
    # radius 1e9 was killed after 180 s (offsets growing as radius**2)
    works("reduce-jump-radius-1e9", _LAB,
          _map_case("quadrants", "[{detect_jumps: {read_noise: 1.0, radius: 1.0e+9, "
                                 "radius_above: 100}}, fit_ramp]", jumps=((5, 5),)),
          _check_all_jump),
    # threshold 1e300: OverflowError, exit 1
    works("reduce-jump-threshold-1e300", _LAB,
          _map_case("rows", "[{detect_jumps: {threshold: 1.0e+300}}, fit_ramp]",
                    jumps=((5, 5),)), _check_no_jump),
    # a map in metres or in ADU (data in electrons, no gain) was used as electrons
    refused("reduce-read-noise-map-in-metres", _LAB, _map_case("rows", _MAPS_FIT, bunit="m"),
            mentions=r"fit_ramp\.read_noise.* m\b"),
    refused("reduce-read-noise-map-in-adu-without-gain", _LAB,
            _map_case("rows", _MAPS_FIT, bunit="adu"), mentions=r"read_noise.*gain"),
    # astropy's truncation warning came before our line
    refused("reduce-truncated-read-noise-map", _LAB,
            chain(_map_case("rows", _MAPS_FIT), _truncate("rn.fits")),
            mentions=r"read_noise.*truncated"),
]


@pytest.mark.parametrize("case", ROUND3_MAPS)
def test_round_three_maps_and_jump_neighbours(case, inputs, runner, tmp_path):
    test_input(case, inputs, runner, tmp_path)


# Issue 31: Roman input

_ROMAN_PATTERN = [[1], [2, 3], [4, 5, 6, 7], [8]]  # reads from 1, uneven resultants
_ROMAN_TIMES = np.array([np.mean(r) for r in _ROMAN_PATTERN]) * 3.04
_ROMAN_STEPS = "steps:\n  - fit_ramp: {weighting: uniform}\n"


def _roman(name="r_uncal.asdf", **exposure):
    """Setup: a Roman level-1 file written by roman_datamodels (32 x 64 stand-in, WFI01)."""
    def setup(d):
        rdm = pytest.importorskip("roman_datamodels.datamodels")
        rng = np.random.default_rng(31)
        rate = rng.uniform(5, 60, (32, 64))
        data = np.round(2000 + rate * _ROMAN_TIMES[:, None, None]
                        + rng.normal(0, 4, (4, 32, 64))).astype(np.uint16)
        model = rdm.ScienceRawModel.create_fake_data(shape=data.shape)
        model.data = data
        model.amp33 = np.zeros((4, 32, 128), np.uint16)
        values = {"read_pattern": _ROMAN_PATTERN, "nresultants": 4, "frame_time": 3.04,
                  **exposure}
        for key, value in values.items():
            model.meta.exposure[key] = value
        model.meta.instrument.detector = "WFI01"
        model.save(d / name)
        np.save(d / "r_data.npy", data)
        (d / "steps.yaml").write_text(_ROMAN_STEPS)
    return setup


def _check_roman_slopes(d, result, run):
    data = np.load(d / "r_data.npy").astype(np.float64)
    design = np.vstack([_ROMAN_TIMES, np.ones(4)]).T
    expected = np.linalg.lstsq(design, data.reshape(4, -1), rcond=None)[0][0].reshape(32, 64)
    with fits.open(d / "out.fits") as hdul:
        np.testing.assert_allclose(hdul["SCI"].data, expected, rtol=1e-6, atol=0)
        assert hdul[0].header["GRPREADS"] == "1;2-3;4-7;8"
        assert hdul[0].header["DETECTOR"] == "WFI01"


def _asdf_bytes(d):
    """Setup: a plain ASDF file that is no Roman data model."""
    import asdf

    asdf.AsdfFile({"data": np.arange(12, dtype=np.uint16).reshape(1, 3, 4)}).write_to(
        d / "r_uncal.asdf")
    (d / "steps.yaml").write_text(_ROMAN_STEPS)


def _cut_roman(d):
    """Setup: the Roman file cut inside its data block."""
    path = d / "r_uncal.asdf"
    path.write_bytes(path.read_bytes()[:-4000])


_ROMAN = ["reduce", "r_uncal.asdf", "-c", "steps.yaml", "-o", "out.fits"]
ROMAN_INPUT = [
    # an ASDF file was "not a readable FITS file"; now its read pattern, frame time and
    # detector are the file's (a config of steps alone)
    works("reduce-roman-level1-steps-only", _ROMAN, _roman(), _check_roman_slopes,
          timeout=90),
    refused("reduce-roman-read-pattern-shorter-than-data", _ROMAN,
            _roman(read_pattern=[[1], [2, 3], [4]]), mentions=r"read_pattern", timeout=90),
    refused("reduce-roman-placeholder-frame-time", _ROMAN, _roman(frame_time=-999999.0),
            mentions=r"frame_time", timeout=90),
    refused("reduce-roman-config-pixel-rate-disagrees",
            ["reduce", "r_uncal.asdf", "-c", "rate.yaml", "-o", "out.fits"],
            chain(_roman(), write("rate.yaml", "geometry: {pixel_rate: 2.0e+5}\n"
                                               + _ROMAN_STEPS)),
            mentions=r"PIXRATE", timeout=90),
    refused("reduce-asdf-not-a-roman-model", _ROMAN, _asdf_bytes, mentions=r"asdf",
            timeout=90),
    refused("reduce-asdf-magic-then-garbage", _ROMAN,
            chain(write("r_uncal.asdf", b"#ASDF 1.0.0\n\x00\xff garbage"),
                  write("steps.yaml", _ROMAN_STEPS)), mentions=r"asdf", timeout=90),
    refused("reduce-roman-cut-inside-data", _ROMAN, chain(_roman(), _cut_roman),
            mentions=r"r_uncal\.asdf", timeout=90),
]


@pytest.mark.parametrize("case", ROMAN_INPUT)
def test_issue31_roman_input(case, inputs, runner, tmp_path):
    test_input(case, inputs, runner, tmp_path)


# Issue 31: JWST-format output
_FIT_RN = "steps:\n  - fit_ramp: {read_noise: 10.0}\n"  # readout order: slopes not un-chopped
_JWST = ["--format", "jwst"]


def _check_jwst_rate(d, result, run):
    """The rate file: SCI the native reduction's slopes, ERR**2 the sum of the variances."""
    assert run(["reduce", "raw.fits", "-c", "rn.yaml", "-o", "native.fits"]).rc == 0
    with fits.open(d / "j_rate.fits") as j, fits.open(d / "native.fits") as n:
        assert j[0].header["DATAMODL"] == "ImageModel" and "TELESCOP" not in j[0].header
        np.testing.assert_array_equal(j["SCI"].data, n["SCI"].data.astype(np.float32))
        np.testing.assert_allclose(j["ERR"].data.astype(float) ** 2,
                                   j["VAR_POISSON"].data.astype(float) + j["VAR_RNOISE"].data,
                                   rtol=1e-6)


_RN_UNCHOPPED = write("rn.yaml", "steps:\n  - unchop: {}\n  - fit_ramp: {read_noise: 10.0}\n")
ROUND4_JWST = [
    works("reduce-format-jwst-rate", ["reduce", "raw.fits", "-c", "rn.yaml", "-o",
                                      "j_rate.fits", *_JWST], _RN_UNCHOPPED, _check_jwst_rate),
    # no read-noise model: no VAR_RNOISE / VAR_POISSON to write; refused before reducing
    refused("reduce-format-jwst-without-read-noise", [*REDUCE, *_JWST], mentions=r"read_noise"),
    # slopes of a chopped readout are not an image of the array
    refused("reduce-format-jwst-in-readout-order", ["reduce", "raw.fits", "-c", "rn.yaml",
                                                    "-o", "j.fits", *_JWST],
            write("rn.yaml", _FIT_RN), mentions=r"unchop"),
    refused("reduce-format-jwst-over-an-existing-file",
            ["reduce", "raw.fits", "-c", "rn.yaml", "-o", "red.fits", *_JWST], _RN_UNCHOPPED,
            mentions=r"overwrite"),
    refused("reduce-format-jwst-of-several-inputs",
            ["reduce", "raw.fits", "red.fits", "-c", "rn.yaml", "-o", "outdir", *_JWST],
            _RN_UNCHOPPED, mentions=r"--format"),
    refused("reduce-format-unknown", [*REDUCE, "--format", "fits2"], mentions=r"--format"),
]


@pytest.mark.parametrize("case", ROUND4_JWST)
def test_jwst_format_output(case, inputs, runner, tmp_path):
    test_input(case, inputs, runner, tmp_path)


# Issue 31: JWST input

_JW_RATE, _JW_T = 30.0, 0.0494 * np.arange(4)  # ADU/s; SUB64P-like frame time, 4 groups
_JW_LIGHT = np.indices((64, 64)).min(axis=0) >= 4  # DMS: the corner's first 4 rows, columns


def _jw_uncal(name="jw_uncal.fits", nints=2, **cards):
    """Setup: a 64 x 64 NIRCam NRCA1 subarray at the array's corner, ``nints`` integrations
    of 4 groups of uint16 ADU, written by stdatamodels (JWST's keywords: FASTAXIS = -1, an
    integer; NFRAMES = 1 frame per group), then ``cards`` set in its primary header."""
    def setup(d):
        from stdatamodels.jwst.datamodels import Level1bModel
        ramps = 1000.0 + _JW_RATE * _JW_T[:, None, None] * np.ones((nints, 1, 64, 64))
        ramps[..., ~_JW_LIGHT] = 1000.0  # the array's reference pixels: no signal
        m = Level1bModel(data=np.round(ramps).astype(np.uint16))
        m.meta.telescope = "JWST"
        m.meta.instrument.name, m.meta.instrument.detector = "NIRCAM", "NRCA1"
        e = m.meta.exposure
        e.readpatt, e.nints, e.ngroups, e.nframes, e.groupgap = "RAPID", nints, 4, 1, 0
        e.frame_time, e.group_time, e.noutputs = 0.0494, 0.0494, 1
        s = m.meta.subarray
        s.xstart, s.ystart, s.xsize, s.ysize, s.fastaxis, s.slowaxis = 1, 1, 64, 64, -1, 2
        m.save(d / name)
        if cards:
            with fits.open(d / name, mode="update") as hdul:
                for key, value in cards.items():
                    if value is None:
                        del hdul[0].header[key]
                    else:
                        hdul[0].header[key] = value
    return setup


_STEPS_ONLY = "steps:\n  - correct_reference: {strategy: mean}\n  - fit_ramp: {}\n"


def _check_jw_slopes(d, result, run):
    """The light-sensitive slopes are numpy's least squares of the stored counts, in the
    detector orientation (NRCA1: the DMS image flipped left to right); the output reads
    back through our own reader (its header keeps TELESCOP, but the file is ours)."""
    counts = np.round(1000.0 + _JW_RATE * _JW_T)
    expected = np.polyfit(_JW_T, counts, 1)[0]
    light = _JW_LIGHT[:, ::-1]
    with fits.open(d / "out.fits") as hdul:
        assert hdul["INTSLOPE"].shape == (2, 64, 64)
        assert hdul[0].header["JWFASTAX"] == -1 and hdul[0].header["NFRAMES"] == 4
        np.testing.assert_allclose(hdul["SCI"].data[light], expected, rtol=1e-4)
    back = run(["spectrum", "out.fits", "-o", "pk.ecsv"])
    assert back.rc == 0, back.describe()


JWST_INPUT = [
    # every JWST file was refused: "keyword FASTAXIS must be a string, got 2"
    works("reduce-jwst-uncal-with-steps-alone", ["reduce", "jw_uncal.fits", "-c", "jw.yaml",
                                                 "-o", "out.fits"],
          chain(_jw_uncal(), write("jw.yaml", "steps: [fit_ramp]\n")), _check_jw_slopes),
    works("reduce-jwst-uncal-with-reference-correction",
          ["reduce", "jw_uncal.fits", "-c", "jw.yaml", "-o", "out.fits"],
          chain(_jw_uncal(), write("jw.yaml", _STEPS_ONLY)), _check_jw_slopes),
    refused("reduce-jwst-without-tframe", ["reduce", "jw_uncal.fits", "-c", "jw.yaml", "-o",
                                           "out.fits"],
            chain(_jw_uncal(TFRAME=None, TGROUP=None), write("jw.yaml", _STEPS_ONLY)),
            mentions=r"TFRAME.*readout\.frame_time"),
    refused("reduce-jwst-irs2", ["reduce", "jw_uncal.fits", "-c", "jw.yaml", "-o", "out.fits"],
            chain(_jw_uncal(READPATT="NRSIRS2"), write("jw.yaml", _STEPS_ONLY)),
            mentions=r"IRS2"),
    refused("reduce-jwst-fastaxis-0", ["reduce", "jw_uncal.fits", "-c", "jw.yaml", "-o",
                                       "out.fits"],
            chain(_jw_uncal(FASTAXIS=0), write("jw.yaml", _STEPS_ONLY)), mentions=r"FASTAXIS"),
    refused("reduce-jwst-config-frame-time-disagrees",
            ["reduce", "jw_uncal.fits", "-c", "jw.yaml", "-o", "out.fits"],
            chain(_jw_uncal(), write("jw.yaml", "readout: {frame_time: 2.0}\n" + _STEPS_ONLY)),
            mentions=r"TFRAME.*frame_time.*override"),
    refused("reduce-jwst-config-preset", ["reduce", "jw_uncal.fits", "-c", "jw.yaml", "-o",
                                          "out.fits"],
            chain(_jw_uncal(), write("jw.yaml", "geometry: {preset: SIDECAR}\n" + _STEPS_ONLY)),
            mentions=r"preset"),
    refused("reduce-jwst-subsize-disagrees", ["reduce", "jw_uncal.fits", "-c", "jw.yaml",
                                              "-o", "out.fits"],
            chain(_jw_uncal(SUBSIZE1=128), write("jw.yaml", _STEPS_ONLY)),
            mentions=r"SUBSIZE"),
]


@pytest.mark.parametrize("case", JWST_INPUT)
def test_issue31_jwst_input(case, inputs, runner, tmp_path):
    test_input(case, inputs, runner, tmp_path)


# Issue 35: read events and too few reads in detect_jumps

def _four_reads(d):
    """A 4-read dark ramp (16 x 16, 10 e read noise) written by the package."""
    import spherex_reduce as sr

    s = sr.ReadoutSchedule(sr.DetectorGeometry(16, 16, 1, ref_border=0), skip=1, ref_reads=0,
                           ref_mode="none", phantom_reads=0, nframes=4, frame_time=1.5)
    ramps = 1000 + np.random.default_rng(0).normal(0, 10, (4, 16, 16))
    sr.write(sr.Exposure.from_arrays(ramps.astype("f4"), s), d / "raw4.fits")


def _check_skipped_in_one_line(d, result, run):
    """4 reads without read_noise: exit 0, S_JUMP SKIPPED, and one warning line saying why
    and naming the fix (before: the SKIPPED status alone)."""
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    assert len(lines) == 1, result.describe()
    assert re.match(r"spherex-reduce reduce: warning: detect_jumps: 4 reads: too few.*give "
                    r"detect_jumps\.read_noise", lines[0]), lines[0]
    assert fits.getheader(d / "out.fits")["S_JUMP"] == "SKIPPED"
    with_noise = run(["reduce", "raw4.fits", "-c", "jumps_rn.yaml", "-o", "out2.fits"])
    assert with_noise.rc == 0 and not with_noise.stderr.strip(), with_noise.describe()
    assert fits.getheader(d / "out2.fits")["S_JUMP"] == "COMPLETE"


JUMP_INPUT = [
    works("reduce-detect-jumps-on-4-reads-without-read-noise",
          ["reduce", "raw4.fits", "-c", "jumps.yaml", "-o", "out.fits"],
          chain(_four_reads, write("jumps.yaml", "steps: [detect_jumps, fit_ramp]\n"),
                write("jumps_rn.yaml", "steps: [{detect_jumps: {read_noise: 10.0}}, "
                                       "fit_ramp]\n")),
          _check_skipped_in_one_line),
]


@pytest.mark.parametrize("case", JUMP_INPUT)
def test_issue35_jump_input(case, inputs, runner, tmp_path):
    test_input(case, inputs, runner, tmp_path)


# Issue 33: characterize (darks in, a scene out)
CHARACTERIZE = ["characterize", "raw.fits", "-c", "unchop", "-o", "model.yaml"]
CHARACTERIZE_INPUT = [
    refused("characterize-reduced-image", ["characterize", "red.fits", "-c", "unchop", "-o",
                                           "model.yaml"], mentions=r"raw darks"),
    refused("characterize-same-file-twice-as-output", ["characterize", "raw.fits", "-c",
                                                       "unchop", "-o", "raw.fits"]),
    refused("characterize-nan-huge-segments", [*CHARACTERIZE, "--segments", "1e9"]),
    refused("characterize-nbins-zero", [*CHARACTERIZE, "--nbins", "0"]),
    refused("characterize-exponent-nan", [*CHARACTERIZE, "--exponent", "nan"]),
    refused("characterize-not-fits", ["characterize", "scene.yaml", "-c", "unchop", "-o",
                                      "model.yaml"]),
]


@pytest.mark.parametrize("case", CHARACTERIZE_INPUT)
def test_issue33_characterize_input(case, inputs, runner, tmp_path):
    test_input(case, inputs, runner, tmp_path)


# Issue 33: a scene's unit and gain, and its pixel populations
_ADU_SCENE = SCENE + "noise: {components: [{name: w, alpha: 1.0e-3}]}\n"
SCENE_UNIT_INPUT = [
    refused("simulate-scene-unit-furlong", SIMULATE_BAD,
            write("bad.yaml", SCENE + "unit: furlong\n"), mentions=r"unit: expected electron"),
    refused("simulate-scene-unit-list", SIMULATE_BAD, write("bad.yaml", SCENE + "unit: [adu]\n"),
            mentions=r"unit: expected electron"),
    refused("simulate-scene-gain-nan", SIMULATE_BAD,
            write("bad.yaml", _ADU_SCENE + "unit: adu\ngain: .nan\n"), mentions=r"gain:"),
    refused("simulate-scene-gain-negative", SIMULATE_BAD,
            write("bad.yaml", _ADU_SCENE + "unit: adu\ngain: -2\n"), mentions=r"gain:"),
    refused("simulate-scene-gain-with-electrons", SIMULATE_BAD,
            write("bad.yaml", SCENE + "gain: 2\n"), mentions=r"gain: the scene is in electrons"),
    refused("simulate-scene-adu-current-without-gain", SIMULATE_BAD,
            write("bad.yaml", _ADU_SCENE + "unit: adu\nscene: {dark_current: 1}\n"),
            mentions=r"gain"),
    refused("simulate-scene-population-seed-text", SIMULATE_BAD,
            write("bad.yaml", SCENE + "scene: {population_seed: seven}\n"),
            mentions=r"population_seed"),
    refused("forecast-scene-adu-without-gain", ["forecast", "bad.yaml", "-c", "unchop", "-o",
                                                "f.ecsv"],
            write("bad.yaml", _ADU_SCENE + "unit: adu\n"), mentions=r"gain"),
    works("simulate-scene-in-adu", SIMULATE_BAD,
          write("bad.yaml", _ADU_SCENE + "unit: adu\ngain: 2\nscene: {dark_current: 1}\n"),
          check=lambda d, result, run: None),
]


@pytest.mark.parametrize("case", SCENE_UNIT_INPUT)
def test_issue33_scene_unit_input(case, inputs, runner, tmp_path):
    test_input(case, inputs, runner, tmp_path)


# Issue 33: overflowing spreads and gains (a probe of the new scene keys)
SCENE_OVERFLOW_INPUT = [
    refused("simulate-dark-current-spread-overflows", SIMULATE_BAD,
            write("bad.yaml", SCENE + "scene: {dark_current: 1.0e-300, "
                                      "dark_current_spread: 1.0e+9}\n"),
            mentions=r"scene.dark_current_spread: .* beyond what can be drawn"),
    refused("simulate-telegraph-spread-overflows", SIMULATE_BAD,
            write("bad.yaml", SCENE + "scene: {rtn: [{fraction: 0.1, amplitude: 1.0e-300, "
                                      "amplitude_spread: 1.0e+9}]}\n"),
            mentions=r"scene.rtn\[0\].amplitude_spread"),
    refused("simulate-scene-gain-tiny", SIMULATE_BAD,
            write("bad.yaml", _ADU_SCENE + "unit: adu\ngain: 1.0e-300\n"), mentions=r"gain:"),
    refused("forecast-scene-gain-overflows-the-noise", ["forecast", "bad.yaml", "-c", "unchop",
                                                        "-o", "f.ecsv"],
            write("bad.yaml", SCENE + "unit: adu\ngain: 1.0e+9\nnoise: {components: "
                                      "[{name: w, alpha: 1.0}]}\n"),
            mentions=r"gain: .* out of range"),
]


@pytest.mark.parametrize("case", SCENE_OVERFLOW_INPUT)
def test_issue33_scene_overflow_input(case, inputs, runner, tmp_path):
    test_input(case, inputs, runner, tmp_path)


# Issue 33: design-readout scene terms
_DESIGN_TERMS = """\
scene:
  geometry: {{nrows: 32, ncols: 16, nchannels: 2, ref_border: 4}}
  readout: {{nframes: 4}}
  noise: {{components: [{{name: f, beta: 0.01, alpha: 1.0e-5}}]}}
  scene: {terms}
band: {{kmin: 0.3, kmax: 1.5}}
bins: 4
baseline: {{skip: 1, ref_reads: 8, phantom_reads: 2}}
search: {{families: [golden], phantom_reads: [2], ref_reads: [8], ref_modes: [distributed],
         iterations: 1}}
realizations: 0
"""
DESIGN_TERMS = ["design-readout", "design.yaml", "-o", "best.yaml"]


def _design_terms(terms):
    return write("design.yaml", _DESIGN_TERMS.format(terms=terms))


def _carried(d, result, run):
    """BEST.yaml holds the terms the search left out, as the design's scene gave them, and
    stdout one note per term (hot pixels, telegraph pixels)."""
    import yaml

    assert yaml.safe_load((d / "best.yaml").read_text())["scene"] == {
        "dark_current": 2.0, "hot_pixel_fraction": 0.01, "hot_pixel_current": 300.0,
        "rtn": [{"fraction": 0.02, "amplitude": 25.0, "pixels": "all"}]}
    notes = [line for line in result.stdout.splitlines() if line.startswith("note: ")]
    assert [n.split(":")[1] for n in notes] == [" scene.hot_pixel_fraction", " scene.rtn"]


DESIGN_TERMS_INPUT = [
    refused("design-readout-hot-pixel-fraction-above-one", DESIGN_TERMS,
            _design_terms("{hot_pixel_fraction: 1.5}"),
            mentions=r"scene: scene\.hot_pixel_fraction: must be in \[0, 1\], got 1\.5$"),
    refused("design-readout-hot-pixel-fraction-text", DESIGN_TERMS,
            _design_terms("{hot_pixel_fraction: lots}"), mentions=r"scene\.hot_pixel_fraction"),
    refused("design-readout-dark-current-spread-nan", DESIGN_TERMS,
            _design_terms("{dark_current: 1.0, dark_current_spread: .nan}"),
            mentions=r"scene\.dark_current_spread"),
    refused("design-readout-hot-spread-overflows", DESIGN_TERMS,
            _design_terms("{hot_pixel_fraction: 0.1, hot_pixel_current: 1.0e-300, "
                          "hot_pixel_current_spread: 1.0e+9}"),
            mentions=r"scene\.hot_pixel_current_spread: .* beyond what can be drawn"),
    refused("design-readout-rtn-not-a-population", DESIGN_TERMS, _design_terms("{rtn: [3]}"),
            mentions=r"scene\.rtn"),
    refused("design-readout-rtn-seventeen-populations", DESIGN_TERMS,
            _design_terms("{rtn: [" + ", ".join(["{fraction: 0.01}"] * 17) + "]}"),
            mentions=r"scene\.rtn: a list of 1 to 16 telegraph populations, got 17"),
    refused("design-readout-model-file-rtn-rate-negative", DESIGN_TERMS,
            chain(write("design.yaml", "scene: model.yaml\nrealizations: 0\n"),
                  write("model.yaml", SCENE + "scene: {rtn: {fraction: 0.1, rate: -2}}\n")),
            mentions=r"scene: scene\.rtn\.rate: must be in"),
    works("design-readout-populations-carried-into-best", DESIGN_TERMS,
          _design_terms("{dark_current: 2.0, hot_pixel_fraction: 0.01, hot_pixel_current: "
                        "300.0, rtn: [{fraction: 0.02, amplitude: 25.0, pixels: all}]}"),
          check=_carried),
]


@pytest.mark.parametrize("case", DESIGN_TERMS_INPUT)
def test_issue33_design_readout_scene_terms(case, inputs, runner, tmp_path):
    test_input(case, inputs, runner, tmp_path)


# Issue 33: a window without its pixel rate
def _window_without_rate(d):
    """`_window` with its frame time, the config's ``pixel_rate`` taken out."""
    _window(f"frame_time: {WINDOW_FRAME!r}")(d)
    text = (d / "win.yaml").read_text()
    (d / "win.yaml").write_text(text.replace(", pixel_rate: 1.0e+5", ""))


WINDOW_RATE_INPUT = [
    # it asked for NCHAN and PIXRATE: NCHAN comes from the window's full array
    refused("reduce-window-without-pixel-rate",
            ["reduce", "win.fits", "-c", "win.yaml", "-o", "out.fits"], _window_without_rate,
            mentions=r"missing readout keyword\(s\) PIXRATE: .*sections: geometry\.pixel_rate; "
                     r"the window's NCHAN, SCANDIR and REFBORD come from its full array$"),
]


@pytest.mark.parametrize("case", WINDOW_RATE_INPUT)
def test_issue33_window_without_pixel_rate(case, inputs, runner, tmp_path):
    test_input(case, inputs, runner, tmp_path)
