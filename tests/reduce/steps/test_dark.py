"""Master darks: subtract_dark and combine_darks against ccdproc, and the combine command."""

import warnings

import numpy as np
import pytest
from astropy import units as u
from astropy.nddata import CCDData, StdDevUncertainty
from astropy.stats import mad_std

from spherex_reduce import (
    DetectorGeometry,
    Exposure,
    ReadoutSchedule,
    combine_darks,
    dq,
    read,
    subtract_dark,
    write,
)
from spherex_reduce.cli import main
from spherex_reduce.core.errors import SpherexReduceError


def sched(nframes=4, skip=3):
    return ReadoutSchedule(DetectorGeometry(32, 32, 2, ref_border=2), skip=skip, ref_reads=4,
                           phantom_reads=0, nframes=nframes)


def image(s, values, **kw):
    return Exposure.from_arrays(values, s, order="physical", unit=u.electron / u.s, **kw)


def test_subtract_dark_and_combine_with_ccdproc(tmp_path):
    s = sched()
    rng = np.random.default_rng(4)
    dark_level = rng.normal(5, 1, (32, 32))
    darks = [image(s, dark_level + rng.normal(0, 0.1, (32, 32))) for _ in range(5)]
    darks[0].data.data[0, 0] = 1e4  # an outlier the clipped combine rejects
    master = combine_darks(darks)
    import ccdproc

    ref = ccdproc.combine([CCDData(d.data.data, unit="electron/s") for d in darks],
                          method="average", sigma_clip=True, sigma_clip_low_thresh=3.0,
                          sigma_clip_high_thresh=3.0, sigma_clip_func=np.ma.median,
                          sigma_clip_dev_func=mad_std)
    np.testing.assert_allclose(master.data.data, ref.data)
    assert master.data.data[0, 0] == pytest.approx(dark_level[0, 0], abs=0.5)
    assert master.data.uncertainty is not None and master.header["NCOMBINE"] == 5
    sci = image(s, dark_level + 2.0)
    out = subtract_dark(sci, master)
    np.testing.assert_allclose(out.data.data, 2.0, atol=0.3)
    path = write(master, tmp_path / "master.fits")
    out2 = subtract_dark(sci, path)  # the file's master is float32: 5 x 6e-8 apart at most
    np.testing.assert_allclose(out2.data.data, out.data.data, rtol=0, atol=5 * 2**-22)
    assert out2.header["DARKFILE"] == "master.fits"
    ccd = CCDData(np.ones((32, 32)) * 1000, unit="electron / ks")  # unit conversion
    np.testing.assert_allclose(subtract_dark(sci, ccd).data.data, dark_level + 1.0)
    with pytest.raises(SpherexReduceError, match="at least two"):
        combine_darks(darks[:1])
    with pytest.raises(SpherexReduceError, match="does not match"):
        subtract_dark(sci, CCDData(np.ones((4, 4)), unit="electron/s"))


def test_combine_cli(tmp_path, capsys):
    s = sched()
    paths = []
    for i in range(3):
        paths.append(write(image(s, np.full((32, 32), float(i))), tmp_path / f"d{i}.fits"))
    out = tmp_path / "master.fits"
    assert main(["combine", *map(str, paths), "-o", str(out), "--sigma", "0"]) == 0
    master = read(out)
    np.testing.assert_allclose(master.data.data, 1.0)
    assert master.header["NCOMBINE"] == 3
    assert main(["combine", *map(str, paths), "-o", str(out)]) == 2  # exists
    assert "exists" in capsys.readouterr().err
    assert main(["combine", str(paths[0]), "-o", str(tmp_path / "m2.fits")]) == 2
    assert main(["combine", *map(str, paths), "-o", str(out), "--overwrite"]) == 0
    raw = sched()
    ramp = write(Exposure.from_arrays(np.zeros((4, raw.n_reads, 32)), raw), tmp_path / "r.fits")
    assert main(["combine", str(ramp), str(ramp), "-o", str(tmp_path / "m3.fits")]) == 2
    assert "fit the ramps first" in capsys.readouterr().err


MAD_TO_SIGMA = 1.482602218505602  # 1 / Phi^-1(3/4)


