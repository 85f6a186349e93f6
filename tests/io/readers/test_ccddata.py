"""A reduced image as astropy's CCDData (issue 31): unit, uncertainty and a mask of the
unusable pixels only, as `sr.read` reads it; the readout keywords in SCI's own header."""

import numpy as np
import pytest
from astropy import units as u
from astropy.io import fits
from astropy.nddata import CCDData, StdDevUncertainty

import spherex_reduce as sr
from spherex_reduce import dq
from spherex_reduce.core.errors import FormatError
from spherex_reduce.io import read_ccddata
from spherex_reduce.io.examples import example_raw_exposure


@pytest.fixture
def reduced(tmp_path):
    """A slope image with every kind of flag: informational ones (REFERENCE, JUMP,
    SATURATED) and unusable ones (DO_NOT_USE, HOT, FEW_READS), alone and together."""
    raw = example_raw_exposure(seed=3)
    image = sr.Pipeline({"steps": ["unchop", "fit_ramp"]}).run(raw)
    rng = np.random.default_rng(5)
    bits = np.array([0, dq.REFERENCE, dq.JUMP, dq.SATURATED, dq.JUMP | dq.SATURATED,
                     dq.DO_NOT_USE, dq.HOT, dq.FEW_READS | dq.JUMP, dq.REFERENCE | dq.HOT],
                    np.uint32)
    flags = rng.choice(bits, image.shape).astype(np.uint32)
    err = rng.uniform(0.5, 2.0, image.shape)
    e = sr.Exposure.from_arrays(image.data.data, image.schedule, unit=u.electron / u.s,
                                uncertainty=err, mask=flags, header=image.header,
                                order="physical")
    return sr.write(e, tmp_path / "slopes.fits"), image.data.data, err, flags


def test_ccddata_has_the_unit_the_uncertainty_and_a_mask_of_the_unusable_pixels(reduced):
    path, data, err, flags = reduced
    ccd = CCDData.read(path, format="spherex_reduce")
    assert ccd.unit == u.electron / u.s
    np.testing.assert_array_equal(ccd.data, data.astype(np.float32))  # stored float32
    assert isinstance(ccd.uncertainty, StdDevUncertainty)
    np.testing.assert_array_equal(ccd.uncertainty.array, err.astype(np.float32))
    informational = dq.JUMP | dq.SATURATED | dq.REFERENCE
    unusable = (flags & ~np.uint32(informational)) != 0
    np.testing.assert_array_equal(ccd.mask, unusable)
    np.testing.assert_array_equal(ccd.flags, flags)
    assert 0 < unusable.sum() < (flags != 0).sum()
    mine = sr.read(path)  # the same as the package's own reader
    assert mine.unit == ccd.unit
    np.testing.assert_array_equal(mine.data.uncertainty.array, ccd.uncertainty.array)
    np.testing.assert_array_equal(mine.data.mask, ccd.mask)
    assert ccd.meta["NROWS"] == mine.schedule.geometry.nrows
    same = read_ccddata(path)
    np.testing.assert_array_equal(same.mask, ccd.mask)
    # astropy's own reader, pointed at ERR and DQ, masks every flag, informational or not
    theirs = CCDData.read(path, hdu_uncertainty="ERR", hdu_mask="DQ")
    np.testing.assert_array_equal(theirs.mask, flags != 0)


def test_the_readout_keywords_are_in_the_images_own_header(reduced):
    path = reduced[0]
    primary, sci = fits.getheader(path), fits.getheader(path, "SCI")
    readout = sr.read(path).schedule.to_header()
    assert len(readout) > 5
    for key in readout:
        assert sci[key] == primary[key] == readout[key], key
    assert sci["ORDER"] == primary["ORDER"] == "PHYSICAL"
    # what a tool that reads one extension sees (ccdproc's combine(..., hdu='SCI'))
    one = CCDData.read(path, hdu="SCI")
    assert one.meta["NROWS"] == readout["NROWS"] and one.meta["TFRAME"] == readout["TFRAME"]


@pytest.mark.filterwarnings("ignore:Mean of empty slice:RuntimeWarning")  # masked in both
@pytest.mark.filterwarnings("ignore:Degrees of freedom <= 0 for slice:RuntimeWarning")
def test_ccdproc_combines_with_the_unusable_pixels_masked(reduced):
    ccdproc = pytest.importorskip("ccdproc")
    path, data, _, flags = reduced
    combined = ccdproc.combine([path, path], format="spherex_reduce", method="average")
    unusable = (flags & ~np.uint32(dq.JUMP | dq.SATURATED | dq.REFERENCE)) != 0
    np.testing.assert_array_equal(combined.mask, unusable)
    np.testing.assert_allclose(combined.data[~unusable], data.astype(np.float32)[~unusable],
                               rtol=1e-7)


def test_ramps_are_refused_in_one_line(tmp_path):
    path = sr.write(example_raw_exposure(seed=1), tmp_path / "raw.fits")
    with pytest.raises(FormatError, match="ramps"):
        CCDData.read(path, format="spherex_reduce")
