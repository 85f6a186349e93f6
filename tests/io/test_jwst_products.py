"""``reduce --format jwst``: rate and rateints files that stdatamodels opens and validates."""

import numpy as np
import pytest
from _cli_helpers import run
from astropy.io import fits
from stdatamodels.jwst import datamodels as dm
from stdatamodels.jwst.datamodels import dqflags

from spherex_reduce import DetectorGeometry, Exposure, ReadoutSchedule, fit_ramp, write
from spherex_reduce.core import dq
from spherex_reduce.io.examples import example_raw_exposure
from spherex_reduce.io.jwst_products import jwst_dq, write_jwst

PIX = dqflags.pixel
READ_NOISE = 10.0  # e, the example's white noise


def _expected_dq(ours):
    """JWST flags of our flags, bit by bit, by the names of stdatamodels' dqflags.pixel."""
    names = {dq.DO_NOT_USE: ["DO_NOT_USE"], dq.SATURATED: ["SATURATED"],
             dq.HOT: ["OUTLIER", "DO_NOT_USE"], dq.NO_REFERENCE: ["OTHER_BAD_PIXEL", "DO_NOT_USE"],
             dq.FEW_READS: ["DO_NOT_USE"], dq.NOT_READ: ["DROPOUT", "DO_NOT_USE"],
             dq.JUMP: ["JUMP_DET"], dq.REFERENCE: ["REFERENCE_PIXEL", "DO_NOT_USE"]}
    out = np.zeros(np.shape(ours), np.int64)
    for b in range(32):
        hit = (np.asarray(ours, np.int64) >> b) & 1 == 1
        for name in names.get(1 << b, ["OTHER_BAD_PIXEL", "DO_NOT_USE"]):
            out[hit] |= PIX[name]
    return out


def test_dq_bits_are_jwst_bits():
    """Every bit of ours (and one we do not define) against stdatamodels' flags; a pixel our
    mask leaves out has DO_NOT_USE, one it keeps has not (reference pixels aside: JWST marks
    them DO_NOT_USE)."""
    values = np.array([0, *(1 << b for b in range(32)), dq.JUMP | dq.SATURATED,
                       dq.FEW_READS | dq.SATURATED, dq.REFERENCE | dq.JUMP], np.uint32)
    got = jwst_dq(values)
    assert got.dtype == np.uint32
    np.testing.assert_array_equal(got, _expected_dq(values))
    assert got.tolist()[:9] == [0, PIX["DO_NOT_USE"], PIX["SATURATED"],
                                PIX["OUTLIER"] | 1, PIX["OTHER_BAD_PIXEL"] | 1, 1,
                                PIX["DROPOUT"] | 1, PIX["JUMP_DET"], PIX["REFERENCE_PIXEL"] | 1]
    masked = ~dq.image_usable(values) | ((values & dq.REFERENCE) != 0)
    np.testing.assert_array_equal((got & PIX["DO_NOT_USE"]) != 0, masked)


def _config(tmp_path, read_noise=READ_NOISE):
    path = tmp_path / "pipe.yaml"
    fit = "{}" if read_noise is None else f"{{read_noise: {read_noise}}}"
    path.write_text("steps:\n  - unchop: {}\n  - subtract_phantom: {}\n"
                    "  - correct_reference: {strategy: mean}\n  - detect_jumps: {}\n"
                    f"  - fit_ramp: {fit}\n")
    return path


def _ols_variances(n, dt):
    """Uniform-weight least squares over ``n`` equally spaced reads ``dt`` apart: the slope's
    read-noise variance per read-noise variance, and its shot-noise variance per unit rate."""
    t = np.arange(n) * dt
    w = (t - t.mean()) / ((t - t.mean()) ** 2).sum()
    cov = np.minimum.outer(t, t)  # Poisson charge: cov(t_i, t_j) = rate * min(t_i, t_j)
    return float(w @ w), float(w @ cov @ w)


