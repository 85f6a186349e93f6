"""sigma_clip against astropy; pair differences; master darks with ccdproc; combine CLI."""

import numpy as np
import pytest
from astropy import units as u
from astropy.nddata import CCDData
from astropy.stats import mad_std
from astropy.stats import sigma_clip as astropy_sigma_clip

from spherex_reduce import (
    DetectorGeometry,
    Exposure,
    ReadoutSchedule,
    combine_darks,
    dq,
    pair_difference,
    read,
    sigma_clip,
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


@pytest.mark.parametrize("kw", [{}, {"sigma": 3.0, "maxiters": 2},
                                {"sigma": 2.5, "cenfunc": "mean", "stdfunc": "mad_std"},
                                {"sigma_lower": 2.0, "sigma_upper": 4.0}])
def test_sigma_clip_masks_exactly_what_astropy_masks(kw):
    rng = np.random.default_rng(0)
    data = rng.standard_t(3, (32, 32))  # heavy tails: many clipped
    data[3, 3] = 80.0
    data[5, 6] = np.nan
    mask = np.zeros((32, 32), bool)
    mask[7, 7] = True
    out = sigma_clip(image(sched(), data, mask=mask), **kw)
    akw = dict(kw)
    akw.setdefault("sigma", 5.0)
    akw.setdefault("maxiters", None)
    ref = astropy_sigma_clip(np.ma.MaskedArray(data, mask=mask | np.isnan(data)), **akw)
    expected = np.ma.getmaskarray(ref)
    assert np.array_equal(out.data.mask | np.isnan(data), expected)
    hot = expected & ~mask & np.isfinite(data)
    assert out.header["NHOTPIX"] == hot.sum() > 0
    assert np.array_equal(out.dq & dq.HOT != 0, hot)
    assert out.dq[7, 7] == dq.DO_NOT_USE  # the caller's flag is kept
    assert len(out.tables["HOTPIX"]) == hot.sum()


@pytest.mark.parametrize("kw", [{}, {"sigma": 3.0, "cenfunc": "mean", "stdfunc": "mad_std"}])
def test_sigma_clip_matches_astropy_on_a_large_heavy_tailed_image(kw):
    # a million pixels and a few hundred clipped: the bounds must select exactly the
    # pixels astropy's own (axis=None) sigma_clip masks
    s = ReadoutSchedule(DetectorGeometry(1024, 1024, 16, ref_border=4), skip=1,
                        ref_mode="none", phantom_reads=0, nframes=2)
    rng = np.random.default_rng(1)
    data = rng.standard_t(4, (1024, 1024))
    data[rng.random((1024, 1024)) < 1e-3] = np.nan
    out = sigma_clip(image(s, data), **kw)
    ref = astropy_sigma_clip(np.ma.MaskedArray(data, mask=np.isnan(data)),
                             **{"sigma": 5.0, "maxiters": None, **kw})
    expected = np.ma.getmaskarray(ref) & np.isfinite(data)
    assert expected.sum() > 100
    assert np.array_equal(out.dq & dq.HOT != 0, expected)


@pytest.mark.parametrize("kw", [{"sigma": 0.5}, {"sigma_lower": 0.3, "sigma_upper": 0.6},
                                {"sigma": 0.5, "cenfunc": "mean", "stdfunc": "mad_std"}])
def test_sigma_clip_below_one_sigma_matches_astropy(kw):
    # thresholds under 1 sigma, iterated to the end, clip everything on astropy's
    # compiled path but nothing on its axis=None path: the step must follow the latter
    data = np.random.default_rng(2).normal(0, 1, (32, 32))
    out = sigma_clip(image(sched(), data), **kw)
    ref = astropy_sigma_clip(data, **{"sigma": 5.0, "maxiters": None, **kw})
    assert np.array_equal(out.dq & dq.HOT != 0, np.ma.getmaskarray(ref))


def test_sigma_clip_of_an_image_without_usable_pixels():
    data = np.full((32, 32), np.nan)
    out = sigma_clip(image(sched(), data))
    assert out.header["NHOTPIX"] == 0


def test_sigma_clip_finds_injected_hot_pixels_only():
    rng = np.random.default_rng(1)
    data = rng.normal(0, 1, (32, 32))
    hot = [(1, 2), (20, 30), (31, 0)]
    for r, c in hot:
        data[r, c] = 50.0
    out = sigma_clip(image(sched(), data))
    assert sorted(zip(out.tables["HOTPIX"]["row"], out.tables["HOTPIX"]["column"],
                      strict=True)) == hot


def test_sigma_clip_refuses_ramps():
    s = sched()
    with pytest.raises(SpherexReduceError, match="fit the ramps first"):
        sigma_clip(Exposure.from_arrays(np.zeros((4, s.n_reads, 32)), s))


def test_pair_difference_scaling_uncertainty_and_refusal():
    s = sched()
    rng = np.random.default_rng(2)
    a_val, b_val = rng.normal(0, 1, (2, 32, 32))
    a = image(s, a_val, uncertainty=np.full((32, 32), 3.0))
    b = image(s, b_val, uncertainty=np.full((32, 32), 4.0),
              mask=np.eye(32, dtype=bool))
    d = pair_difference(a, b)
    np.testing.assert_allclose(d.data.data, (a_val - b_val) / np.sqrt(2))
    np.testing.assert_allclose(d.data.uncertainty.array, 5.0 / np.sqrt(2))
    assert np.array_equal(d.data.mask, np.eye(32, dtype=bool))
    assert d.header["PAIRDIFF"]
    other = image(sched(skip=4), b_val)
    with pytest.raises(SpherexReduceError, match=r"readout parameters differ \(skip: 3 vs 4"):
        pair_difference(a, other)
    with pytest.raises(SpherexReduceError, match="shapes differ"):
        pair_difference(a, Exposure.from_arrays(np.zeros((4, 32, 32)), s, order="physical"))


def test_pair_difference_doubles_nothing_for_identical_noise_statistics():
    # the 1/sqrt(2) keeps the per-exposure noise: std of the difference of two N(0, 1)
    s = sched()
    rng = np.random.default_rng(3)
    a, b = (image(s, rng.normal(0, 1, (32, 32))) for _ in range(2))
    assert np.std(pair_difference(a, b).data.data) == pytest.approx(1.0, rel=0.1)


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
    out2 = subtract_dark(sci, path)
    np.testing.assert_allclose(out2.data.data, out.data.data)
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
