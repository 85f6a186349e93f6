"""Temporal PSD, the α + β/f + γ/f^1.3 fit and raw-file streams, on streams made here.

Streams are drawn (``tests/_noise_streams.py``) by Fourier synthesis on a grid
8× (4× for raw files) longer than the stream, of which the first part is kept:
an exact draw of the stationary Gaussian process whose spectrum is ``p`` on that
fine grid, with no periodic wrap-around of the kept part.  None of this uses the
package's simulator.
"""

import numpy as np
import pytest
from _noise_streams import FS, PHANTOM, PIXELS, raw_exposure, synth
from _paper import TABLE2

from spherex_reduce.analysis import (
    aliased_basis,
    fit_noise_model,
    fit_raw_noise,
    model_basis,
    phantom_timestream,
    reference_timestream,
    temporal_psd,
)
from spherex_reduce.core.errors import SpherexReduceError


def pulls(result, truth, names=("alpha", "beta", "gamma")):
    return np.array([(result.values[k] - v) / result.errors[k]
                     for k, v in zip(names, truth, strict=False)])


def test_welch_white_normalisation_one_sided():
    sigma, fs = 2.0, 1000.0
    x = np.random.default_rng(0).normal(0, sigma, (4, 2**15))
    t = temporal_psd(x, fs, nperseg=1024)
    assert np.mean(t["psd"]) == pytest.approx(2 * sigma**2 / fs, rel=0.01)
    assert t["frequency"].unit == "Hz" and t["psd"].unit == "1 / Hz"
    assert t["frequency"][0] > 0 and t["frequency"][-1] < fs / 2
    assert t.meta["nstreams"] == 4 and t.meta["nsegments"] == 63


@pytest.mark.parametrize("name", sorted(TABLE2))
def test_fit_recovers_table2_component(name):
    truth = TABLE2[name]
    rng = np.random.default_rng(sorted(TABLE2).index(name))
    x = synth(2**16, truth, rng, nstreams=4)
    r = fit_noise_model(temporal_psd(x, FS, nperseg=4096))
    assert np.all(np.abs(pulls(r, truth)) < 4), (r.values, r.errors)
    assert 0.5 < r.chi2 / r.dof < 1.6
    for k, v in zip(("alpha", "beta", "gamma"), truth, strict=True):
        if v > 5 * r.errors[k]:  # a term well above its error is detected, with the right sign
            assert r.values[k] > 2 * r.errors[k]


def test_fit_uncertainties_are_calibrated():
    """Over independent streams the pulls have mean ~0 and spread ~1."""
    truth = TABLE2["roic"]
    p = np.array([pulls(fit_noise_model(temporal_psd(
        synth(2**14, truth, np.random.default_rng(100 + s), nstreams=2), FS, nperseg=2048)),
        truth) for s in range(16)])
    assert np.all(np.abs(p.mean(axis=0)) < 0.9)
    assert np.all((p.std(axis=0) > 0.55) & (p.std(axis=0) < 1.6))


def test_fit_subset_and_model():
    truth = (1e-3, 5e-2, 0.0)
    x = synth(2**15, truth, np.random.default_rng(7), nstreams=2)
    r = fit_noise_model(temporal_psd(x, FS, nperseg=4096), fit=("alpha", "beta"))
    assert r.values["gamma"] == 0 and r.errors["gamma"] == 0
    assert np.all(np.abs(pulls(r, truth, ("alpha", "beta"))) < 4)
    assert r.model([10.0])[0] == pytest.approx(r.values["alpha"] + r.values["beta"] / 10)
    row = r.to_row()
    assert set(row) >= {"alpha", "alpha_err", "beta", "chi2", "dof", "fmin", "fmax"}
    with pytest.raises(SpherexReduceError, match="fit must name"):
        fit_noise_model(temporal_psd(x, FS, nperseg=256), fit=("delta",))


