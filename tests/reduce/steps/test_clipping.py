"""sigma_clip against astropy: the same pixels masked, hard cases, refusals.

astropy is given the light-sensitive pixels only: reference pixels (a border whose
widths each test writes out with numpy) neither enter the statistics nor are clipped."""

import numpy as np
import pytest
from astropy import units as u
from astropy.stats import sigma_clip as astropy_sigma_clip

from spherex_reduce import (
    DetectorGeometry,
    Exposure,
    ReadoutSchedule,
    dq,
    sigma_clip,
)
from spherex_reduce.core.errors import SpherexReduceError


def sched(nframes=4, skip=3):
    return ReadoutSchedule(DetectorGeometry(32, 32, 2, ref_border=2), skip=skip, ref_reads=4,
                           phantom_reads=0, nframes=nframes)


def image(s, values, **kw):
    return Exposure.from_arrays(values, s, order="physical", unit=u.electron / u.s, **kw)


def border(shape, top=0, bottom=0, left=0, right=0):
    """The reference pixels of a physical-order image: rows ``top`` from row 0 and
    ``bottom`` from the last, columns ``left`` from column 0 and ``right`` from the last."""
    ny, nx = shape
    ref = np.zeros(shape, bool)
    ref[:top] = ref[ny - bottom:] = True
    ref[:, :left] = ref[:, nx - right:] = True
    return ref


#: the reference pixels of `sched` (ref_border=2)
REF32 = border((32, 32), 2, 2, 2, 2)


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
    ref = astropy_sigma_clip(np.ma.MaskedArray(data, mask=mask | np.isnan(data) | REF32),
                             **akw)
    expected = np.ma.getmaskarray(ref) & ~REF32
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
    ref_pixels = border((1024, 1024), 4, 4, 4, 4)
    ref = astropy_sigma_clip(np.ma.MaskedArray(data, mask=np.isnan(data) | ref_pixels),
                             **{"sigma": 5.0, "maxiters": None, **kw})
    expected = np.ma.getmaskarray(ref) & np.isfinite(data) & ~ref_pixels
    assert expected.sum() > 100
    assert np.array_equal(out.dq & dq.HOT != 0, expected)


@pytest.mark.parametrize("kw", [{"sigma": 0.5}, {"sigma_lower": 0.3, "sigma_upper": 0.6},
                                {"sigma": 0.5, "cenfunc": "mean", "stdfunc": "mad_std"}])
def test_sigma_clip_below_one_sigma_matches_astropy(kw):
    # thresholds under 1 sigma, iterated to the end, clip everything on astropy's
    # compiled path but nothing on its axis=None path: the step must follow the latter
    data = np.random.default_rng(2).normal(0, 1, (32, 32))
    out = sigma_clip(image(sched(), data), **kw)
    ref = astropy_sigma_clip(np.ma.MaskedArray(data, mask=REF32),
                             **{"sigma": 5.0, "maxiters": None, **kw})
    assert np.array_equal(out.dq & dq.HOT != 0, np.ma.getmaskarray(ref) & ~REF32)


def test_sigma_clip_of_an_image_without_usable_pixels():
    data = np.full((32, 32), np.nan)
    out = sigma_clip(image(sched(), data))
    assert out.header["NHOTPIX"] == 0


def test_sigma_clip_finds_injected_hot_pixels_only():
    rng = np.random.default_rng(1)
    data = rng.normal(0, 1, (32, 32))
    hot = [(2, 2), (20, 29), (29, 2)]
    for r, c in hot:
        data[r, c] = 50.0
    data[[1, 31, 10], [2, 0, 30]] = 50.0  # reference pixels: not clipped
    out = sigma_clip(image(sched(), data))
    assert sorted(zip(out.tables["HOTPIX"]["row"], out.tables["HOTPIX"]["column"],
                      strict=True)) == hot


def test_sigma_clip_refuses_ramps():
    s = sched()
    with pytest.raises(SpherexReduceError, match="fit the ramps first"):
        sigma_clip(Exposure.from_arrays(np.zeros((4, s.n_reads, 32)), s))


