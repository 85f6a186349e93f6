"""The forecast 2-D FFT (Fig. 7) against a brute-force covariance of every sample pushed
through explicit reduction matrices (tests/_forecast_brute.py) and a 2-D DFT written here,
and against the mean |FFT|² of the package's own Monte Carlo."""

import numpy as np
import pytest
from _forecast_brute import Samples, reduction_matrix

from spherex_reduce.analysis import fft_magnitude
from spherex_reduce.analysis.case import run_case
from spherex_reduce.analysis.forecast.fft import forecast_fft_magnitude
from spherex_reduce.simulation import load_scene

BOTH = {"name": "video8", "alpha": 1e-3, "beta": 5e-3, "visibility": "both", "acn": True}
COMMON = {"name": "bias", "beta": 2e-4, "scope": "common", "visibility": "both"}
PHANTOM = {"name": "phantom_only", "beta": 4e-5, "scope": "common", "visibility": "phantom"}
SCENE = {"geometry": {"nrows": 20, "ncols": 20, "nchannels": 2, "ref_border": 2},
         "readout": {"skip": 3, "ref_reads": 4, "phantom_reads": 2, "nframes": 4,
                     "frame_overhead": 20000},
         "noise": {"components": [BOTH, COMMON, PHANTOM]}}


@pytest.mark.parametrize("pipeline, subtract", [
    (None, {}),
    ("spherex-default", dict(phantom=True, reference="mean", reference_phantom=True)),
])
def test_forecast_fft_equals_brute_force(pipeline, subtract):
    scene = load_scene(SCENE)
    samples = Samples(scene)
    lmat = reduction_matrix(samples, **subtract)
    cy = lmat @ sum(samples.covariance(scene.components).values()) @ lmat.T
    n = 16  # light-sensitive rows and columns
    f1 = np.exp(-2j * np.pi * np.outer(np.arange(n), np.arange(n)) / n)
    f2 = np.kron(f1, f1)  # the 2-D DFT of the image raveled row by row
    power = np.einsum("ki,ij,kj->k", f2, cy, f2.conj()).real.reshape(n, n)
    power[0, 0] = 0.0  # the mean is subtracted
    expect = np.fft.fftshift(np.sqrt(power / n**2))[8 - 3:8 + 4, 8 - 3:8 + 4]
    got = forecast_fft_magnitude(scene, pipeline, size=7)
    assert got.magnitude.shape == (7, 7)
    np.testing.assert_allclose(got.magnitude.value, expect, rtol=1e-3, atol=1e-12)
    np.testing.assert_allclose(got.ky.value, 2 * np.pi * np.arange(-3, 4) / n)


def test_forecast_fft_is_the_mean_of_the_monte_carlo():
    """120 realisations of fft_magnitude² of the real pipeline: within 4 standard errors in
    every cell (an exponential variable per cell and realisation)."""
    scene = dict(SCENE, readout={**SCENE["readout"], "frame_overhead": 0})
    got = forecast_fft_magnitude(scene, "spherex-default", size=7).magnitude.value ** 2
    draws = np.array([fft_magnitude(run_case(scene, "spherex-default", lambda im: im,
                                             seed=i).measurement, size=7).magnitude.value ** 2
                      for i in range(120)])
    mean, err = draws.mean(axis=0), draws.std(axis=0, ddof=1) / np.sqrt(len(draws))
    z = np.abs(mean - got)[got > 0] / err[got > 0]
    assert z.max() < 4, z.max()
    assert got[3, 3] == 0.0 and np.all(draws[:, 3, 3] < 1e-20)