def test_fit_exponent():
    """A steeper excess term (exponent 1.8) is found, within the Δχ² = 1 error."""
    truth = (1e-3, 0.0, 20.0)  # the excess term crosses the white level near 110 Hz
    x = synth(2**16, truth, np.random.default_rng(31), nstreams=4, exponent=1.8)
    r = fit_noise_model(temporal_psd(x, FS, nperseg=4096), exponent=None,
                        fit=("alpha", "gamma"))
    assert 0 < r.exponent_err < 0.2
    assert abs(r.exponent - 1.8) < 4 * r.exponent_err
    assert abs(r.values["alpha"] - truth[0]) < 4 * r.errors["alpha"]
    assert r.to_row()["exponent_err"] == r.exponent_err
    with pytest.raises(SpherexReduceError, match="needs 'gamma'"):
        fit_noise_model(temporal_psd(x, FS, nperseg=256), exponent=None, fit=("alpha",))


def test_model_and_aliased_basis():
    b = model_basis([2.0], exponent=1.3)[0]
    assert b == pytest.approx([1, 0.5, 2**-1.3])
    # white noise averaged over nbox samples every m samples: alpha * m / nbox
    assert aliased_basis([10.0, 300.0], FS, 72, 4)[:, 0] == pytest.approx([18, 18])
    # no decimation, no box: the plain model
    f = np.array([5.0, 50.0, 500.0])
    assert np.allclose(aliased_basis(f, FS, 1, 1), model_basis(f))


def test_aliased_stream_fit_recovers_pixel_rate_coefficients():
    """Means of c = 4 samples every 72 samples (phantom reads) fit with the aliased model."""
    truth = (3.71e-5, 8.40e-3, 0.0)  # Video8
    x = synth(72 * 2**12, truth, np.random.default_rng(21), nstreams=4, pad=4)
    y = x.reshape(4, -1, 72)[:, :, :4].mean(axis=-1)
    spec = temporal_psd(y, FS / 72, nperseg=512)
    r = fit_noise_model(spec, basis=lambda f, e: aliased_basis(f, FS, 72, 4, e))
    assert np.all(np.abs(pulls(r, truth)) < 4), (r.values, r.errors)
    # the plain model would be wrong by the aliasing factor 72/4 on alpha
    plain = fit_noise_model(spec)
    assert plain.values["alpha"] / truth[0] > 10


def test_streams_in_time_order():
    e = raw_exposure(1, nframes=4)
    s, g = e.schedule, e.geometry
    tp = phantom_timestream(e)
    assert tp.values.shape == (g.nchannels, s.nframes, s.n_reads)
    assert np.all(np.diff(tp.samples.ravel()) > 0)  # strictly increasing in time
    assert tp.samples[1, 0] - tp.samples[0, 0] == s.frame_samples
    # residuals equal an independent per-position straight-line fit over frames
    raw = np.asarray(e.phantom, dtype=float)[:, :, 2]  # frames, reads of channel 2
    t = np.arange(s.nframes)
    fitted = np.polynomial.polynomial.polyfit(t, raw, 1)
    resid = raw - np.polynomial.polynomial.polyval(t, fitted).T
    assert np.allclose(tp.values[2], resid * np.sqrt(4 / 2), atol=1e-3)
    tc = reference_timestream(e, "columns")
    assert tc.values.shape == (2, s.nframes, s.n_reads)
    assert np.all(np.diff(tc.samples.ravel()) > 0)
    tr = reference_timestream(e, "rows")
    nref = s.reference_read_indices.size
    assert tr.values.shape == (g.nchannels, s.nframes, nref, g.channel_width)
    assert np.all(np.diff(tr.samples.ravel()) > 0)


