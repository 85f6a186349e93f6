"""Spatial power spectrum, band power, 2-D FFT and photon noise vs independent expectations."""

import numpy as np
import pytest
from astropy import units as u
from astropy.nddata import CCDData, NDData
from astropy.table import Table

from spherex_reduce.analysis import (
    band_power,
    fft_magnitude,
    k_from_theta,
    photon_noise_power,
    power_spectrum,
    slope_variance_factor,
    source_mask,
    theta_from_k,
)
from spherex_reduce.core.errors import SpherexReduceError


def white(shape, sigma, seed=0):
    return np.random.default_rng(seed).normal(0.0, sigma, shape)


def within(table, expected, nsig=4.0, min_modes=30):
    """Bins agree with ``expected`` within ``nsig`` errors.

    Bins with fewer than ``min_modes`` modes are chi-square with few degrees
    of freedom (and their error estimate is itself noisy): they only need to
    be within a factor 20.
    """
    p = np.asarray(table["power"])
    e = np.asarray(table["power_err"])
    many = np.asarray(table["nmodes"]) >= min_modes
    ok = np.abs(p - expected) < nsig * e
    loose = (p > expected / 20) & (p < expected * 20)
    return np.where(many, ok, loose)


def test_white_noise_gives_sigma_squared_at_every_k():
    sigma = 3.0
    t = power_spectrum(white((512, 512), sigma), bins=20)
    assert within(t, sigma**2).all()
    # mode-weighted mean over all bins: error ~ 1/sqrt(total modes)
    n = np.asarray(t["nmodes"], float)
    mean = np.sum(np.asarray(t["power"]) * n) / n.sum()
    assert mean == pytest.approx(sigma**2, rel=4 / np.sqrt(n.sum()))
    # the quoted error is P/sqrt(nmodes) for an isotropic bin
    rel = np.asarray(t["power_err"] / t["power"]) * np.sqrt(n)
    big = n > 200
    assert np.allclose(rel[big], 1.0, atol=0.15)


def test_white_noise_odd_and_rectangular_shape():
    t = power_spectrum(white((255, 300), 0.5, seed=4), bins=10)
    assert within(t, 0.25).all()


def test_error_estimate_matches_scatter_over_realisations():
    edges = [0.2, 0.4, 0.8]
    p = np.array([np.asarray(power_spectrum(white((64, 64), 1.0, seed=s), bins=edges)["power"])
                  for s in range(200)])
    quoted = np.asarray(power_spectrum(white((64, 64), 1.0, seed=999), bins=edges)["power_err"])
    assert np.allclose(p.std(axis=0), quoted, rtol=0.2)


def test_sine_peaks_at_2pi_over_period():
    period = 32.0
    _y, x = np.mgrid[0:256, 0:256]
    img = np.sin(2 * np.pi * x / period) + white((256, 256), 0.01, seed=2)
    t = power_spectrum(img, bins=40)
    kpeak = t["k"][np.argmax(t["power"])]
    assert t["k_lo"][np.argmax(t["power"])] <= 2 * np.pi / period <= t["k_hi"][
        np.argmax(t["power"])]
    assert kpeak == pytest.approx(2 * np.pi / period, rel=0.05)
    # the period in angle: θ = period × pixel scale
    theta = t["theta"][np.argmax(t["power"])]
    assert theta == pytest.approx(period * 6.2 / 60, rel=0.05)


def test_parseval():
    img = white((129, 101), 2.0, seed=5) + np.linspace(0, 1, 101)[None, :]
    t = power_spectrum(img, bins=[0, np.pi * np.sqrt(2) + 1e-9])
    # odd sizes: every cell but k = 0 pairs with its mirror, so cells = 2 nmodes
    total = np.sum(2 * np.asarray(t["nmodes"]) * np.asarray(t["power"])) / img.size
    assert total == pytest.approx(img.var(), rel=1e-10)


def test_masked_white_noise_hot_pixels_and_nan():
    sigma = 1.5
    img = white((256, 256), sigma, seed=7)
    rng = np.random.default_rng(8)
    mask = rng.random(img.shape) < 0.05
    img[mask] = 1e6  # hot pixels: must not leak
    img[3, 3] = np.nan  # unflagged NaN: masked too
    before = img.copy()
    t = power_spectrum(img, mask=mask, bins=12)
    assert np.array_equal(img, before, equal_nan=True)  # input untouched
    assert within(t, sigma**2).all()
    assert t.meta["masked_fraction"] == pytest.approx(mask.mean() + (not mask[3, 3]) / img.size)


def test_masked_array_and_ccddata_mask_are_used():
    img = white((128, 128), 1.0, seed=9)
    mask = np.zeros(img.shape, bool)
    mask[10:20, 30:40] = True
    img[mask] = 500.0
    ccd = CCDData(img, unit="electron/s", mask=mask)
    t1 = power_spectrum(ccd, bins=8)
    t2 = power_spectrum(np.ma.MaskedArray(img, mask), bins=8)
    t3 = power_spectrum(img, mask=mask, bins=8)
    assert np.allclose(t1["power"], t2["power"]) and np.allclose(t2["power"], t3["power"])
    assert t1["power"].unit == u.electron**2 / u.s**2 * u.pix**2
    assert within(t1, 1.0).all()


