"""JWST level-1 files, written by stdatamodels as the JWST pipeline writes them, reduce with
a config of steps alone: the layout, the groups, the timing and the flags come from the file.

Slopes are checked against a least-squares fit written here (group times: the mean of the
times of the frames averaged into each group), and the detector orientation against the
jwst refpix step's own flips per detector (not FASTAXIS/SLOWAXIS, which the reader uses).
"""

import logging

import numpy as np
import pytest
from astropy.io import fits
from stdatamodels.jwst.datamodels import Level1bModel, RampModel, dqflags

import spherex_reduce as sr
from spherex_reduce.core import dq
from spherex_reduce.core.errors import FormatError
from spherex_reduce.io.readers.jwst_level1 import JWST_DQ
from spherex_reduce.reduce.integrations import reduce_input

FIT = {"steps": ["fit_ramp"]}
#: detector: (FASTAXIS, SLOWAXIS, DMS -> detector orientation as the jwst refpix step flips)
DETECTORS = {
    "NRCA1": (-1, 2, lambda a: a[..., :, ::-1]),
    "NRCA2": (1, -2, lambda a: a[..., ::-1, :]),
    "NRS1": (2, 1, lambda a: np.swapaxes(a, -1, -2)),
    "NRS2": (-2, -1, lambda a: np.swapaxes(a, -1, -2)[..., ::-1, ::-1]),
    "NIS": (-2, -1, lambda a: np.swapaxes(a[..., ::-1, ::-1], -1, -2)),
    "GUIDER1": (-1, -2, lambda a: a[..., ::-1, ::-1]),
    "GUIDER2": (-1, 2, lambda a: a[..., :, ::-1]),
}
INSTRUMENT = {"NRC": "NIRCAM", "NRS": "NIRSPEC", "NIS": "NIRISS", "GUI": "FGS"}


def _group_times(ngroups, nframes, gap, tframe):
    """Mean time of the frames averaged into each group (frame ``a`` read at ``a tframe``)."""
    frames = np.arange(ngroups)[:, None] * (nframes + gap) + np.arange(nframes)[None, :]
    return tframe * frames.mean(axis=1)


def _lstsq_slopes(ramps, t):
    """Least-squares slope of every pixel of ``ramps`` (groups, rows, columns) against ``t``."""
    design = np.column_stack([np.ones_like(t), t])
    coef, *_ = np.linalg.lstsq(design, ramps.reshape(len(t), -1).astype(float), rcond=None)
    return coef[1].reshape(ramps.shape[1:])


def _uncal(path, detector="NRCA1", *, nints=1, ngroups=3, shape=(64, 64), start=(1, 1),
           nframes=1, gap=0, outputs=1, model=RampModel, rates=None, pixeldq=None,
           groupdq=None, readpatt=None):
    """A JWST file by stdatamodels: ``shape`` (rows, columns) in the DMS orientation at
    ``start`` (SUBSTRT1, SUBSTRT2), ramps ``1000 + rate t`` at the groups' mean times.
    Returns the ramps (DMS) and the group times."""
    fast, slow, _ = DETECTORS[detector]
    ny, nx = shape
    along, rows = (nx, ny) if abs(fast) == 1 else (ny, nx)  # detector columns, rows
    tframe = (along / outputs + 12) * (rows + 1) * 1e-5  # JWST's frame time
    t = _group_times(ngroups, nframes, gap, tframe)
    if rates is None:
        y, x = np.indices(shape)
        rates = 50.0 + 0.5 * x + 0.25 * y + 40.0 * np.arange(nints)[:, None, None]
    ramps = 1000.0 + rates[:, None] * t[None, :, None, None]
    data = np.round(ramps).astype(np.uint16) if model is Level1bModel else ramps.astype("f4")
    m = model(data=data)
    m.meta.telescope = "JWST"
    m.meta.instrument.name = INSTRUMENT[detector[:3]]
    m.meta.instrument.detector = detector
    e = m.meta.exposure
    e.readpatt = readpatt or ("RAPID" if nframes == 1 else "MEDIUM8")
    e.nints, e.ngroups, e.nframes, e.groupgap = nints, ngroups, nframes, gap
    e.frame_time, e.group_time, e.noutputs = tframe, tframe * (nframes + gap), outputs
    s = m.meta.subarray
    if shape == (2048, 2048):
        s.name = "FULL"
    (s.xstart, s.ystart), (s.ysize, s.xsize) = start, shape
    s.fastaxis, s.slowaxis = fast, slow
    if pixeldq is not None:
        m.pixeldq = pixeldq
    if groupdq is not None:
        m.groupdq = groupdq
    m.save(path)
    return data, t


def test_the_bit_table_is_jwsts():
    jwst = dqflags.pixel
    assert JWST_DQ == {jwst["DO_NOT_USE"]: dq.DO_NOT_USE, jwst["SATURATED"]: dq.SATURATED,
                       jwst["JUMP_DET"]: dq.JUMP, jwst["REFERENCE_PIXEL"]: dq.REFERENCE}