def test_fit_raw_noise_recovers_coefficients():
    t = fit_raw_noise(raw_exposure(2))
    assert list(t["stream"]) == ["reference", "phantom"]
    for row in t:
        truth = PIXELS if row["stream"] == "reference" else PHANTOM
        for k, v in zip(("alpha", "beta", "gamma"), truth, strict=True):
            assert abs(row[k] - v) < 4 * row[f"{k}_err"], (row["stream"], k, row[k], v)
    ref = t[0]
    assert ref["alpha_err"] < 0.05 * PIXELS[0]  # the white level is measured well
    assert str(t["alpha"].unit) == "electron2 / Hz"


def test_fit_raw_noise_with_alternating_column_noise():
    """Independent even/odd column noise: per-parity streams give the per-column PSD."""
    pixels = (1e-4, 5e-2, 0.0)
    e = raw_exposure(4, pixels=pixels, acn=True)
    ref = fit_raw_noise(e, fit=("alpha", "beta"))[0]
    for k, v in zip(("alpha", "beta"), pixels, strict=False):
        assert abs(ref[k] - v) < 4 * ref[f"{k}_err"], (k, ref[k], v, ref[f"{k}_err"])
    # mixing the parities halves the 1/f power of the border-column average
    mixed = fit_raw_noise(e, fit=("alpha", "beta"), acn=False)[0]
    assert mixed["beta"] < pixels[1] - 4 * mixed["beta_err"]


def test_raw_stream_errors():
    e = raw_exposure(3, nframes=4)
    from spherex_reduce import unchop

    with pytest.raises(SpherexReduceError, match="readout order"):
        phantom_timestream(unchop(e))
    with pytest.raises(SpherexReduceError, match="columns' or 'rows"):
        reference_timestream(e, "diagonal")
    with pytest.raises(SpherexReduceError, match="at least 4 samples"):
        temporal_psd([1.0, 2.0], 10.0)
    with pytest.raises(SpherexReduceError, match="NaN"):
        temporal_psd([1.0, np.nan, 2.0, 3.0, 4.0], 10.0)


def test_a_good_fit_is_not_flagged_and_bad_ones_are():
    """Implausible fits are flagged (meta and one warning), a fit of the model's own noise
    is not."""
    from astropy.table import Table

    from spherex_reduce.analysis.timestreams import implausible_fits

    good = fit_raw_noise(raw_exposure(2))  # a warning would fail the test here
    assert "implausible" not in good.meta and implausible_fits(good) == {}
    bad = Table({"stream": ["reference", "phantom"], "alpha": [1e-3, -1e-3],
                 "alpha_err": [1e-4, 1e-4], "beta": [0.0, 0.0], "beta_err": [0.0, 0.0],
                 "gamma": [2.0, 1.0], "gamma_err": [1e-15, 0.1], "chi2": [30.0, 6.3e14],
                 "dof": [2, 47]})
    assert implausible_fits(bad) == {
        "reference": ["gamma = 2 ± 1e-15, an error below floating-point noise",
                      "chi2/dof = 30/2", "2 degrees of freedom: too few frequency bins to "
                      "test the model (use more rows or reads)"],
        "phantom": ["alpha = -0.001 is 10 sigma below zero", "chi2/dof = 6.3e+14/47"]}


def test_reference_rows_of_a_window_are_timed_by_the_full_readout():
    """A window of 4 columns inside the reversed channel 1 (columns 8-15) of a 16 x 16
    array: its columns 9-12 are sampled 6, 5, 4, 3 samples into each row read."""
    from spherex_reduce import DetectorGeometry, Exposure, ReadoutSchedule
    from spherex_reduce.core.window import Window

    full = DetectorGeometry(16, 16, 2, ref_border={"top": 2, "bottom": 2}, scan="alternate")
    s = ReadoutSchedule(Window(0, 9, full).geometry(16, 4), skip=1, ref_mode="none",
                        phantom_reads=1, row_overhead=2, nframes=3, frame_time=0.01)
    e = Exposure.from_arrays(np.zeros((3, 16, 4)), s)
    row_read = 1 + 8 + 2  # phantom, full channel width, overhead
    starts = np.array([0, 1, 14, 15]) * row_read + 1  # the reference rows' reads
    tr = reference_timestream(e, "rows")
    assert tr.samples[0].tolist() == (starts[:, None] + [3, 4, 5, 6]).tolist()
    even = reference_timestream(e, "rows", parity="even")
    assert even.samples[0].tolist() == (starts[:, None] + [4, 6]).tolist()