def test_rate_file_opens_validates_and_holds_our_reduction(tmp_path):
    """A raw exposure reduced with --format jwst and natively: ImageModel opens and validates
    the rate file (strict), SCI is our slope (float32), DQ our flags in JWST's bits,
    ERR**2 = VAR_POISSON + VAR_RNOISE, and the variances those of a least-squares slope."""
    raw = write(example_raw_exposure(seed=2), tmp_path / "raw.fits")
    cfg = _config(tmp_path)
    assert run("-q", "reduce", raw, "-c", cfg, "-o", tmp_path / "native.fits") == 0
    assert run("-q", "reduce", raw, "-c", cfg, "-o", tmp_path / "r_rate.fits",
               "--format", "jwst") == 0
    with dm.open(tmp_path / "r_rate.fits", strict_validation=True) as model:
        assert isinstance(model, dm.ImageModel)
        model.validate()
        sci, err, flags = model.data.copy(), model.err.copy(), model.dq.copy()
        vp, vr = model.var_poisson.copy(), model.var_rnoise.copy()
        assert model.meta.telescope is None  # not a JWST observation
    with fits.open(tmp_path / "native.fits") as f:
        nsci, nerr, ndq = f["SCI"].data, f["ERR"].data, f["DQ"].data
        rampfit = f["RAMPFIT"].data
        nframes = f[0].header["NFRAMES"]
    np.testing.assert_array_equal(sci, nsci.astype(np.float32))
    np.testing.assert_array_equal(flags, _expected_dq(ndq))
    np.testing.assert_allclose(err.astype(np.float64) ** 2, vp.astype(np.float64) + vr,
                               rtol=1e-6)
    # pixels of the sky fitted on every read, no jump: the closed forms
    frame_time = example_raw_exposure(seed=2).schedule.frame_time.value
    per_rn2, per_rate = _ols_variances(nframes, frame_time)
    whole = (ndq == 0) & (rampfit["nreads"] == nframes)
    assert whole.sum() > 1000
    np.testing.assert_allclose(vr[whole], READ_NOISE**2 * per_rn2, rtol=1e-6)
    # the shot noise of a rate >= 0 (fit_ramp's expected rates: its own tests), our own ERR
    rate = vp[whole] / per_rate
    assert (rate >= 0).all() and np.median(np.abs(rate - sci[whole])) < np.std(sci[whole])
    np.testing.assert_allclose(err[whole], nerr[whole], rtol=1e-5)
    assert (flags[0] & PIX["REFERENCE_PIXEL"]).all() and (flags[0] & PIX["DO_NOT_USE"]).all()


def _uncal(path, rates, ngroups, rng):
    """A 4-D SCI (integrations, groups, 8, 8) of ramps 1 s per group at ``rates`` e/s."""
    t = np.arange(ngroups, dtype=float)[None, :, None, None]
    sci = 100 + np.asarray(rates)[:, None, None, None] * t + rng.normal(0, 1, (len(rates),
                                                                        ngroups, 8, 8))
    fits.HDUList([fits.PrimaryHDU(), fits.ImageHDU(sci.astype("f4"), name="SCI")]).writeto(path)
    return path


