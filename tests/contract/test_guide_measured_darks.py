"""The Measured darks guide as written: every command it shows runs on the files it describes.

The guide's first example (its doctest) writes ``lab.fits``; its YAML blocks are
``lab.yaml``, ``nirspec.yaml``, ``jwst_dark.yaml``, ``wfc3.yaml``, ``corner.yaml``,
``output.yaml`` and ``roman.yaml`` (the windows of a larger array, the HST-like file and the
Roman file are tested on their own).  The tests build the other inputs the commands name
from small arrays (the lab ramps one file per read and a mask file for them, a JWST uncal
file and a JWST dark reference file written by stdatamodels, a folder of darks, an HST-like
file of SCI extensions, a Roman level-1 file written by roman_datamodels), run every
``spherex-reduce`` command of the page (a new one must be given its inputs here) and check
the slopes against numpy.
"""

import hashlib
import re
import shlex
import shutil
import warnings

import numpy as np
import pytest
from _paths import ROOT
from astropy.io import fits
from astropy.table import Table
from astropy.utils.exceptions import AstropyUserWarning

from spherex_reduce.cli import main

GUIDE = ROOT / "docs" / "measured_darks.rst"
RATE = 12.0  # ADU/s of the JWST-like file's light-sensitive pixels
DARK, TFRAME_FULL = 0.02, 10.73677  # ADU/s of the JWST dark reference file; its frame time
#: commands of the sections on SCI extensions and on one mask file for the read files: run
#: by their own test, on their own inputs
OWN_TEST = ("wfc3.yaml", "--reads-dq")
#: the command of the section on Roman level-1 files: run by its own test, on a Roman file
ROMAN_CONFIG = "roman.yaml"
#: SAMPTIME of the HST-like file's reads, in time order: RAPID, then SPARS10-like gaps (s)
SAMPTIMES = [0.0, 2.932, 12.933, 22.934, 32.935, 42.936]


def _yaml_block(text, intro):
    m = re.search(re.escape(intro) + r".*?::\n\n(.*?)\n\n(?=\S)", text, re.S)
    assert m, f"no YAML block after {intro!r}"
    return "\n".join(line[4:] for line in m.group(1).splitlines()) + "\n"


def _commands(text):
    return (re.findall(r"^\s+(spherex-reduce .*)$", text, re.M)
            + re.findall(r"``(spherex-reduce [^`]*)``", text))


def _lab_file(text):
    """Run the guide's first doctest lines (up to ``lab.fits`` written)."""
    lines = []
    for line in text.splitlines():
        s = line.strip()
        if s.startswith((">>> ", "... ")):
            lines.append(s[4:])
        if 'writeto("lab.fits")' in line:
            break
    exec("\n".join(lines), {})  # the guide's own code


def _reads_of(lab, folder):
    folder.mkdir()
    with fits.open(lab) as hdul:
        for k, frame in enumerate(hdul["SCI"].data, start=1):
            sci = fits.ImageHDU(frame, name="SCI")
            sci.header["BUNIT"] = "ADU"
            fits.HDUList([fits.PrimaryHDU(), sci]).writeto(folder / f"read_{k}.fits")


def _jwst_uncal(path):
    """2 integrations of 8 groups of a 512 x 512 NIRSpec NRS1 subarray at the array's
    corner, uint16 ADU, written by stdatamodels as the JWST pipeline writes them (JWST's
    own keywords: NFRAMES = 1 frame per group, FASTAXIS = 2, SLOWAXIS = 1).  The array's
    reference pixels (the first 4 rows and columns of the corner) carry no signal."""
    from stdatamodels.jwst.datamodels import Level1bModel
    tframe = (512 + 12) * (512 + 1) * 1e-5  # JWST's frame time of one output
    t = tframe * np.arange(8)
    ramps = 1000.0 + RATE * t[:, None, None] * np.ones((512, 512))
    ramps[:, :4, :] = 1000.0
    ramps[:, :, :4] = 1000.0
    model = Level1bModel(data=np.round(np.stack([ramps, ramps + 5.0])).astype(np.uint16))
    model.meta.telescope = "JWST"
    model.meta.instrument.name, model.meta.instrument.detector = "NIRSPEC", "NRS1"
    e = model.meta.exposure
    e.readpatt, e.nints, e.ngroups, e.nframes, e.groupgap = "NRSRAPID", 2, 8, 1, 0
    e.frame_time, e.group_time, e.noutputs = tframe, tframe, 1
    s = model.meta.subarray
    s.xstart, s.ystart, s.xsize, s.ysize, s.fastaxis, s.slowaxis = 1, 1, 512, 512, 2, 1
    model.save(path)