def test_cross_basis_of_white_noise_is_the_shared_samples():
    """Two means of white samples (4 at offsets 0-3, 4 at offsets 2-5) share 2 samples:
    their covariance per read is ``σ² · 2 / 16`` and, decimated once every ``m``
    samples, the one-sided cross-spectrum ``2 · cov / f_r = α · m · 2 / 16``
    (``σ² = α fs / 2``); disjoint means have none."""
    m, fs = 72, 1e5
    overlap = aliased_basis([10.0, 300.0], fs, m, 4, cross=(4, 1, 2.0))[:, 0]
    assert overlap == pytest.approx([m * 2 / 16] * 2, rel=1e-9)
    apart = aliased_basis([10.0, 300.0], fs, m, 4, cross=(4, 1, 4.0))[:, 0]
    assert np.all(np.abs(apart) < 1e-9)


def test_cross_basis_matches_a_measured_cross_spectrum():
    """The cross-spectrum of a 28-sample mean and a 4-sample mean 20 samples earlier,
    decimated every 40 samples, of a 1/f stream drawn here, against the basis."""
    rng = np.random.default_rng(5)
    m, n1, n2, lag = 40, 28, 4, 20.0
    x = synth(m * 4096, (0.0, 1.0, 0.0), rng, nstreams=8, pad=4)
    reads = x.reshape(8, 4096, m)
    a = reads[:, :, 10:10 + n1].mean(axis=-1)   # centre 23.5
    b = reads[:, :, 2:2 + n2].mean(axis=-1)     # centre 3.5
    pa, pb = temporal_psd(a, FS / m, nperseg=512), temporal_psd(b, FS / m, nperseg=512)
    pab = temporal_psd(a + b, FS / m, nperseg=512)
    cross = 0.5 * (pab["psd"] - pa["psd"] - pb["psd"])
    f = np.asarray(pa["frequency"])
    want = aliased_basis(f, FS, m, n1, cross=(n2, 1, lag))[:, 1]
    sel = slice(4, None)
    ratio = np.sum(cross[sel]) / np.sum(want[sel])
    assert ratio == pytest.approx(1.0, abs=0.05)


def test_a_weight_column_makes_the_fit_linear():
    """With fixed weights the fit of a difference of spectra is the difference of fits."""
    rng = np.random.default_rng(2)
    x = synth(16384, (2e-3, 1e-1, 1.0), rng, nstreams=4)
    y = synth(16384, (1e-3, 5e-2, 0.0), rng, nstreams=4)
    sx, sy = temporal_psd(x, FS, nperseg=1024), temporal_psd(y, FS, nperseg=1024)
    w = sx["psd"] + sy["psd"]
    fits = []
    for psd in (sx["psd"], sy["psd"], sx["psd"] - sy["psd"]):
        t = sx.copy()
        t["psd"], t["weight"] = psd, w
        fits.append(fit_noise_model(t))
    for p in ("alpha", "beta", "gamma"):
        assert fits[2].values[p] == pytest.approx(fits[0].values[p] - fits[1].values[p],
                                                  rel=1e-9, abs=1e-15)
    bad = sx.copy()
    bad["weight"] = -w
    with pytest.raises(SpherexReduceError, match="weight column must be positive"):
        fit_noise_model(bad)


