"""Calibration maps (read noise, dark current, gain) meet the channel layouts and units.

A map is given as the files hold the pixels: the stored image, ``(nrows, ncols)``.
Each test writes a small ramp in the stored orientation, fits or searches it with
maps, and compares with numpy computed here on the stored image: the slope by
``np.polyfit``, its variance ``rn**2 sum(w**2) + (max(rate, 0) + dark) / gain *
w' min(t_i, t_j) w`` with the least-squares weights ``w``.
"""

import warnings

import numpy as np
import pytest
from astropy.io import fits

import spherex_reduce as sr
from spherex_reduce import ConfigError, DetectorGeometry, Exposure, ReadoutSchedule, dq
from spherex_reduce.reduce.steps.fit_ramp.expected_rates import expected_rates

N, NF, DT = 16, 6, 2.0
T = DT * np.arange(NF)
READOUT = {"skip": 1, "ref_reads": 0, "ref_mode": "none", "phantom_reads": 0, "nframes": NF,
           "frame_time": DT}
LAYOUTS = {
    "rows": {"nchannels": 2, "channels": "rows"},
    **{f"quadrants-{c}-{f}": {"nchannels": 4, "channels": "quadrants", "first_corner": c,
                              "fast_axis": f}
       for c in ("outer", "inner") for f in ("rows", "columns")},
}


def _config(layout, steps, **sections):
    return {"geometry": {"nrows": N, "ncols": N, "pixel_rate": 1e5, "ref_border": 0,
                         **LAYOUTS.get(layout, {"nchannels": 2})},
            "readout": READOUT, "steps": steps, **sections}


def _lab_ramp(path, seed=1, noise=1.0):
    """Ramps ``(NF, N, N)`` of the stored image, slopes 1-5 per s, written to ``path``."""
    rng = np.random.default_rng(seed)
    data = 1000 + rng.uniform(1, 5, (N, N)) * T[:, None, None] + rng.normal(0, 1, (NF, N, N)) \
        * noise
    fits.HDUList([fits.PrimaryHDU(), fits.ImageHDU(data, name="SCI")]).writeto(path)
    return data


def _write_map(path, values, bunit=None):
    hdu = fits.PrimaryHDU(values)
    if bunit is not None:
        hdu.header["BUNIT"] = bunit
    hdu.writeto(path)
    return str(path)


def _numpy_fit(data, rn, dark=0.0, gain=1.0):
    """Slopes and their standard deviations on the stored image, by numpy."""
    slope = np.polyfit(T, data.reshape(NF, -1), 1)[0].reshape(N, N)
    tc = T - T.mean()
    w = tc / (tc @ tc)
    pf = w @ np.minimum.outer(T, T) @ w
    rnoise = rn ** 2 * (w @ w) + dark / gain * pf
    # the shot noise of fit_ramp's expected rates (tested against the truth in
    # tests/reduce/steps/fit_ramp/test_fit_ramp.py); here on the pixels' maps of read noise
    rate = expected_rates(slope, np.broadcast_to(rnoise, slope.shape),
                          np.broadcast_to(pf / gain, slope.shape))
    rate = np.maximum(slope, 0) if rate is None else rate
    return slope, np.sqrt(rnoise + rate / gain * pf)


def _stored(exposure):
    lay = exposure.geometry.layout
    return lay.to_stored(exposure.data.data), lay.to_stored(exposure.data.uncertainty.array)


@pytest.mark.parametrize("layout", list(LAYOUTS))
def test_maps_of_the_stored_image_give_numpy_errors_in_every_layout(tmp_path, layout):
    """With channels: rows the maps were applied transposed (ERR wrong at most pixels); a
    quadrant map of the stored shape was refused."""
    data = _lab_ramp(tmp_path / "raw.fits")
    rng = np.random.default_rng(2)
    rn, dark = rng.uniform(2, 8, (N, N)), rng.uniform(0, 3, (N, N))
    steps = [{"fit_ramp": {"read_noise": _write_map(tmp_path / "rn.fits", rn),
                           "dark_current": _write_map(tmp_path / "dark.fits", dark)}}]
    slope, err = _stored(sr.Pipeline(_config(layout, steps)).run(tmp_path / "raw.fits"))
    want_slope, want_err = _numpy_fit(data, rn, dark)
    np.testing.assert_allclose(slope, want_slope, rtol=0, atol=1e-9)
    np.testing.assert_allclose(err, want_err, rtol=1e-6)  # float32 parts
    # in Python the same maps as arrays of the stored image, on the exposure read
    e = sr.read(tmp_path / "raw.fits", **_config(layout, [])["geometry"], **READOUT)
    _, err = _stored(sr.fit_ramp(e, read_noise=rn, dark_current=dark))
    np.testing.assert_allclose(err, want_err, rtol=1e-6)  # float32 parts


@pytest.mark.parametrize("layout", ["rows", "quadrants-outer-rows", "quadrants-inner-columns"])
def test_detect_jumps_reads_its_map_in_the_stored_orientation(tmp_path, layout):
    """Pixels of read noise 1 carry a 40 e jump, the others (read noise 50) none: with the
    map of the stored image exactly the jumps are flagged (transposed, the map called the
    noisy pixels quiet and the jumps noise)."""
    rng = np.random.default_rng(3)
    r, c = np.indices((N, N))
    quiet = (c > r) & ((r + c) % 2 == 0)  # its transpose is another set of pixels
    rn = np.where(quiet, 1.0, 50.0)
    data = 1000 + rng.normal(0, 1, (NF, N, N)) * rn
    data[3:] += 40.0 * quiet
    fits.HDUList([fits.PrimaryHDU(), fits.ImageHDU(data, name="SCI")]).writeto(
        tmp_path / "raw.fits")
    # a fifth of the pixels step at read 3: each pixel's search, not the array's event
    steps = [{"detect_jumps": {"read_noise": _write_map(tmp_path / "rn.fits", rn),
                               "threshold": 6.0, "read_events": False}}]
    out = sr.Pipeline(_config(layout, steps)).run(tmp_path / "raw.fits")
    flags = out.geometry.layout.to_stored(out.dq & dq.JUMP)
    assert sorted(map(tuple, np.argwhere(flags).tolist())) == \
        sorted((3, int(i), int(j)) for i, j in np.argwhere(quiet))


