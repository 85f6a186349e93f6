"""`dark_spectra`: a dark's spectra taken in threads are those taken one at a time, and
each is the Welch estimate of its stream."""

import numpy as np
import pytest
import scipy.signal

from spherex_reduce.analysis.characterize import spectra
from spherex_reduce.analysis.characterize.spectra import dark_spectra
from spherex_reduce.analysis.characterize.streams import Box, channel_streams
from spherex_reduce.io.examples import example_raw_exposure


@pytest.mark.parametrize("threads", [2, 3])
def test_the_spectra_do_not_depend_on_the_threads(monkeypatch, threads):
    e = example_raw_exposure()
    st = channel_streams(e)
    monkeypatch.setattr(spectra, "SPECTRA_THREADS", 1)
    one = dark_spectra(st, e.schedule)
    monkeypatch.setattr(spectra, "SPECTRA_THREADS", threads)
    monkeypatch.setattr(spectra, "default_threads", lambda: 4)
    many = dark_spectra(st, e.schedule)
    assert list(many) == list(one)  # the keys in the same order
    for key in one:
        np.testing.assert_array_equal(many[key]["psd"], one[key]["psd"], err_msg=key)
        assert many[key].meta == one[key].meta
    # one of them against scipy's Welch estimate, written out
    rate = e.schedule.geometry.pixel_rate / e.schedule.row_samples
    n = many["sum_mean"].meta["nperseg"]
    f, p = scipy.signal.welch(st.sum.mean(axis=0), fs=rate, window="hann", nperseg=n,
                              axis=-1)
    keep = (f > 0) & (f < f[-1])
    np.testing.assert_allclose(many["sum_mean"]["psd"].value, p.mean(axis=0)[keep],
                               rtol=1e-12)


def test_phantom_values_of_acn_fit_their_white_level_with_each_paritys_average():
    """Phantom values (means of 4 samples every 72, 100 kHz) of white noise and a 1/f drawn
    apart for even and odd samples (ACN), synthesised by numpy FFTs: fitted with the whole
    box's terms the white level comes back several errors high (1/f near the pixel rate's
    Nyquist frequency passes an average of every other sample whole and looks white);
    with `_parity_basis` within 3 errors, and its 1/f is one parity stream's."""
    fs, m, c, nv, n = 1e5, 72, 4, 1024, 2**17
    alpha, beta = 3.71e-5, 0.84
    f = np.fft.rfftfreq(n, 1 / fs)
    amp = np.zeros(f.size)
    amp[1:-1] = np.sqrt(beta / f[1:-1] * n * fs / 4)  # one-sided beta/f, unit variance draws
    rng = np.random.default_rng(3)
    idx = np.arange(nv)[:, None] * m + np.arange(c)
    values = []
    for _ in range(800):
        a, b = (np.fft.irfft(amp * (rng.standard_normal(f.size)
                                    + 1j * rng.standard_normal(f.size)), n=n) for _ in "ab")
        x = np.where(idx % 2 == 0, a[idx], b[idx])
        values.append((x + rng.normal(0, np.sqrt(alpha * fs / 2), idx.shape)).mean(axis=1))
    spec = spectra.temporal_psd(np.array(values), fs / m, nperseg=nv)
    whole = spectra.fit_noise_model(spec, 1.3, nbins=30, basis=lambda ff, e:
                                    spectra.aliased_basis(ff, fs, m, c, e))
    parity = spectra.fit_noise_model(
        spec, 1.3, nbins=30, basis=spectra._parity_basis(Box(c, 1, 1.5, even=2), fs, m))
    assert (whole.values["alpha"] - alpha) / whole.errors["alpha"] > 3
    assert abs(parity.values["alpha"] - alpha) < 3 * parity.errors["alpha"]
    assert parity.values["beta"] == pytest.approx(beta, rel=0.03)