def test_aliased_basis_is_computed_once_per_set_of_arguments_and_returned_as_a_copy(
        monkeypatch):
    """The fit over all darks and each of its jackknife fits ask for the same terms (a
    third of characterize's spectral fits was spent recomputing them): each set of
    arguments is computed once, and what a caller does to its array does not reach the
    next caller, whose numbers are the formula's (the white term of an ``nbox``-sample
    mean every ``m`` samples is ``m / nbox``)."""
    from spherex_reduce.analysis import temporal
    from spherex_reduce.core.recently_used import RecentlyUsed

    calls = []
    original = temporal._aliased_terms
    monkeypatch.setattr(temporal, "_aliased_terms",
                        lambda *a: calls.append(a[2:4]) or original(*a))
    monkeypatch.setattr(temporal, "_BASES", RecentlyUsed(2**20, size=lambda t: t.nbytes))
    f = np.array([3.0, 30.0, 300.0])
    first = aliased_basis(f, FS, 72, 4)
    first[:] = -1.0
    again = aliased_basis(f, FS, 72, 4)
    assert len(calls) == 1
    assert again[:, 0] == pytest.approx([18.0] * 3) and np.all(again[:, 1:] > 0)
    # every argument is part of the key: each of these is computed, and is the formula's
    others = [((f, FS, 72, 8), 9.0), ((f, FS, 72, 4, 2.0), 18.0), ((f, FS, 72, 4, 1.3, 2), 18.0),
              ((f, FS, 36, 4), 9.0), ((f * 2, FS, 72, 4), 18.0)]
    for args, white in others:
        got = aliased_basis(*args)
        assert got[:, 0] == pytest.approx([white] * 3)
    assert len(calls) == 1 + len(others)
    cross = [aliased_basis(f, FS, 72, 4, cross=(4, 1, lag))[:, 2] for lag in (0, 10)]
    assert len(calls) == 3 + len(others) and not np.allclose(cross[0], cross[1])
    assert aliased_basis(f, FS, 72, 4, exponent=2.0)[:, 2] == pytest.approx(
        original(f, FS, 72, [(4, 1)], 2.0, None)[:, 2])


def test_aliased_basis_keeps_its_terms_within_its_bytes(monkeypatch):
    """The terms kept are bounded by their bytes (`temporal.BASES_BYTES`): past it the
    oldest are let go and computed again when asked for; the newest are kept."""
    from spherex_reduce.analysis import temporal

    calls = []
    original = temporal._aliased_terms
    monkeypatch.setattr(temporal, "_aliased_terms",
                        lambda *a: calls.append(a[0][0]) or original(*a))
    size = 3 * 8 * 20000  # one set of terms of 20000 frequencies
    kept = temporal.BASES_BYTES // size
    start = 1e-3 + np.pi  # frequencies no other test asks for
    sets = [start + k + np.linspace(1.0, 2.0, 20000) for k in range(kept + 2)]
    for f in sets:
        aliased_basis(f, FS, 2, 1)
    assert len(calls) == kept + 2
    aliased_basis(sets[-1], FS, 2, 1)  # the newest: kept
    assert len(calls) == kept + 2
    aliased_basis(sets[0], FS, 2, 1)  # the oldest: let go
    assert len(calls) == kept + 3


def _ar1_periodogram_expectation(phi, n, k, fs):
    """E[Welch periodogram] at frequencies ``k fs / n`` of an AR(1) process of unit
    innovations, each segment less its mean, from the autocovariance ``R = phi^|d| / (1 -
    phi^2)`` in the time domain: ``2 / (fs Σw²) g R g*`` with ``g = w e^(-2πi k t / n)``
    less its mean (the mean's removal)."""
    from scipy.signal import get_window

    w = get_window("hann", n)
    t = np.arange(n)
    r = phi ** np.abs(np.subtract.outer(t, t)) / (1 - phi**2)
    out = []
    for kk in k:
        g = w * np.exp(-2j * np.pi * kk * t / n)
        g -= g.mean()
        out.append(2 * np.real(g @ r @ g.conj()) / (fs * np.sum(w**2)))
    return np.array(out)