def _jwst_dark(path):
    """A JWST dark reference file as CRDS holds them, written by stdatamodels (DarkModel):
    here a 512 x 512 NIRSpec NRS1 corner of 4 groups, 3-D float SCI of the dark signal, 2-D
    DQ, no TFRAME; the dark is DARK ADU/s."""
    from stdatamodels.jwst.datamodels import DarkModel
    t = TFRAME_FULL * np.arange(4)
    data = (DARK * t)[:, None, None] * np.ones((1, 512, 512), "f4")
    model = DarkModel(data=data, dq=np.zeros((512, 512), np.uint32),
                      err=np.ones_like(data))
    model.meta.telescope, model.meta.reftype = "JWST", "DARK"
    model.meta.instrument.name, model.meta.instrument.detector = "NIRSPEC", "NRS1"
    e = model.meta.exposure
    e.readpatt, e.nframes, e.ngroups, e.groupgap = "NRSRAPID", 1, 4, 0
    s = model.meta.subarray
    s.xstart, s.ystart, s.xsize, s.ysize, s.fastaxis, s.slowaxis = 1, 1, 512, 512, 2, 1
    model.save(path)


@pytest.mark.slow
def test_every_command_of_the_guide_runs_as_written(tmp_path, monkeypatch, capsys):
    text = GUIDE.read_text()
    monkeypatch.chdir(tmp_path)
    _lab_file(text)
    (tmp_path / "lab.yaml").write_text(_yaml_block(text, "As YAML (``lab.yaml``)"))
    (tmp_path / "nirspec.yaml").write_text(_yaml_block(text, "``nirspec.yaml`` for such a"))
    _reads_of(tmp_path / "lab.fits", tmp_path / "dark07")
    _jwst_uncal(tmp_path / "jw_uncal.fits")
    (tmp_path / "jwst_dark.yaml").write_text(_yaml_block(text, "As YAML (``jwst_dark.yaml``)"))
    _jwst_dark(tmp_path / "jwst_nirspec_dark_0046.fits")
    (tmp_path / "darks").mkdir()
    for name in ("dark01.fits", "dark02.fits"):
        shutil.copy(tmp_path / "lab.fits", tmp_path / "darks" / name)
    commands = [c for c in _commands(_without(text, LAYOUTS))  # those below: their own tests
                if not _window_command(c) and not any(own in c for own in OWN_TEST)
                and ROMAN_CONFIG not in c]
    commands.sort(key=lambda c: "-o lab_slopes.fits" not in c)  # read by a later one
    assert len(commands) >= 6, commands
    for command in commands:
        argv = (shlex.split(command)[1:] if "--reads" in command  # the package's own glob
                else _expand(command, tmp_path))  # the shell's glob
        if argv[0] == "fit-noise":  # 16 x 16, 5 reads: the guide says it is flagged
            capsys.readouterr()
            with warnings.catch_warnings():
                warnings.simplefilter("always", AstropyUserWarning)
                assert main(["-q", *argv]) == 0, command
            assert "warning: implausible noise fit" in capsys.readouterr().err
            continue
        assert main(["-q", *argv]) == 0, command

    # one file per read reduces as the 3-D file does (the files carry no DQ: the
    # pixel masked in lab.fits is the only difference)
    one = fits.getdata("lab_slopes.fits", "SCI")
    reads = fits.getdata("dark07.fits", "SCI")
    keep = np.ones(one.shape, bool)
    keep[9, 9] = False
    np.testing.assert_allclose(reads[keep], one[keep], rtol=1e-6)
    # the noise fit of the reads is the 3-D file's, bit for bit
    noise, noise07 = Table.read("noise.ecsv"), Table.read("noise07.ecsv")
    for name in ("alpha", "alpha_err", "beta", "beta_err", "gamma", "gamma_err", "chi2"):
        np.testing.assert_array_equal(noise07[name], noise[name], name)
    # the 4-D file: in electrons (gain 2), the light-sensitive slopes are the rate
    jw = fits.getdata("dark.fits", "SCI")
    np.testing.assert_allclose(jw[4:, 4:], 2.0 * RATE, rtol=0.02)
    # the dark reference file: its dark current, at the config's frame time
    np.testing.assert_allclose(fits.getdata("nirspec_dark_slopes.fits", "SCI"), DARK,
                               rtol=1e-5)
    # the folder: one output each and the summary
    assert sorted(p.name for p in (tmp_path / "reduced").iterdir()) == [
        "dark01_reduced.fits", "dark02_reduced.fits", "summary.ecsv"]