@pytest.mark.slow
def test_full_frame_nircam_uncal_reduces_with_steps_alone(tmp_path):
    """2048 x 2048 in 4 outputs, uint16 as the archive's uncal files; NRCA1 is flipped
    left to right; the reference border is 4 on every side."""
    path = tmp_path / "jw_nrca1_uncal.fits"
    data, t = _uncal(path, "NRCA1", shape=(2048, 2048), outputs=4, model=Level1bModel)
    e = sr.read(path, integration=0)
    s = e.schedule
    assert (s.geometry.nchannels, s.geometry.scan, s.geometry.border.sides()) == (
        4, (1, -1, 1, -1), dict.fromkeys(("top", "bottom", "left", "right"), 4))
    assert s.frame_time.to_value("s") == pytest.approx((512 + 12) * 2049 * 1e-5, rel=1e-12)
    out, images = reduce_input(path, sr.Pipeline(FIT))
    expected = _lstsq_slopes(DETECTORS["NRCA1"][2](data[0]), t)
    np.testing.assert_allclose(out.data.data, expected, rtol=1e-4, atol=1e-3)
    assert out.unit == "adu / s" and images["INTSLOPE"].shape == (1, 2048, 2048)


@pytest.mark.parametrize("detector", sorted(DETECTORS))
def test_subarrays_several_integrations_in_detector_orientation(tmp_path, detector):
    """A 32 x 64 subarray near the DMS origin in 2 integrations: the slopes of each, in
    the detector orientation, and the reference pixels are the full array's inside it."""
    path = tmp_path / f"{detector}_uncal.fits"
    data, t = _uncal(path, detector, nints=2, shape=(32, 64), start=(3, 1))
    flip = DETECTORS[detector][2]
    _, images = reduce_input(path, sr.Pipeline(FIT))
    for k in range(2):
        np.testing.assert_allclose(images["INTSLOPE"][k].value,
                                   _lstsq_slopes(flip(data[k]), t), rtol=1e-5)
    y, x = np.indices((32, 64))
    x, y = x + 2, y  # the full array's DMS pixel (SUBSTRT1 = 3)
    reference = (x < 4) | (y < 4) | (x >= 2044) | (y >= 2044)
    e = sr.read(path, integration=1)
    np.testing.assert_array_equal(e.geometry.reference_pixel_mask(), flip(reference))
    assert e.header["SXRINT"] == 1 and e.header["JWFASTAX"] == DETECTORS[detector][0]


def test_medium8_groups_average_eight_frames_with_two_dropped(tmp_path):
    """NIRCam MEDIUM8: NFRAMES = 8 frames averaged per group, GROUPGAP = 2 dropped."""
    path = tmp_path / "medium8.fits"
    data, t = _uncal(path, "NRCA2", ngroups=4, nframes=8, gap=2)
    e = sr.read(path, integration=0)
    s = e.schedule
    assert (s.nframes, s.frames_per_group, s.group_gap) == (4, 8, 2)
    np.testing.assert_allclose(s.frame_starts.to_value("s") - s.frame_starts[0].value,
                               t - t[0], rtol=1e-12)
    out, _ = reduce_input(path, sr.Pipeline(FIT))
    np.testing.assert_allclose(out.data.data, _lstsq_slopes(DETECTORS["NRCA2"][2](data[0]), t),
                               rtol=1e-5)


def test_jwst_flags_keep_their_meaning(tmp_path):
    """PIXELDQ and GROUPDQ in JWST's bits: DO_NOT_USE masks, SATURATED, JUMP_DET and
    REFERENCE_PIXEL become ours, HOT (informational in JWST) masks nothing."""
    j = dqflags.pixel
    pixeldq = np.zeros((32, 64), np.uint32)
    pixeldq[10, 20] = j["DO_NOT_USE"] | j["DEAD"]
    pixeldq[11, 21] = j["HOT"]
    pixeldq[0, 30] = j["REFERENCE_PIXEL"]
    groupdq = np.zeros((1, 5, 32, 64), np.uint8)
    groupdq[0, 2, 12, 22] = j["JUMP_DET"]
    groupdq[0, 3:, 13, 23] = j["SATURATED"]
    path = tmp_path / "flags.fits"
    _uncal(path, "NRS1", ngroups=5, shape=(32, 64), pixeldq=pixeldq, groupdq=groupdq)
    e = sr.read(path, integration=0)
    flags = np.swapaxes(e.dq, -1, -2)  # back to the DMS orientation (NRS1: the transpose)
    assert (flags[:, 10, 20] == dq.DO_NOT_USE).all()
    assert (flags[:, 11, 21] == 0).all()
    assert (flags[:, 0, 30] == dq.REFERENCE).all()
    assert flags[:, 12, 22].tolist() == [0, 0, dq.JUMP, 0, 0]
    assert flags[:, 13, 23].tolist() == [0, 0, 0, dq.SATURATED, dq.SATURATED]
    masked = sr.read(path, integration=0, dq_bits=j["HOT"])  # named bits mask too
    assert (np.swapaxes(masked.dq, -1, -2)[:, 11, 21] == dq.DO_NOT_USE).all()


