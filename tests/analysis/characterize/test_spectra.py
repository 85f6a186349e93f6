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


def test_no_burst_kept_in_every_channel_leaves_the_common_reference_spectrum_out():
    """Channel 0 loses its even reference-row bursts, channel 1 its odd ones (a pixel left
    out in each): no burst is clean in both, so the bursts' cross-spectrum between channels
    has nothing to average (it raised inside scipy: review); the rest is there, and
    pooling it with a dark that has it keeps only the spectra both darks have.  Channels of
    64 columns (bursts of 32 per parity, too short for the common white level) have none."""
    from spherex_reduce.io.config import schedule_from_config

    s = schedule_from_config({"nrows": 64, "ncols": 256, "nchannels": 2, "ref_border": 4,
                              "scan": "alternate"},
                             {"skip": 4, "ref_reads": 8, "phantom_reads": 2, "nframes": 4,
                              "frame_overhead": 100})
    e = example_raw_exposure(s)
    g = e.schedule.geometry
    left = np.zeros((g.nrows, g.ncols), bool)
    offs, chan = g.column_offsets(), g.channel_of_column()
    for r in np.flatnonzero(g.reference_pixel_mask().all(axis=1)):
        left[r, np.flatnonzero((chan == 0) & (offs == 2))[0]] = True
        left[r, np.flatnonzero((chan == 1) & (offs == 3))[0]] = True
    lacking = dark_spectra(channel_streams(e, leave_out=left), e.schedule)
    assert "rows_mean" not in lacking and {"rows", "rows[0]", "rows[1]"} <= set(lacking)
    whole = dark_spectra(channel_streams(e), e.schedule)
    assert {"rows_each", "rows_mean"} <= set(whole)
    pooled = spectra.pool([whole, lacking])
    assert "rows_mean" not in pooled and set(pooled) == set(lacking)
    narrow = schedule_from_config({"nrows": 64, "ncols": 128, "nchannels": 2, "ref_border": 4},
                                  {"skip": 4, "ref_reads": 8, "phantom_reads": 2, "nframes": 4,
                                   "frame_overhead": 100})
    e = example_raw_exposure(narrow)
    assert "rows_mean" not in dark_spectra(channel_streams(e), e.schedule)
