"""A 4-D SCI (integrations, groups, rows, columns: the JWST "uncal" layout).

Every file is built here from small arrays as other software writes it (no
``READOUT`` table; the readout from the pipeline config given with ``-c``).
Each integration's slopes are checked against numpy's least squares, the
mean against an independent inverse-variance weighted mean.
"""

import numpy as np
import pytest
from _cli_helpers import digest, one_line_error, run
from astropy import units as u
from astropy.io import fits

import spherex_reduce as sr
from spherex_reduce import dq
from spherex_reduce.core.errors import FormatError
from spherex_reduce.reduce.integrations import INTEGRATION_IMAGES, combine_integrations

NINT, NGROUPS, NROWS, NCOLS = 3, 5, 16, 16
TFRAME = 2.0
GEOMETRY = {"nrows": NROWS, "ncols": NCOLS, "nchannels": 2, "ref_border": 0, "pixel_rate": 1e5}
READOUT = {"skip": 4, "ref_mode": "none", "phantom_reads": 0, "nframes": NGROUPS,
           "frame_time": TFRAME}
ONE_BAD = (1, 3, 7)  # (integration, read, column): every group flagged, in one integration
ALL_BAD = (5, 2)  # (read, column): flagged in every integration


def _config(path, steps=("fit_ramp: {weighting: uniform}",)):
    def flow(d):
        return "{" + ", ".join(f"{k}: {v}" for k, v in d.items()) + "}"
    path.write_text(f"geometry: {flow(GEOMETRY)}\nreadout: {flow(READOUT)}\n"
                    "steps:\n" + "".join(f"  - {s}\n" for s in steps))
    return path


def _cube(seed=5):
    """Ramps of one rate per pixel, with different noise in each integration, as float32."""
    rng = np.random.default_rng(seed)
    t = np.arange(NGROUPS)[None, :, None, None] * TFRAME
    rate = rng.uniform(1, 5, (1, 1, NROWS, NCOLS))
    noise = np.array([0.3, 1.0, 3.0])[:, None, None, None]  # integrations weigh differently
    sci = 1000 + rate * t + noise * rng.normal(size=(NINT, NGROUPS, NROWS, NCOLS))
    return sci.astype(np.float32)


def _flags():
    flags = np.zeros((NINT, NGROUPS, NROWS, NCOLS), np.uint8)
    k, r, c = ONE_BAD
    flags[k, :, r, c] = 1
    flags[:, :, ALL_BAD[0], ALL_BAD[1]] = 1
    flags[0, 2, 9, 9] = 4  # not bit 0: masks by default, not with --dq-bits 1
    return flags


def _uncal(path, sci, flags=None):
    hdus = [fits.PrimaryHDU(), fits.ImageHDU(sci, name="SCI")]
    if flags is not None:
        hdus.append(fits.ImageHDU(flags, name="DQ"))
    fits.HDUList(hdus).writeto(path, checksum=True)
    return path


def _fit(ramps):
    """numpy least squares of every pixel: slopes and their residual standard deviations."""
    n = ramps.shape[0]
    t = np.arange(n) * TFRAME
    design = np.vstack([t, np.ones(n)]).T
    y = ramps.reshape(n, -1).astype(np.float64)
    coef = np.linalg.lstsq(design, y, rcond=None)[0]
    resid = y - design @ coef
    sigma = np.sqrt((resid**2).sum(axis=0) / (n - 2) / ((t - t.mean()) ** 2).sum())
    return coef[0].reshape(ramps.shape[1:]), sigma.reshape(ramps.shape[1:])


def _expected(sci):
    slopes, sigma = (np.stack(a) for a in zip(*(_fit(sci[k]) for k in range(NINT)),
                                              strict=True))
    good = np.ones(slopes.shape, bool)
    good[ONE_BAD] = False
    good[:, ALL_BAD[0], ALL_BAD[1]] = False
    w = np.where(good, 1 / sigma**2, 0)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = (w * np.where(good, slopes, 0)).sum(axis=0) / w.sum(axis=0)
        err = 1 / np.sqrt(w.sum(axis=0))
    return slopes, sigma, mean, err