def test_welch_terms_are_the_periodogram_expectation():
    """The window's smoothing of a spectrum that curves within a few frequencies (an AR(1)
    process, phi = 0.95) against its periodogram's expectation summed in the time domain,
    the segment's mean removed (it reaches the first Welch frequency only: there white
    noise loses a sixth of its power); white noise is unchanged elsewhere."""
    from spherex_reduce.analysis import welch_terms

    phi, n, fs = 0.95, 256, 10.0

    def ar1(f, e):  # one-sided PSD of x_t = phi x_(t-1) + e_t, unit innovations
        z = np.exp(-2j * np.pi * np.asarray(f) / fs)
        return np.stack([2 / (fs * np.abs(1 - phi * z) ** 2), np.ones(np.shape(f))], axis=-1)

    k = np.array([1, 2, 3, 4, 6, 10, 40, 128])
    f = k * fs / n
    meta = {"nperseg": n, "sample_rate": fs, "window": "hann", "detrend": "constant"}
    got = welch_terms(ar1, f, 1.3, meta)
    exact = _ar1_periodogram_expectation(phi, n, k, fs)
    assert got[:, 0] == pytest.approx(exact, rel=1e-4)
    assert got[1:, 1] == pytest.approx(1.0, rel=1e-12)
    assert got[0, 1] == pytest.approx(5 / 6, rel=1e-12)
    # the smoothing is not negligible where the spectrum curves: the bare PSD is off there
    assert abs(ar1(f, 1.3)[1, 0] / exact[1] - 1) > 0.02
    with pytest.raises(SpherexReduceError, match="Hann window"):
        welch_terms(ar1, f, 1.3, {**meta, "window": "boxcar"})
    with pytest.raises(SpherexReduceError, match="detrend is 'linear'"):
        welch_terms(ar1, f, 1.3, {**meta, "detrend": "linear"})
    for none in (False, np.False_, 0):  # what scipy takes for no detrending
        with pytest.raises(SpherexReduceError, match="not detrended"):
            welch_terms(ar1, f, 1.3, {**meta, "detrend": none})
    made = temporal_psd(np.ones((1, 64)) + np.arange(64), 1.0, nperseg=32,
                        detrend=lambda s: s - np.median(s))
    assert made.meta["detrend"] == "callable"  # the table can still be written
    with pytest.raises(SpherexReduceError, match="detrend is 'callable'"):
        welch_terms(ar1, f, 1.3, {**meta, "detrend": "callable"})
    assert welch_terms(ar1, f[1:], 1.3, {**meta, "detrend": False}) == pytest.approx(got[1:])
    assert temporal_psd(np.zeros((1, 64)) + np.arange(64), 1.0, nperseg=32).meta[
        "detrend"] == "constant"
    with pytest.raises(SpherexReduceError, match=r"in \(0, 5\] Hz"):
        welch_terms(ar1, [6.0], 1.3, meta)


def test_fit_of_many_segments_is_unbiased_at_the_lowest_frequencies():
    """~30 000 segments of 256 samples of α + β/f + γ/f^1.3: the fit's β and γ within 3.5
    of their errors of the truth.  Fitted with the bare terms instead of the window's
    expectation of them (`welch_terms`), γ came out 6.4 errors high, β 5.1 low, α 3.6 high."""
    from spherex_reduce.analysis.characterize.spectra import pool

    truth = (1e-2, 2e-2, 2e-2)
    rng = np.random.default_rng(11)
    fs = 100.0
    spectra = [{"x": temporal_psd(synth(2**16, truth, rng, nstreams=8, pad=2, fs=fs), fs,
                                  nperseg=256)} for _ in range(8)]
    r = fit_noise_model(pool(spectra)["x"])
    p = pulls(r, truth)
    assert np.all(np.abs(p) < 3.5), p