def _combined_by_numpy(values, usable, errors, method, sigma):
    """Per pixel, with numpy: clip the usable values around their median at ``sigma`` MAD
    spreads (one pass, as ccdproc), then combine what is left as ccdproc would; one value
    left: that value and its input's error; none: NaN."""
    x = np.where(usable, values, np.nan)
    kept = usable.copy()
    if sigma:
        with np.errstate(all="ignore"), warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            centre = np.nanmedian(x, axis=0)
            spread = MAD_TO_SIGMA * np.nanmedian(np.abs(x - centre), axis=0)
        kept &= np.abs(values - centre) <= sigma * spread
    mean, err = np.full(values.shape[1:], np.nan), np.full(values.shape[1:], np.nan)
    for r, c in np.ndindex(*values.shape[1:]):
        v, n = values[kept[:, r, c], r, c], kept[:, r, c].sum()
        if n == 1:
            mean[r, c], err[r, c] = v[0], errors[kept[:, r, c], r, c][0]
        elif n > 1:
            if method == "median":
                spread = MAD_TO_SIGMA * np.median(np.abs(v - np.median(v)))
                mean[r, c], err[r, c] = np.median(v), spread / np.sqrt(n)
            elif method == "average":
                mean[r, c], err[r, c] = v.mean(), v.std() / np.sqrt(n)
            else:
                mean[r, c], err[r, c] = v.sum(), v.std() * np.sqrt(n)
    return mean, err, kept.sum(axis=0)


@pytest.mark.parametrize("method", ["average", "median", "sum"])
@pytest.mark.parametrize("sigma", [3.0, 0.0])
def test_combine_flagged_values_stay_out_of_the_clip(method, sigma):
    """A value flagged in its input enters neither the clip nor the result: a pixel with one
    usable value of three keeps it (two flagged zeros made ccdproc's clip median and spread 0
    and clipped the good value: NaN); its error is its input's own, not the spread of one
    value (0); a pixel with none is NaN, flagged and counted; no raw numpy warning."""
    s = ReadoutSchedule(DetectorGeometry(8, 8, 1, ref_border=0), skip=1, ref_mode="none",
                        phantom_reads=0, nframes=2)
    rng = np.random.default_rng(7)
    values = rng.normal(5.0, 1.0, (3, 8, 8))
    errors = rng.uniform(0.5, 1.5, (3, 8, 8))
    flags = np.zeros((3, 8, 8), np.uint32)
    values[:2, 1, 1], flags[:2, 1, 1] = 0.0, dq.DO_NOT_USE  # one usable value of three
    values[:2, 2, 2] = np.nan  # one finite value of three
    flags[:, 3, 3] = dq.DO_NOT_USE  # none usable
    flags[0, 3, 3] |= dq.HOT
    values[:, 4, 4] = np.nan  # none finite
    values[0, 5, 5], flags[0, 5, 5] = 1e6, dq.DO_NOT_USE  # a flagged outlier: two left
    values[1, 6, 6] = 1e3  # a clipped outlier (with the clip)
    flags[2, 7, 7] = dq.JUMP  # informational: used
    before = values.copy()
    darks = [image(s, values[k], uncertainty=errors[k], mask=flags[k]) for k in range(3)]
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        master = combine_darks(darks, method=method, sigma=sigma)
    usable = np.isfinite(values) & ((flags & ~np.uint32(dq.INFORMATIONAL)) == 0)
    mean, err, n = _combined_by_numpy(values, usable, errors, method, sigma)
    np.testing.assert_allclose(master.data.data, mean, rtol=1e-12, equal_nan=True)
    unc = master.data.uncertainty.represent_as(StdDevUncertainty).array
    np.testing.assert_allclose(unc, err, rtol=1e-12, equal_nan=True)
    assert master.data.data[1, 1] == values[2, 1, 1] and unc[1, 1] == errors[2, 1, 1]
    assert master.data.data[2, 2] == values[2, 2, 2]
    assert np.isnan(master.data.data[3, 3]) and np.isnan(master.data.data[4, 4])
    np.testing.assert_array_equal(master.dq & dq.DO_NOT_USE, np.where(n == 0, dq.DO_NOT_USE, 0))
    assert master.dq[3, 3] == dq.DO_NOT_USE | dq.HOT
    assert master.header["NCOMB1"] == (n == 1).sum() and master.header["NCOMB0"] == 2
    # side by side with ccdproc.combine: the same where every input is usable
    import ccdproc

    kw = dict(sigma_clip=True, sigma_clip_low_thresh=sigma, sigma_clip_high_thresh=sigma,
              sigma_clip_func=np.ma.median, sigma_clip_dev_func=mad_std) if sigma else {}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ref = ccdproc.combine([CCDData(values[k], unit="electron/s", mask=~usable[k])
                               for k in range(3)], method=method, dtype=np.float64, **kw)
    clean = usable.all(axis=0)
    np.testing.assert_allclose(master.data.data[clean], ref.data[clean], rtol=1e-12)
    np.testing.assert_allclose(unc[clean], ref.uncertainty.array[clean], rtol=1e-12)
    np.testing.assert_array_equal(values, before)  # inputs untouched
    np.testing.assert_array_equal(darks[0].data.data, before[0])