def test_config_fills_what_the_file_lacks_and_overrides_once_per_file(tmp_path, caplog):
    path = tmp_path / "two.fits"
    data, t = _uncal(path, "NRCA1", nints=2)
    tframe = fits.getheader(path)["TFRAME"]
    with pytest.raises(FormatError, match=r"TFRAME gives frame_time = .* readout\.frame_time "
                                          r"is 1\.0 in the config.*override"):
        reduce_input(path, sr.Pipeline({"readout": {"frame_time": 1.0}, **FIT}))
    pipe = sr.Pipeline({"input": {"header": "override"}, "readout": {"frame_time": 1.0}, **FIT})
    with caplog.at_level(logging.WARNING):
        _, images = reduce_input(path, pipe)
    notes = [r for r in caplog.records if "frame_time" in r.getMessage()]
    assert len(notes) == 1  # one warning per keyword per file, not one per integration
    flip = DETECTORS["NRCA1"][2]
    for k in range(2):  # the config's frame time: groups at t / tframe seconds
        np.testing.assert_allclose(images["INTSLOPE"][k].value,
                                   _lstsq_slopes(flip(data[k]), t / tframe), rtol=1e-5)
    with fits.open(path, mode="update") as hdul:
        del hdul[0].header["TFRAME"]
    with pytest.raises(FormatError, match=r"TFRAME missing .* readout\.frame_time"):
        sr.read(path, integration=0)
    e = sr.read(path, integration=0, frame_time=tframe)
    assert e.schedule.frame_time.to_value("s") == pytest.approx(tframe)


@pytest.mark.parametrize(("edit", "message"), [
    ({"READPATT": "NRSIRS2"}, "IRS2"),
    ({"INSTRUME": "MIRI"}, "H2RG instruments"),
    ({"FASTAXIS": 3}, "FASTAXIS = 3"),
    ({"SUBSIZE1": 32}, "SUBSIZE"),
    ({"NGROUPS": 7}, "NGROUPS = 7"),
    ({"TGROUP": 9.0}, "TGROUP"),
])
def test_a_jwst_file_the_reader_cannot_place_is_refused_in_one_line(tmp_path, edit, message):
    path = tmp_path / "bad.fits"
    _uncal(path, "NRCA1")
    with fits.open(path, mode="update") as hdul:
        hdul[0].header.update(edit)
    with pytest.raises(FormatError, match=message):
        sr.read(path, integration=0)


def test_layout_keys_in_the_config_are_refused(tmp_path):
    path = tmp_path / "a.fits"
    _uncal(path, "NRCA1")
    with pytest.raises(FormatError, match=r"geometry\.preset does not apply to a JWST file"):
        sr.read(path, integration=0, preset="SIDECAR")


def test_a_dark_reference_file_asks_for_its_frame_time(tmp_path):
    """A CRDS dark reference file (stdatamodels' DarkModel: 3-D float SCI, 2-D DQ, no
    TFRAME) reads once the config gives readout.frame_time; its DQ keeps JWST's bits."""
    from stdatamodels.jwst.datamodels import DarkModel
    t = 10.73677 * np.arange(5)
    y, x = np.indices((32, 64))
    data = (0.01 * (1 + x + y))[None] * t[:, None, None]
    flags = np.zeros((32, 64), np.uint32)
    flags[20, 30] = dqflags.pixel["DO_NOT_USE"] | dqflags.pixel["HOT"]
    m = DarkModel(data=data.astype("f4"), dq=flags, err=np.ones_like(data, "f4"))
    m.meta.telescope, m.meta.reftype = "JWST", "DARK"
    m.meta.instrument.name, m.meta.instrument.detector = "NIRSPEC", "NRS1"
    e = m.meta.exposure
    e.readpatt, e.nframes, e.ngroups, e.groupgap = "NRSRAPID", 1, 5, 0
    s = m.meta.subarray
    s.xstart, s.ystart, s.xsize, s.ysize, s.fastaxis, s.slowaxis = 1, 1, 64, 32, 2, 1
    path = tmp_path / "jwst_nirspec_dark.fits"
    m.save(path)
    with pytest.raises(FormatError, match=r"TFRAME missing .* readout\.frame_time"):
        sr.read(path)
    pipe = sr.Pipeline({"readout": {"frame_time": 10.73677}, **FIT})
    out = pipe.run(path)
    expected = np.swapaxes(_lstsq_slopes(data, t), 0, 1)  # NRS1: the transpose
    expected[30, 20] = np.nan
    np.testing.assert_allclose(out.data.data, expected, rtol=1e-5)
    assert out.dq[30, 20] & dq.DO_NOT_USE
