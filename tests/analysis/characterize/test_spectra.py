"""`dark_spectra`: a dark's spectra taken in threads are those taken one at a time, and
each is the Welch estimate of its stream."""

import numpy as np
import pytest
import scipy.signal

from spherex_reduce.analysis.characterize import spectra
from spherex_reduce.analysis.characterize.spectra import dark_spectra
from spherex_reduce.analysis.characterize.streams import channel_streams
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