def test_informational_flags_are_clipped_like_clean_pixels():
    """A slope flagged only JUMP or SATURATED is valid: it enters the statistics and is
    clipped as astropy clips it; a DO_NOT_USE pixel stays out."""
    s = sched()
    rng = np.random.default_rng(3)
    values = rng.normal(0, 1, (32, 32))
    values[[3, 4, 5], [3, 4, 5]] = 1e4
    flags = np.zeros((32, 32), np.uint32)
    flags[3, 3], flags[4, 4], flags[5, 5] = dq.JUMP, dq.SATURATED, dq.DO_NOT_USE
    out = sigma_clip(image(s, values, mask=flags), sigma=5.0)
    expected = astropy_sigma_clip(np.ma.masked_array(values, (flags == dq.DO_NOT_USE) | REF32),
                                  sigma=5.0, maxiters=None).mask & (flags != dq.DO_NOT_USE) & ~REF32
    np.testing.assert_array_equal((out.dq & dq.HOT) != 0, expected)
    assert out.dq[3, 3] == dq.JUMP | dq.HOT and out.dq[4, 4] == dq.SATURATED | dq.HOT
    assert out.dq[5, 5] == dq.DO_NOT_USE


@pytest.mark.parametrize("widths", [{"top": 4, "bottom": 4, "left": 4, "right": 4},
                                    {"top": 4, "left": 4}])
def test_reference_pixels_stay_out_of_the_statistics_and_are_never_clipped(widths):
    """Reference pixels at 1e6 (and one at -1e6): astropy on the light-sensitive pixels
    alone gives the clipped pixels, and no reference pixel is flagged.  Mixed in, they
    made the spread ~1e5 and nothing was clipped; in readout order too."""
    ref_pixels = border((24, 24), **widths)
    s = ReadoutSchedule(DetectorGeometry(24, 24, 2, ref_border=widths), skip=5, ref_reads=3,
                        phantom_reads=0, nframes=4)
    rng = np.random.default_rng(5)
    values = rng.normal(10.0, 1.0, (24, 24))
    values[ref_pixels] = 1e6
    values[0, 0] = -1e6
    values[[9, 15, 19], [12, 7, 18]] = [30.0, -20.0, 17.0]
    expected = astropy_sigma_clip(np.ma.MaskedArray(values, ref_pixels), sigma=5.0,
                                  maxiters=None).mask & ~ref_pixels
    assert expected.sum() == 3
    out = sigma_clip(image(s, values))
    np.testing.assert_array_equal((out.dq & dq.HOT) != 0, expected)
    assert out.header["NHOTPIX"] == 3
    # the same image in readout order: each read holds its physical row
    readout = sigma_clip(Exposure.from_arrays(values[s.rows], s, unit=u.electron / u.s))
    np.testing.assert_array_equal((readout.dq & dq.HOT) != 0, expected[s.rows])


@pytest.mark.parametrize(("sigma", "cenfunc", "stdfunc"), [
    (5.0, "median", "std"), (3.0, "mean", "mad_std"), (0.5, "median", "std")])
def test_clipped_pixels_are_astropys_mask_of_the_usable_pixels(sigma, cenfunc, stdfunc):
    """`clipped_pixels` (the step's clip, also the slope scatter's) masks exactly what
    astropy's ``sigma_clip`` masks of the same pixels with the others masked, NaN and
    outliers included; at 0.5 sigma astropy ends with every pixel kept."""
    from astropy.stats import SigmaClip

    from spherex_reduce.reduce.steps.clipping import clipped_pixels

    rng = np.random.default_rng(3)
    data = rng.normal(0.0, 1.0, (64, 48))
    data[rng.integers(0, 64, 30), rng.integers(0, 48, 30)] = rng.normal(0, 40, 30)
    data[5, :4] = np.nan
    usable = np.isfinite(data)
    usable[:2] = False  # left out: never clipped, not in the statistics
    data[0, 0] = 1e6
    clipper = SigmaClip(sigma=sigma, maxiters=None, cenfunc=cenfunc, stdfunc=stdfunc)
    got = clipped_pixels(data, usable, clipper)
    expected = np.ma.getmaskarray(astropy_sigma_clip(
        np.ma.MaskedArray(data, mask=~usable), sigma=sigma, maxiters=None, cenfunc=cenfunc,
        stdfunc=stdfunc)) & usable
    np.testing.assert_array_equal(got, expected)
    assert not got[:2].any() and (got.any() or sigma < 1)