def test_a_map_of_the_readout_frames_shape_is_refused_naming_the_stored_shape(tmp_path):
    _lab_ramp(tmp_path / "raw.fits")
    frame_shaped = _write_map(tmp_path / "rn.fits", np.ones((N // 2, 2 * N)))
    config = _config("quadrants-outer-rows", [{"fit_ramp": {"read_noise": frame_shaped}}])
    with pytest.raises(ConfigError, match=r"fit_ramp\.read_noise: .*\(8, 32\).*\(16, 16\)"):
        sr.Pipeline(config).run(tmp_path / "raw.fits")


@pytest.mark.parametrize(("bunit", "words"), [
    ("m", r"in m, not in a unit of the data \(electron\)"),
    ("adu", r"in adu, the data in electron, and no gain"),
    ("furlongs", r"BUNIT 'furlongs', not a unit")])
@pytest.mark.parametrize("step", ["fit_ramp", "detect_jumps"])
def test_a_map_in_a_unit_that_is_not_the_datas_is_refused(tmp_path, bunit, words, step):
    """A map with BUNIT 'm' or 'adu' was used as electrons."""
    _lab_ramp(tmp_path / "raw.fits")
    rn = _write_map(tmp_path / "rn.fits", np.full((N, N), 3.0), bunit)
    config = _config("columns", [{step: {"read_noise": rn}}])
    with pytest.raises(ConfigError, match=rf"{step}\.read_noise: .*{words}") as err:
        sr.Pipeline(config).run(tmp_path / "raw.fits")
    assert "\n" not in str(err.value)


def test_maps_in_adu_and_electrons_are_converted_with_the_gain(tmp_path):
    data = _lab_ramp(tmp_path / "raw.fits", noise=3.0)
    rn = np.random.default_rng(4).uniform(2, 4, (N, N))
    # the data in ADU made electrons by input.gain (GAIN = 2 in the header): a map in ADU is
    # twice as many electrons
    steps = [{"fit_ramp": {"read_noise": _write_map(tmp_path / "adu.fits", rn, "ADU")}}]
    config = _config("rows", steps, input={"unit": "adu", "gain": 2.0})
    _, err = _stored(sr.Pipeline(config).run(tmp_path / "raw.fits"))
    np.testing.assert_allclose(err, _numpy_fit(2.0 * data, 2.0 * rn)[1], rtol=1e-6)
    # the data left in ADU, fit_ramp's gain 2 e-/ADU: a map in electrons is half as many ADU,
    # and a dark current in electron / s too
    dark = np.full((N, N), 0.5)
    steps = [{"fit_ramp": {"read_noise": _write_map(tmp_path / "e.fits", rn, "electron"),
                           "dark_current": _write_map(tmp_path / "d.fits", dark, "electron/s"),
                           "gain": 2.0}}]
    out = sr.Pipeline(_config("rows", steps, input={"unit": "adu"})).run(tmp_path / "raw.fits")
    _, err = _stored(out)
    np.testing.assert_allclose(err, _numpy_fit(data, rn / 2.0, dark / 2.0, gain=2.0)[1],
                               rtol=1e-6)
    # a map in the data's unit, or in none, is taken as it is
    for bunit in ("adu", None):
        steps = [{"fit_ramp": {"read_noise": _write_map(tmp_path / f"as-{bunit}.fits", rn, bunit)}}]
        out = sr.Pipeline(_config("rows", steps, input={"unit": "adu"})).run(
            tmp_path / "raw.fits")
        np.testing.assert_allclose(_stored(out)[1], _numpy_fit(data, rn)[1], rtol=1e-6)


def test_a_quantity_is_converted_like_a_file(tmp_path):
    s = ReadoutSchedule(DetectorGeometry(N, N, 2, ref_border=0), **READOUT)
    data = 1000 + 2.0 * T[:, None, None] + np.random.default_rng(5).normal(0, 3, (NF, N, N))
    e = Exposure.from_arrays(data, s)
    from astropy import units as u

    got = sr.fit_ramp(e, read_noise=np.full((N, N), 3.0) * u.electron)
    np.testing.assert_allclose(got.data.uncertainty.array, _numpy_fit(data, 3.0)[1],
                               rtol=1e-6)
    with pytest.raises(ConfigError, match=r"read_noise: .*in m"):
        sr.fit_ramp(e, read_noise=3.0 * u.m)


def test_a_truncated_map_gives_one_error_and_no_warning(tmp_path):
    """astropy's 'File may have been truncated' warning was printed before the error."""
    _lab_ramp(tmp_path / "raw.fits")
    path = _write_map(tmp_path / "rn.fits", np.full((N, N), 3.0))
    with open(path, "r+b") as fh:
        fh.truncate(2880 + 500)  # the header and part of the data
    config = _config("columns", [{"fit_ramp": {"read_noise": path}}])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(ConfigError, match=r"fit_ramp\.read_noise: .*truncated") as err:
            sr.Pipeline(config).run(tmp_path / "raw.fits")
    assert "\n" not in str(err.value)