def test_input_types_and_units():
    img = white((64, 64), 2.0, seed=10)
    t_arr = power_spectrum(img, bins=5)
    t_q = power_spectrum(img * u.adu, bins=5)
    t_nd = power_spectrum(NDData(img, unit=u.electron), bins=5)
    assert np.allclose(t_arr["power"], t_q["power"]) and np.allclose(t_q["power"], t_nd["power"])
    assert t_q["power"].unit == u.adu**2 * u.pix**2
    assert t_arr["k"].unit == u.rad / u.pix and t_arr["theta"].unit == u.arcmin
    assert t_arr.colnames[:5] == ["k", "theta", "power", "power_err", "nmodes"]


def test_k_theta_conversion_matches_paper():
    k = k_from_theta([5, 20] * u.arcmin)
    assert np.allclose(k.value, [2 * np.pi * 6.2 / 300, 2 * np.pi * 6.2 / 1200])
    assert np.allclose(k.value, [0.13, 0.0325], atol=0.001)
    assert theta_from_k(k).to_value(u.arcmin) == pytest.approx([5, 20])
    t = power_spectrum(white((128, 128), 1.0), pixel_scale=3.1 * u.arcsec, bins=5)
    assert np.allclose(t["theta"], 2 * np.pi * 3.1 / 60 / np.asarray(t["k"]))