def test_cli_reduces_each_integration_and_their_weighted_mean(tmp_path):
    """reduce on a 4-D file: INTSLOPE is each integration's least squares, SCI the
    inverse-variance mean; a pixel flagged in one integration uses the others, one flagged
    in all is NaN and DO_NOT_USE; the input's bytes are unchanged."""
    sci = _cube()
    raw = _uncal(tmp_path / "uncal.fits", sci, _flags())
    before = digest(raw)
    out = tmp_path / "out.fits"
    assert run("-q", "reduce", raw, "-c", _config(tmp_path / "fit.yaml"), "-o", out,
               "--dq-bits", "1") == 0
    assert digest(raw) == before
    slopes, sigma, mean, err = _expected(sci)
    with fits.open(out) as hdul:
        names = [h.name for h in hdul]
        assert all(n in names for n in INTEGRATION_IMAGES)
        assert hdul["INTSLOPE"].data.shape == (NINT, NROWS, NCOLS)
        assert hdul["INTSLOPE"].header["BUNIT"] == hdul["SCI"].header["BUNIT"] == "electron / s"
        assert hdul[0].header["SXRNINT"] == NINT and hdul[0].header["NEXTEND"] == len(names) - 1
        islope, ierr, idq = (hdul[n].data for n in INTEGRATION_IMAGES)
        got, got_err, got_dq = hdul["SCI"].data, hdul["ERR"].data, hdul["DQ"].data
        prov = hdul["PROVENANCE"].data
        assert sorted(set(prov["integration"])) == list(range(NINT))
    k, r, c = ONE_BAD
    assert np.isnan(islope[k, r, c]) and idq[k, r, c] & dq.DO_NOT_USE
    ok = np.isfinite(islope)
    assert ok.sum() == islope.size - 1 - NINT
    np.testing.assert_allclose(islope[ok], slopes[ok], rtol=1e-6, atol=1e-6)
    # the fit's residuals are summed from float32 reads near 1000: ~1e-4 of sigma
    np.testing.assert_allclose(ierr[ok], sigma[ok], rtol=1e-3)
    used = np.isfinite(mean)
    assert not used[ALL_BAD] and used.sum() == NROWS * NCOLS - 1
    np.testing.assert_allclose(got[used], mean[used], rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(got_err[used], err[used], rtol=1e-3)
    # and the weighted mean of the file's own INTSLOPE and INTERR, to the float32 they
    # are all stored in (each value rounded to nearest, 6e-8: a few roundings apart)
    w = np.where(ok, 1 / ierr.astype(np.float64)**2, 0)
    with np.errstate(invalid="ignore"):
        own = (w * np.where(ok, islope, 0)).sum(axis=0) / w.sum(axis=0)
    np.testing.assert_allclose(got[used], own[used], rtol=5e-7)
    np.testing.assert_allclose(got_err[used], 1 / np.sqrt(w.sum(axis=0))[used], rtol=5e-7)
    # the pixel flagged in one integration: the weighted mean of the other two, unflagged
    others = [j for j in range(NINT) if j != k]
    w = 1 / sigma[others, r, c] ** 2
    np.testing.assert_allclose(got[r, c], (w * slopes[others, r, c]).sum() / w.sum(), rtol=1e-5,
                               atol=1e-5)
    assert got_dq[r, c] == 0
    assert np.isnan(got[ALL_BAD]) and np.isnan(got_err[ALL_BAD])
    assert got_dq[ALL_BAD] & dq.DO_NOT_USE and got_dq[ALL_BAD] & dq.FEW_READS
    assert (got_dq[used] == 0).all()
    back = sr.read(out)  # the reader takes the output, extra images and all
    np.testing.assert_array_equal(back.data.data, got)


def test_read_one_integration(tmp_path):
    """read(path, integration=k) gives integration k's ramps (and DQ); plain read refuses a
    4-D SCI saying how to reduce it; a bad index is named."""
    sci, flags = _cube(), _flags()
    raw = _uncal(tmp_path / "uncal.fits", sci, flags)
    for k in range(NINT):
        e = sr.read(raw, integration=k, **GEOMETRY, **READOUT)
        np.testing.assert_array_equal(e.data.data, sci[k])
        np.testing.assert_array_equal(e.dq != 0, flags[k] != 0)
        assert e.header["SXRINT"] == k
    with pytest.raises(FormatError, match=r"4-D .*spherex-reduce reduce.*integration=i"):
        sr.read(raw, **GEOMETRY, **READOUT)
    for bad in (NINT, -1, 1.0, True):
        with pytest.raises(FormatError, match="not one of the file's 3 integrations"):
            sr.read(raw, integration=bad, **GEOMETRY, **READOUT)
    mask = np.zeros((NROWS, NCOLS), np.int32)
    mask[4, 6] = 1  # a 2-D DQ: every read of one pixel in every integration
    pixel = sr.read(_uncal(tmp_path / "mask.fits", sci, mask), integration=2, **GEOMETRY,
                    **READOUT)
    (read,) = np.flatnonzero(pixel.schedule.rows == 4)  # row 4's read (chopped order)
    assert [tuple(i) for i in np.argwhere(pixel.dq)] == [(g, read, 6) for g in range(NGROUPS)]
    phantom = _uncal(tmp_path / "phantom.fits", sci)
    with fits.open(phantom, mode="append") as hdul:
        hdul.append(fits.ImageHDU(np.arange(NINT * NGROUPS * NROWS * 2, dtype="f4").reshape(
            NINT, NGROUPS, NROWS, 2), name="PHANTOM"))
    e = sr.read(phantom, integration=1, **GEOMETRY, **{**READOUT, "phantom_reads": 2})
    assert e.phantom.shape == (NGROUPS, NROWS, 2) and e.phantom[0, 0, 0] == NGROUPS * NROWS * 2
    flat = _uncal(tmp_path / "ramps.fits", sci[0])
    with pytest.raises(FormatError, match="not 4-D"):
        sr.read(flat, integration=0, **GEOMETRY, **READOUT)


def test_scaled_integers(tmp_path):
    """uint16 integrations (BZERO 32768) are scaled one integration at a time."""
    sci = np.round(_cube(seed=8)).astype(np.uint16) + 30000
    raw = _uncal(tmp_path / "u16.fits", sci)
    before = digest(raw)
    p = sr.Pipeline({"geometry": GEOMETRY, "readout": READOUT,
                     "steps": [{"fit_ramp": {"weighting": "uniform"}}]})
    res = sr.reduce_integrations(raw, p)
    for k in range(NINT):
        np.testing.assert_allclose(res.slopes[k].value, _fit(sci[k].astype(float))[0],
                                   rtol=1e-6, atol=1e-6)
    assert digest(raw) == before


def test_five_dimensions_refused(tmp_path, capsys):
    raw = _uncal(tmp_path / "five.fits", np.zeros((2, 2, NGROUPS, NROWS, NCOLS), "f4"))
    out = tmp_path / "out.fits"
    assert run("-q", "reduce", raw, "-c", _config(tmp_path / "fit.yaml"), "-o", out) == 2
    one_line_error(capsys, "SCI must be 2-D", "4-D", "(2, 2, 5, 16, 16)")
    assert not out.exists()


def test_pipeline_must_fit_the_ramps(tmp_path, capsys):
    raw = _uncal(tmp_path / "uncal.fits", _cube())
    out = tmp_path / "out.fits"
    cfg = _config(tmp_path / "p.yaml", steps=("unchop: {}",))
    assert run("-q", "reduce", raw, "-c", cfg, "-o", out) == 2
    one_line_error(capsys, "integration 0", "fit_ramp")
    assert not out.exists()


def test_batch_gives_the_single_file_result(tmp_path):
    """Several 4-D inputs reduced as a batch: each output is the single reduce's."""
    cfg = _config(tmp_path / "fit.yaml")
    a = _uncal(tmp_path / "a.fits", _cube(seed=1))
    b = _uncal(tmp_path / "b.fits", _cube(seed=2))
    single = tmp_path / "single.fits"
    assert run("-q", "reduce", a, "-c", cfg, "-o", single) == 0
    outdir = tmp_path / "batch"
    assert run("-q", "reduce", a, b, "-c", cfg, "-o", outdir, "--scheduler", "serial") == 0
    with fits.open(single) as one, fits.open(outdir / "a_reduced.fits") as many:
        for name in ("SCI", "ERR", "DQ", *INTEGRATION_IMAGES):
            np.testing.assert_array_equal(one[name].data, many[name].data)


def test_combine_without_uncertainties():
    """Images without uncertainties: the plain mean of the usable ones, uncertainty NaN."""
    s = sr.ReadoutSchedule(sr.DetectorGeometry(2, 2, 1, ref_border=0), ref_mode="none",
                           phantom_reads=0, nframes=2)
    images = [sr.Exposure.from_arrays(np.full((2, 2), v), s) for v in (1.0, 2.0, 6.0)]
    images[2] = images[2].replace(mask=np.array([[1, 0], [0, 0]], bool))
    r = combine_integrations(images)
    np.testing.assert_array_equal(r.exposure.data.data, [[1.5, 3.0], [3.0, 3.0]])
    assert np.isnan(r.exposure.data.uncertainty.array).all()
    assert r.flags.shape == (3, 2, 2) and r.flags[2, 0, 0] == dq.DO_NOT_USE


def test_write_extra_images_named_once(tmp_path):
    """write's images: a Quantity's unit is BUNIT; a reserved or repeated name is refused."""
    s = sr.ReadoutSchedule(sr.DetectorGeometry(2, 2, 1, ref_border=0), ref_mode="none",
                           phantom_reads=0, nframes=2)
    e = sr.Exposure.from_arrays(np.ones((2, 2)), s)
    out = sr.write(e, tmp_path / "x.fits", images={"extra": np.zeros((3, 2, 2)) * u.s})
    with fits.open(out) as hdul:
        assert hdul["EXTRA"].header["BUNIT"] == "s" and hdul["EXTRA"].data.shape == (3, 2, 2)
    for name in ("SCI", "readout"):
        with pytest.raises(ValueError, match="reserved"):
            sr.write(e, tmp_path / "y.fits", images={name: np.zeros(2)})
    with pytest.raises(ValueError, match="already used"):
        sr.write(e.replace(tables={"EXTRA": None}), tmp_path / "y.fits",
                 images={"extra": np.zeros(2)})
    assert not (tmp_path / "y.fits").exists()


def test_a_file_that_is_not_4d_is_named_by_the_reader(tmp_path):
    path = tmp_path / "plain.fits"
    fits.PrimaryHDU(np.zeros((5, 7), np.float32)).writeto(path)
    pipe = sr.Pipeline({"steps": ["fit_ramp"]})
    with pytest.raises(FormatError, match="integration=0 given but SCI has shape"):
        sr.reduce_integrations(path, pipe)


def test_reduce_input_names_a_wrong_argument_order(tmp_path):
    from spherex_reduce.reduce.integrations import reduce_input

    pipe = sr.Pipeline({"steps": ["fit_ramp"]})
    with pytest.raises(TypeError, match=r"reduce_input\(input, pipeline\)"):
        reduce_input(pipe, str(tmp_path / "raw.fits"))


def test_a_quoted_glob_given_as_the_input_is_a_missing_file(tmp_path, capsys):
    # only --reads expands a glob: as IN.fits it names no file (and can never pick an
    # output that is one of the files it would match)
    for k in (1, 2):
        fits.PrimaryHDU(np.zeros((4, 4), np.float32)).writeto(tmp_path / f"read_{k}.fits")
    before = digest(tmp_path / "read_1.fits")
    assert run("reduce", tmp_path / "read_*.fits", "-c", "unchop",
               "-o", tmp_path / "read_1.fits", "--overwrite") == 2
    one_line_error(capsys, "no such file")
    assert digest(tmp_path / "read_1.fits") == before