LAYOUTS = "Other readout layouts"
#: Each layout's file of the section: (YAML, input, stored shape, channel of each pixel,
#: reference pixels), written from the section's own words.
N_READS, T_NIRSPEC, T_WFC3, T_H4RG = 5, 10.737, 2.93, 3.04


def _section(text, title):
    start = text.index(f"{title}\n{'=' * len(title)}")
    following = re.search(r"\n\n([^\n]+)\n=+\n", text[start + 2 * len(title) + 2:])
    return text[start:start + 2 * len(title) + 2 + following.start()]


def _without(text, title):
    return text.replace(_section(text, title), "")


def _layout_files():
    """The section's three darks by hand: channel of each stored pixel and the stored
    reference pixels (each channel's mean of those is its offset in every read)."""
    r, c = np.indices((64, 64))
    nirspec = (r // 16, (c < 4) | (c >= 60), T_NIRSPEC)  # bands of rows; border left, right
    r, c = np.indices((32, 32))
    quadrant = (r // 16) * 2 + c // 16
    edge = (r < 5) | (r >= 27) | (c < 5) | (c >= 27)  # 5 all round; side_columns: all used
    wfc3 = (quadrant, edge, T_WFC3)
    r, c = np.indices((128, 128))
    h4rg = (c // 4, r < 4, T_H4RG)  # 32 stripes; reference rows on top (left: channel 0)
    return {"nirspec_science": nirspec, "wfc3_quadrants": wfc3, "h4rg": h4rg}


@pytest.mark.slow
def test_other_readout_layouts_run_as_written(tmp_path, monkeypatch):
    text = _section(GUIDE.read_text(), LAYOUTS)
    monkeypatch.chdir(tmp_path)
    rng = np.random.default_rng(7)
    darks = {}
    for name, (chan, ref, tframe) in _layout_files().items():
        (tmp_path / f"{name}.yaml").write_text(_yaml_block(text, f"As YAML (``{name}.yaml``)"))
        t = tframe * np.arange(N_READS)
        offset = rng.normal(0, 30, (N_READS, chan.max() + 1))[:, chan]
        slope = rng.uniform(0.5, 2.0, chan.shape)
        data = 1000 + slope * t[:, None, None] + rng.normal(0, 1, (N_READS, *chan.shape))
        data = np.where(ref, 1000.0, data) + offset  # reference pixels: the offsets alone
        sci = fits.ImageHDU(data.astype("f8"), name="SCI")
        sci.header["BUNIT"] = "ADU"
        fits.HDUList([fits.PrimaryHDU(), sci]).writeto(f"{name}_dark.fits")
        corrected = data.copy()
        for ch in range(chan.max() + 1):  # the offset: the mean of its reference pixels
            corrected[:, chan == ch] -= data[:, (chan == ch) & ref].mean(axis=1)[:, None]
        fitted = np.polyfit(t, corrected.reshape(N_READS, -1), 1)[0].reshape(chan.shape)
        darks[name] = (fitted, ref, (tmp_path / f"{name}_dark.fits").read_bytes())
    commands = _commands(text)
    assert len(commands) == 4, commands
    for command in commands:
        assert main(["-q", *shlex.split(command)[1:]]) == 0, command
    for name, (fitted, ref, raw) in darks.items():
        got = fits.getdata(f"{name}_slopes.fits", "SCI")
        assert got.shape == fitted.shape  # the stored orientation
        np.testing.assert_allclose(got[~ref], fitted[~ref], rtol=2**-23, atol=1e-9)  # float32
        assert (tmp_path / f"{name}_dark.fits").read_bytes() == raw
    assert (tmp_path / "wfc3_quadrants.png").stat().st_size > 0


def _expand(command, where):
    out = []
    for a in command.split()[1:]:
        out.extend(sorted(str(p.relative_to(where)) for p in where.glob(a)) if "*" in a
                   else [a])
    return out


WINDOWS = {"corner": ((5, 64, 64), 3.04, (4, 0), 4),   # reads x rows x columns, frame time,
           "output": ((3, 4096, 128), 2.7, (4, 4), 0)}  # top/bottom ref rows, left columns


def _window_command(command):
    return any(name in command for name in WINDOWS)


def _window_file(path, shape, top_bottom, left, rng):
    """Ramps in ADU: a slope per light-sensitive pixel and an offset per read (the one
    channel's) in every pixel, the reference pixels holding the offset alone."""
    n, nrows, ncols = shape
    rate = rng.uniform(0.5, 2.0, (nrows, ncols))
    ref = np.zeros((nrows, ncols), bool)
    top, bottom = top_bottom
    ref[:top] = ref[nrows - bottom:] = True
    ref[:, :left] = True
    rate[ref] = 0.0
    offset = 1000.0 + rng.normal(0, 30.0, n)
    return rate, offset, ref


def test_every_window_command_of_the_guide(tmp_path, monkeypatch, capsys):
    text = GUIDE.read_text()
    monkeypatch.chdir(tmp_path)
    rng = np.random.default_rng(21)
    commands = [c for c in _commands(text) if _window_command(c)]
    assert len(commands) == 3, commands
    made = {}
    for name, (shape, tframe, top_bottom, left) in WINDOWS.items():
        (tmp_path / f"{name}.yaml").write_text(_yaml_block(text, f"As YAML (``{name}.yaml``)"))
        rate, offset, ref = _window_file(tmp_path / f"{name}.fits", shape, top_bottom, left,
                                         rng)
        t = tframe * np.arange(shape[0])
        ramps = (offset[:, None, None] + rate * t[:, None, None]).astype(np.float32)
        sci = fits.ImageHDU(ramps, name="SCI")
        sci.header["BUNIT"] = "ADU"
        fits.HDUList([fits.PrimaryHDU(), sci]).writeto(f"{name}.fits")
        # independent: the mean of the reference rows of each read subtracted, then a
        # least-squares line through the reads at the frame time given
        rows = np.r_[0:top_bottom[0], shape[1] - top_bottom[1]:shape[1]]
        corrected = ramps.astype(np.float64) - ramps[:, rows].mean(axis=(1, 2))[:, None, None]
        slope = np.polyfit(t, corrected.reshape(shape[0], -1), 1)[0].reshape(shape[1:])
        made[name] = (hashlib.sha256((tmp_path / f"{name}.fits").read_bytes()).hexdigest(),
                      slope, ref, rate)
    for command in commands:
        assert main(["-q", *shlex.split(command)[1:]]) == 0, command
    out = capsys.readouterr().out
    assert "window 64x64 at row 0, column 0 of a 4096x4096 array" in out
    for name, (digest, slope, ref, rate) in made.items():
        assert hashlib.sha256((tmp_path / f"{name}.fits").read_bytes()).hexdigest() == digest
        with fits.open(f"{name}_slopes.fits") as hdul:
            got = hdul["SCI"].data
            assert hdul[0].header["FULLCOLS"] == 4096
            assert hdul[0].header["WINCOL"] == (0 if name == "corner" else 384)
        np.testing.assert_allclose(got[~ref], slope[~ref], rtol=1e-5, atol=1e-4)
        np.testing.assert_allclose(got[~ref], rate[~ref], rtol=1e-4)


def _wfc3_raw(path):
    """A WFC3/IR-like ``_raw`` file: 6 reads of 1024 x 1024 uint16 counts as SCI,1 ... SCI,6,
    the latest first, at uneven SAMPTIMEs, with DQ,i; the 5-pixel reference border holds no
    signal, each light-sensitive pixel its own rate; DQ,3 flags pixel (300, 700) in the read
    at 32.935 s.  Returns the counts in time order."""
    rng = np.random.default_rng(5)
    rate = rng.uniform(0.5, 3.0, (1024, 1024))
    rate[:5], rate[-5:], rate[:, :5], rate[:, -5:] = 0, 0, 0, 0
    t = np.array(SAMPTIMES)[:, None, None]
    counts = np.round(1000 + rate * t + rng.normal(0, 2, (6, 1024, 1024)) * (rate > 0))
    hdus = [fits.PrimaryHDU()]
    for version in range(1, 7):
        k = 6 - version
        sci = fits.ImageHDU(counts[k].astype(np.uint16), name="SCI", ver=version)
        sci.header.update(SAMPTIME=SAMPTIMES[k], BUNIT="COUNTS")
        dq = np.zeros((1024, 1024), np.int16)
        if k == 4:
            dq[300, 700] = 256  # WFC3: full-well saturation
        hdus += [sci, fits.ImageHDU(dq, name="DQ", ver=version)]
    fits.HDUList(hdus).writeto(path)
    return counts


def test_extensions_and_mask_file_commands_run_as_written(tmp_path, monkeypatch):
    """``wfc3.yaml`` on an HST-like file: each slope is numpy's least squares on the
    SAMPTIMEs (without the flagged read where DQ flags one); ``--reads-dq``: the read files
    with one 2-D mask give what the 3-D file with that mask as DQ gives."""
    text = GUIDE.read_text()
    monkeypatch.chdir(tmp_path)
    (tmp_path / "wfc3.yaml").write_text(_yaml_block(text, "As YAML (``wfc3.yaml``)"))
    counts = _wfc3_raw(tmp_path / "ib_raw.fits")
    _lab_file(text)
    (tmp_path / "lab.yaml").write_text(_yaml_block(text, "As YAML (``lab.yaml``)"))
    _reads_of(tmp_path / "lab.fits", tmp_path / "dark07")
    fits.PrimaryHDU(fits.getdata("lab.fits", "DQ").astype(np.int32)).writeto(
        "dark07_mask.fits")  # the 3-D file's own mask, as one file for the reads
    before = {p: p.read_bytes() for p in (tmp_path / "ib_raw.fits", tmp_path / "dark07_mask.fits")}
    commands = [c for c in _commands(text) if any(own in c for own in OWN_TEST)]
    assert len(commands) == 2, commands
    for command in commands:
        assert main(["-q", *shlex.split(command)[1:]]) == 0, command
    assert all(p.read_bytes() == b for p, b in before.items())

    slopes = fits.getdata("ib_slopes.fits", "SCI")
    design = np.vstack([SAMPTIMES, np.ones(6)]).T
    expected = np.linalg.lstsq(design, counts.reshape(6, -1), rcond=None)[0][0]
    expected = expected.reshape(1024, 1024)
    keep = [0, 1, 2, 3, 5]  # pixel (300, 700) without its flagged read
    expected[300, 700] = np.linalg.lstsq(design[keep], counts[keep, 300, 700], rcond=None)[0][0]
    np.testing.assert_allclose(slopes[5:-5, 5:-5], expected[5:-5, 5:-5], rtol=0, atol=1e-6)
    assert fits.getheader("ib_slopes.fits")["NFRAMES"] == 6

    assert main(["-q", "reduce", "lab.fits", "-c", "lab.yaml", "-o", "lab_slopes.fits"]) == 0
    one = fits.getdata("lab_slopes.fits", "SCI")
    masked = fits.getdata("dark07_masked.fits", "SCI")
    assert np.isnan(masked[9, 9]) and np.isfinite(np.delete(masked.ravel(), 9 * 16 + 9)).all()
    np.testing.assert_allclose(masked, one, rtol=1e-6)


def test_roman_command_runs_as_written(tmp_path, monkeypatch):
    """``roman.yaml`` (steps alone) on a Roman level-1 file written by roman_datamodels
    (WFI01: rows read from the last; a 32 x 64 stand-in for the 4096 x 4096 array): each
    slope is numpy's least squares of the resultants less their reference level on their
    times."""
    rdm = pytest.importorskip("roman_datamodels.datamodels")
    text = GUIDE.read_text()
    monkeypatch.chdir(tmp_path)
    (tmp_path / ROMAN_CONFIG).write_text(_yaml_block(text, f"As YAML (``{ROMAN_CONFIG}``)"))
    pattern = [[1], [2, 3], [4, 5, 6, 7], [8]]
    t = 3.04 * np.array([np.mean(r) for r in pattern])
    rng = np.random.default_rng(7)
    level = np.round(3000 + rng.normal(0, 20, 4))  # a drift per resultant, whole DN
    data = level[:, None, None] + np.zeros((4, 32, 64))  # the border: the drift alone
    active = (slice(None), slice(4, -4), slice(4, -4))
    data[active] += RATE * t[:, None, None] + rng.normal(0, 2, (4, 24, 56))
    data = np.round(data).astype(np.uint16)
    model = rdm.ScienceRawModel.create_fake_data(shape=data.shape)
    model.data, model.amp33 = data, np.zeros((4, 32, 128), np.uint16)
    model.meta.exposure.read_pattern, model.meta.exposure.nresultants = pattern, 4
    model.meta.exposure.frame_time = 3.04
    model.meta.instrument.detector = "WFI01"
    commands = [c for c in _commands(text) if ROMAN_CONFIG in c]
    assert len(commands) == 1, commands
    argv = shlex.split(commands[0])[1:]
    model.save(argv[1])
    assert main(["-q", *argv]) == 0, commands[0]
    slopes = fits.getdata(argv[argv.index("-o") + 1], "SCI")
    # numpy: every resultant less its reference level (the border rows are that level,
    # exactly, in every output), then least squares on the resultant times
    corrected = data[active] - level[:, None, None]
    design = np.vstack([t, np.ones(4)]).T
    expected = np.linalg.lstsq(design, corrected.reshape(4, -1), rcond=None)[0][0]
    np.testing.assert_allclose(slopes[4:-4, 4:-4], expected.reshape(24, 56), rtol=1e-5)