def test_rateints_file_of_several_integrations(tmp_path):
    """A 4-D SCI of 3 integrations: CubeModel opens and validates the rateints file; each
    integration's SCI and DQ are the native INTSLOPE and INTDQ (in JWST's bits), its
    VAR_RNOISE and VAR_POISSON the closed forms of 5 groups 1 s apart."""
    uncal = _uncal(tmp_path / "u.fits", [2.0, 4.0, 3.0], 5, np.random.default_rng(1))
    cfg = tmp_path / "c.yaml"
    cfg.write_text("geometry: {nrows: 8, ncols: 8, nchannels: 1, ref_border: 0, "
                   "pixel_rate: 1.0e5}\nreadout: {ref_mode: none, phantom_reads: 0, "
                   "nframes: 5, skip: 8, frame_time: 1.0}\nsteps:\n"
                   "  - fit_ramp: {read_noise: 1.5}\n")
    assert run("-q", "reduce", uncal, "-c", cfg, "-o", tmp_path / "n.fits") == 0
    assert run("-q", "reduce", uncal, "-c", cfg, "-o", tmp_path / "r_rateints.fits",
               "--format", "jwst") == 0
    with dm.open(tmp_path / "r_rateints.fits", strict_validation=True) as model:
        assert isinstance(model, dm.CubeModel)
        model.validate()
        sci, err, flags = model.data.copy(), model.err.copy(), model.dq.copy()
        vp, vr = model.var_poisson.copy(), model.var_rnoise.copy()
    with fits.open(tmp_path / "n.fits") as f:
        slopes, intdq = f["INTSLOPE"].data, f["INTDQ"].data
    assert sci.shape == (3, 8, 8)
    np.testing.assert_array_equal(sci, slopes.astype(np.float32))
    np.testing.assert_array_equal(flags, _expected_dq(intdq))
    per_rn2, per_rate = _ols_variances(5, 1.0)
    np.testing.assert_allclose(vr, 1.5**2 * per_rn2, rtol=1e-6)
    np.testing.assert_allclose(vp, np.maximum(sci, 0) * per_rate, rtol=1e-5)
    np.testing.assert_allclose(err.astype(np.float64) ** 2, vp.astype(np.float64) + vr,
                               rtol=1e-6)


def _fitted(header=None):
    s = ReadoutSchedule(DetectorGeometry(8, 8, 1, ref_border=0), ref_mode="none",
                        phantom_reads=0, nframes=4, skip=1, frame_time=2.0)
    ramps = 5.0 * (2.0 * np.arange(4))[:, None, None] * np.ones((4, 8, 8))
    e = Exposure.from_arrays(ramps, s, header=header)
    return fit_ramp(e, read_noise=3.0)


def test_a_jwst_files_header_is_carried_and_no_other(tmp_path):
    """The primary header of a JWST file (as stdatamodels writes it) goes on, so stage 2
    finds the instrument; another file's keywords (a lab's DETECTOR = 5, which the schema
    refuses) are kept in SXRMETA only, with the readout keywords, which a JWST file's
    primary header does not get either (ours: NFRAMES the groups, FASTAXIS a string)."""
    ramp = dm.RampModel(data=np.zeros((1, 4, 8, 8), np.float32))
    ramp.meta.telescope, ramp.meta.instrument.name = "JWST", "NIRCAM"
    ramp.meta.instrument.detector, ramp.meta.exposure.type = "NRCA1", "NRC_IMAGE"
    ramp.meta.subarray.fastaxis, ramp.meta.subarray.slowaxis = -1, 2
    ramp.save(tmp_path / "jw_uncal.fits")
    jwst_header = fits.getheader(tmp_path / "jw_uncal.fits")
    for key in ("FASTAXIS", "SLOWAXIS"):  # a reader keeps the file's keywords of our names
        del jwst_header[key]  # only in its own (JWST's are integers, ours a string)
    fitted = _fitted(jwst_header)
    header = fitted.schedule.to_header(fitted.header)  # and adds ours, as a reader does
    header["FASTAXIS"] = "columns"
    assert header["NFRAMES"] == 4 and header["TELESCOP"] == "JWST"
    out = write_jwst(fitted.replace(header=header), tmp_path / "a_rate.fits")
    with dm.ImageModel(out, strict_validation=True) as model:
        model.validate()
        assert (model.meta.telescope, model.meta.instrument.name,
                model.meta.instrument.detector) == ("JWST", "NIRCAM", "NRCA1")
        assert model.meta.model_type == "ImageModel"
        # our readout keywords (NFRAMES: groups; JWST's: frames per group) are not carried
        assert model.meta.exposure.nframes is None and model.meta.subarray.fastaxis is None
        np.testing.assert_allclose(model.data, 5.0, rtol=1e-6)
    assert fits.getheader(out, "SXRMETA")["NFRAMES"] == 4
    lab = fits.Header({"DETECTOR": 5, "OBSERVER": "lab"})
    out = write_jwst(_fitted(lab), tmp_path / "b_rate.fits")
    with dm.ImageModel(out, strict_validation=True) as model:
        model.validate()
        assert model.meta.instrument.detector is None and model.meta.telescope is None
    meta = fits.getheader(out, "SXRMETA")
    assert meta["DETECTOR"] == 5 and meta["NFRAMES"] == 4 and "DETECTOR" not in fits.getheader(
        out)