def test_band_power_white_and_table_agrees_with_image():
    sigma = 2.0
    img = white((1024, 1024), sigma, seed=11)
    p, err = band_power(img, return_error=True)
    assert abs(p.value - sigma**2) < 4 * err.value
    t = power_spectrum(img, bins=np.geomspace(0.03, 0.13, 5))
    pt, errt = band_power(t, return_error=True)
    assert pt.value == pytest.approx(p.value, rel=1e-9)
    assert errt.value == pytest.approx(err.value, rel=0.05)
    # the band's modes are exactly those with 0.03 <= |k| <= 0.13
    ky = 2 * np.pi * np.fft.fftfreq(1024)
    kk = np.hypot(ky[:, None], ky[None, :])
    assert int(power_spectrum(img, bins=[0.03, 0.13])["nmodes"][0]) == int(
        ((kk >= 0.03) & (kk <= 0.13)).sum() // 2)


def test_band_power_errors():
    with pytest.raises(SpherexReduceError, match="kmin < kmax"):
        band_power(white((32, 32), 1.0), kmin=0.2, kmax=0.1)
    with pytest.raises(SpherexReduceError, match="no spectrum bin"):
        band_power(power_spectrum(white((32, 32), 1.0), bins=[1.0, 2.0]))
    with pytest.raises(SpherexReduceError, match="lacks column"):
        band_power(Table({"k": [0.1]}))


def test_exclude_horizontal_removes_channel_offsets():
    rng = np.random.default_rng(12)
    offsets = np.repeat(rng.normal(0, 10, 16), 16)  # 16 channels of 16 columns
    img = offsets[None, :] + white((256, 256), 1.0, seed=13)
    full = band_power(img, kmin=0.05, kmax=1.0)
    cut, err = band_power(img, kmin=0.05, kmax=1.0, exclude_horizontal=True, return_error=True)
    assert full.value > 10  # channel offsets dominate the full plane
    assert abs(cut.value - 1.0) < 4 * err.value


def test_fft_magnitude_sine_and_white_level():
    y, _x = np.mgrid[0:128, 0:128]
    f = fft_magnitude(np.sin(2 * np.pi * y / 8.0), size=65)
    iy, ix = np.unravel_index(np.argmax(f.magnitude.value), f.magnitude.shape)
    assert abs(f.ky[iy].value) == pytest.approx(2 * np.pi / 8) and f.kx[ix].value == 0
    g = fft_magnitude(white((256, 256), 2.0, seed=3), size=301)
    assert g.magnitude.shape == (256, 256)
    assert np.mean(g.magnitude.value**2) == pytest.approx(4.0, rel=0.02)


def test_source_mask_finds_sources_and_hot_pixels():
    img = white((256, 256), 1.0, seed=15)
    y, x = np.mgrid[0:256, 0:256]
    img += 200 * np.exp(-((x - 100) ** 2 + (y - 60) ** 2) / (2 * 3.0**2))  # a source
    hot = [(20, 30), (200, 220), (128, 5)]
    for r, c in hot:
        img[r, c] = 1000.0
    img[150, 150] = -1000.0  # a negative hot pixel of a pair difference
    m = source_mask(img)
    assert m[60, 100] and all(m[r, c] for r, c in hot) and m[150, 150]
    assert m.mean() < 0.01
    t = power_spectrum(img, mask_sources=True, bins=10)
    assert within(t, 1.0).all()
    assert not within(power_spectrum(img, bins=10), 1.0).all()


def test_bad_inputs():
    with pytest.raises(SpherexReduceError, match="2-D"):
        power_spectrum(np.zeros((3, 8, 8)))
    with pytest.raises(SpherexReduceError, match="mask shape"):
        power_spectrum(np.zeros((8, 8)), mask=np.zeros((4, 4), bool))
    with pytest.raises(SpherexReduceError, match="unmasked"):
        power_spectrum(np.zeros((8, 8)), mask=np.ones((8, 8), bool))
    with pytest.raises(SpherexReduceError, match="bin"):
        power_spectrum(np.zeros((8, 8)), bins=[0.5, 0.1])


def test_band_power_of_a_table_is_the_band_power_of_the_image():
    """A table only gives the band power if its bins tile the band (else it is refused)."""
    from spherex_reduce.analysis import band_power, power_spectrum
    from spherex_reduce.core.errors import SpherexReduceError

    img = np.random.default_rng(5).normal(0, 1, (128, 128)) * np.linspace(1, 3, 128)
    exact = band_power(img)
    tiled = power_spectrum(img, bins=[0.01, 0.03, 0.07, 0.13, 1.0])
    assert band_power(tiled).value == pytest.approx(exact.value, rel=1e-9)
    with pytest.raises(SpherexReduceError, match="tile"):
        band_power(power_spectrum(img, bins=30))  # bins straddle the band edges


def poisson_ramp_slopes(rate, nframes, tframe, shape, seed):
    """Least-squares slopes of Poisson ramps, fitted with numpy.polyfit (independent of us)."""
    rng = np.random.default_rng(seed)
    counts = rng.poisson(rate * tframe, (nframes - 1, *shape)).astype(float)
    reads = np.concatenate([np.zeros((1, *shape)), np.cumsum(counts, axis=0)])
    t = np.arange(nframes) * tframe
    coef = np.polyfit(t, reads.reshape(nframes, -1), 1)
    return coef[0].reshape(shape)


def test_photon_noise_matches_poisson_ramps():
    rate, nframes, tframe = 4.0, 10, 1.5
    slopes = poisson_ramp_slopes(rate, nframes, tframe, (256, 256), seed=14)
    expected = photon_noise_power(rate * u.electron / u.s, nframes * tframe * u.s,
                                  nframes=nframes)
    assert expected.unit == (u.electron / u.s) ** 2 * u.pix**2
    assert slopes.var() == pytest.approx(expected.value, rel=0.03)
    # its spatial spectrum is flat at that level
    t = power_spectrum(slopes * u.electron / u.s, bins=10)
    assert within(t, expected.value).all()


def test_photon_noise_simple_and_from_schedule():
    from spherex_reduce import ReadoutSchedule

    p = photon_noise_power(1 * u.electron / u.s, 112 * u.s)
    assert p.value == pytest.approx(1 / 112)
    s = ReadoutSchedule()
    ps = photon_noise_power(1.0, schedule=s)
    assert ps.value == pytest.approx(slope_variance_factor(74) / 1.51)
    assert slope_variance_factor(2) == 1.0
    with pytest.raises(SpherexReduceError):
        photon_noise_power(1.0)


def test_every_column_is_described_and_read_back_with_its_unit(tmp_path):
    """An ECSV spectrum says what each column is and in which unit (astropy reads both)."""
    rng = np.random.default_rng(5)
    image = rng.normal(0, 2, (64, 64)) * u.electron / u.s
    power_spectrum(image, bins=6).write(tmp_path / "p.ecsv")
    t = Table.read(tmp_path / "p.ecsv")
    assert all(t[c].description for c in t.colnames)
    assert "standard error" in t["power_err"].description
    assert t["power_err"].unit == u.electron**2 * u.pix**2 / u.s**2
    assert t["theta"].unit == u.arcmin and t["k"].unit == u.rad / u.pix


def test_power_spectra_are_power_spectrum_in_each_binning_and_the_measure_s_band_is_the_image_s():
    """One FFT for several binnings: each table equals `power_spectrum`'s in that binning
    to the last digit, and a case's measure gives the image's `band_power` to the last
    digit (its band from the band's own one-bin table)."""
    from spherex_reduce.analysis.case import SpectrumMeasure
    from spherex_reduce.analysis.spectrum import EmptyBandError, power_spectra

    img = np.random.default_rng(4).normal(0, 2, (96, 80))
    img[3, 5] = np.nan
    t8, band = power_spectra(img, [8, [0.1, 0.5]], exclude_horizontal=True)
    for got, bins in ((t8, 8), (band, [0.1, 0.5])):
        want = power_spectrum(img, bins=bins, exclude_horizontal=True)
        for col in want.colnames:
            assert np.array_equal(np.asarray(got[col]), np.asarray(want[col]))
    m = SpectrumMeasure(kmin=0.1, kmax=0.5, bins=8)(img)
    p, err = band_power(img, 0.1, 0.5, return_error=True)
    assert m["band_power"] == p and m["band_power_err"] == err
    with pytest.raises(EmptyBandError, match="no Fourier mode of the 20 x 20 image"):
        SpectrumMeasure(bins=4)(img[:20, :20])
