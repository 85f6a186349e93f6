"""The REFERENCE bit: every reduced image flags its reference pixels, and the flag masks
nothing (the reference pixels are fitted and written like the others)."""

import numpy as np
import pytest
from astropy import units as u
from astropy.io import fits

from spherex_reduce import (
    DetectorGeometry,
    Exposure,
    Pipeline,
    ReadoutSchedule,
    combine_darks,
    dq,
    read,
    reduce_integrations,
    write,
)
from spherex_reduce.cli import main
from spherex_reduce.io.config import schedule_from_config
from spherex_reduce.io.examples import example_raw_exposure

WIDTHS = [{"top": 4, "bottom": 4, "left": 4, "right": 4}, {"top": 4, "left": 4}]


def border(shape, top=0, bottom=0, left=0, right=0):
    """Reference pixels of a physical-order image: rows ``top`` from row 0, ``bottom`` from
    the last; columns ``left`` from column 0, ``right`` from the last."""
    ny, nx = shape
    ref = np.zeros(shape, bool)
    ref[:top] = ref[ny - bottom:] = True
    ref[:, :left] = ref[:, nx - right:] = True
    return ref


def schedule(widths, nframes=5):
    return schedule_from_config({"nrows": 24, "ncols": 24, "nchannels": 2, "ref_border": widths},
                                {"skip": 4, "ref_reads": 8, "phantom_reads": 2,
                                 "nframes": nframes, "frame_overhead": 100})


PIPELINE = {"steps": ["unchop", "subtract_phantom", "correct_reference", "fit_ramp",
                      "sigma_clip"]}


@pytest.mark.parametrize("widths", WIDTHS)
def test_the_reduced_image_flags_exactly_its_reference_pixels(tmp_path, widths):
    raw = example_raw_exposure(schedule(widths))
    path = write(raw, tmp_path / "raw.fits")
    before = path.read_bytes()
    ref = border((24, 24), **widths)
    pipe = Pipeline(PIPELINE)
    for out in (pipe.run(str(path)), pipe.run(raw)):  # streamed, and in memory
        flagged = (out.dq & dq.REFERENCE) != 0
        np.testing.assert_array_equal(flagged, ref)
        # informational: the reference pixels are fitted, and not masked by it
        assert not (out.dq & ~np.uint32(dq.REFERENCE)).any()
        assert np.isfinite(out.data.data).all() and not np.asarray(out.data.mask).any()
    write(out, tmp_path / "out.fits")
    assert ((read(tmp_path / "out.fits").dq & dq.REFERENCE) != 0).sum() == ref.sum()
    assert path.read_bytes() == before


def test_a_pipeline_ending_in_readout_order_flags_each_read_of_a_reference_row():
    s = schedule(WIDTHS[1])
    out = Pipeline({"steps": ["fit_ramp"]}).run(example_raw_exposure(s))
    assert out.order == "readout"
    expected = border((24, 24), **WIDTHS[1])[s.rows]  # each read: its physical row
    np.testing.assert_array_equal((out.dq & dq.REFERENCE) != 0, expected)


def test_ramps_left_by_a_pipeline_are_not_flagged():
    out = Pipeline({"steps": ["unchop"]}).run(example_raw_exposure(schedule(WIDTHS[0])))
    assert out.is_ramp and (out.dq is None or not (out.dq & dq.REFERENCE).any())


def test_integrations_of_a_4d_file_flag_the_reference_pixels(tmp_path):
    widths = WIDTHS[1]
    raw = write(example_raw_exposure(schedule(widths)), tmp_path / "raw.fits")
    four = tmp_path / "four.fits"
    with fits.open(raw) as hdul:
        copies = fits.HDUList([h.copy() for h in hdul])
        copies["SCI"].data = np.stack([hdul["SCI"].data, hdul["SCI"].data * 0.5 + 1])
        copies["PHANTOM"].data = np.stack([hdul["PHANTOM"].data] * 2)
        copies.writeto(four, checksum=True)
    result = reduce_integrations(four, Pipeline(PIPELINE))
    ref = border((24, 24), **widths)
    np.testing.assert_array_equal((result.exposure.dq & dq.REFERENCE) != 0, ref)
    for flags in result.flags:
        np.testing.assert_array_equal((flags & dq.REFERENCE) != 0, ref)


@pytest.mark.parametrize("widths", WIDTHS)
def test_combine_writes_the_reference_pixels_flagged_and_keeps_them_out_of_the_others(
        tmp_path, widths):
    """Reference pixels at 1e6 (one input at -1e6): the light-sensitive pixels of the
    master are numpy's clipped per-pixel means, untouched by them; the reference pixels
    are combined too, and flagged."""
    s = ReadoutSchedule(DetectorGeometry(24, 24, 2, ref_border=widths), skip=4, ref_reads=4,
                        phantom_reads=0, nframes=4)
    ref = border((24, 24), **widths)
    rng = np.random.default_rng(7)
    stack = rng.normal(5.0, 1.0, (4, 24, 24))
    stack[:, ref] = 1e6
    stack[2, ref] = -1e6
    darks = [Exposure.from_arrays(v, s, order="physical", unit=u.electron / u.s)
             for v in stack]
    master = combine_darks(darks, sigma=0)
    np.testing.assert_allclose(master.data.data, stack.mean(axis=0), rtol=1e-12)
    np.testing.assert_array_equal(master.dq, np.where(ref, dq.REFERENCE, 0))
    assert not np.asarray(master.data.mask).any()
    # the command writes the same
    paths = [str(write(d, tmp_path / f"dark{i}.fits")) for i, d in enumerate(darks)]
    out = tmp_path / "master.fits"
    assert main(["-q", "combine", *paths, "-o", str(out), "--sigma", "0"]) == 0
    written = read(out)
    np.testing.assert_allclose(written.data.data, stack.mean(axis=0), rtol=1e-6)
    np.testing.assert_array_equal(written.dq, np.where(ref, dq.REFERENCE, 0))