def test_written_atomically_and_never_over_a_file(tmp_path):
    path = tmp_path / "x_rate.fits"
    path.write_bytes(b"precious")
    with pytest.raises(FileExistsError):
        write_jwst(_fitted(), path)
    assert path.read_bytes() == b"precious"
    write_jwst(_fitted(), path, overwrite=True)
    assert fits.getheader(path)["DATAMODL"] == "ImageModel"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["x_rate.fits"]


@pytest.mark.parametrize(("detector", "axes"), [("NRS1", (2, 1)), ("NRCA1", (-1, 2)),
                                               ("NRS2", (-2, -1))])
@pytest.mark.parametrize("nints", [1, 2])
def test_a_jwst_input_comes_back_in_its_own_orientation_and_subarray(tmp_path, detector,
                                                                     axes, nints):
    """A JWST uncal file (stdatamodels) reduced with --format jwst: the slopes in the file's
    DMS orientation (the reader works in the detector's), its subarray, axes and frames per
    group in JWST's keywords, so stage 2 places the image where the uncal file was."""
    fast, slow = axes
    ny, nx, ngroups, nframes = 32, 64, 4, 1
    along, rows = (nx, ny) if abs(fast) == 1 else (ny, nx)  # detector columns, rows
    tframe = (along + 12) * (rows + 1) * 1e-5
    t = tframe * np.arange(ngroups)
    y, x = np.indices((ny, nx))
    rates = (50.0 + 0.5 * x + 0.25 * y)[None] + 40.0 * np.arange(nints)[:, None, None]
    ramp = dm.RampModel(data=(1000.0 + rates[:, None] * t[None, :, None, None]).astype("f4"))
    ramp.meta.telescope, ramp.meta.instrument.name = "JWST", "NIRSPEC" if detector.startswith(
        "NRS") else "NIRCAM"
    ramp.meta.instrument.detector = detector
    e = ramp.meta.exposure
    e.readpatt, e.nints, e.ngroups, e.nframes, e.groupgap = "RAPID", nints, ngroups, nframes, 0
    e.frame_time, e.group_time, e.noutputs = tframe, tframe, 1
    s = ramp.meta.subarray
    (s.xstart, s.ystart), (s.ysize, s.xsize), (s.fastaxis, s.slowaxis) = (3, 1), (ny, nx), axes
    ramp.save(tmp_path / "jw_uncal.fits")
    config = tmp_path / "fit.yaml"
    config.write_text(f"steps:\n  - fit_ramp: {{read_noise: {READ_NOISE}}}\n")
    out = tmp_path / "jw_rate.fits"
    assert run("reduce", tmp_path / "jw_uncal.fits", "-c", config, "-o", out,
               "--format", "jwst") == 0
    with dm.CubeModel(out, strict_validation=True) as m:  # rateints: a 4-D SCI
        m.validate()
        np.testing.assert_allclose(m.data, rates, rtol=1e-5)
        sub = m.meta.subarray
        assert (sub.xstart, sub.ystart, sub.xsize, sub.ysize, sub.fastaxis, sub.slowaxis) == (
            3, 1, nx, ny, fast, slow)
        assert m.meta.exposure.nframes == nframes and m.meta.instrument.detector == detector
