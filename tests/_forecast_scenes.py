"""The tiny scenes, noise terms and pipelines the forecast's tests share, and their check against
the brute force of tests/_forecast_brute.py (every sample's covariance pushed through the
reduction as an explicit matrix)."""

import numpy as np
from _forecast_brute import Samples, expected_spectrum, reduction_matrix
from astropy import units as u

from spherex_reduce.analysis import forecast
from spherex_reduce.simulation import load_scene

BINS = 5
PINK = {"name": "pink", "beta": 8e-3}
PINK_ACN = {"name": "pink_acn", "beta": 8e-3, "acn": True}
ROIC = {"name": "roic", "alpha": 2e-3, "gamma": 0.1, "exponent": 1.3, "acn": True}
COMMON = {"name": "common", "alpha": 3e-6, "beta": 9e-5, "scope": "common"}
PHANTOM = {"name": "phantom_only", "beta": 4e-5, "scope": "common", "visibility": "phantom"}
BOTH = {"name": "video8", "alpha": 1e-3, "beta": 5e-3, "visibility": "both", "acn": True}
BOTH_COMMON = {"name": "bias", "beta": 2e-4, "scope": "common", "visibility": "both"}

#: name: (what the brute force subtracts, the pipeline)
PIPELINES = {
    "phantom-only": (dict(phantom=True), "phantom-only"),
    "spherex-default": (dict(phantom=True, reference="mean", reference_phantom=True),
                        "spherex-default"),
    "reference-first": (dict(phantom=True, reference="mean"),
                        {"steps": [{"unchop": {}}, {"correct_reference": {}},
                                   {"subtract_phantom": {}}]}),
    "reference-only": (dict(reference="mean"), {"steps": [{"correct_reference": {}}]}),
    "acn": (dict(phantom=True, reference="acn", reference_phantom=True), "acn"),
    "side-columns": (dict(phantom=True, reference="mean", reference_phantom=True,
                          side_columns=True),
                     {"steps": [{"subtract_phantom": {}},
                                {"correct_reference": {"side_columns": True}}]}),
    "acn-side-columns": (dict(phantom=True, reference="acn", reference_phantom=True,
                              side_columns=True),
                         {"steps": [{"subtract_phantom": {}}, {"correct_reference": {
                             "strategy": "acn", "side_columns": True}}]}),
}


def tiny(components, scan="same", terms=None, readout=None):
    """20 x 20 pixels in 2 channels of 10 columns, a reference border of 2 (16 x 16 light
    pixels), skip 3, 4 distributed reference reads, 2 phantom samples per read, a frame
    ~60 times the reads' span; ``readout`` replaces readout keys."""
    return load_scene({
        "geometry": {"nrows": 20, "ncols": 20, "nchannels": 2, "ref_border": 2, "scan": scan},
        "readout": {"skip": 3, "ref_reads": 4, "phantom_reads": 2, "nframes": 4,
                    "frame_overhead": 20000, **(readout or {})},
        "noise": {"components": components},
        "scene": terms or {},
    })


def check_against_brute_force(scene, subtract, pipeline):
    samples = Samples(scene)
    cov = sum(samples.covariance(scene.components).values())
    expect = expected_spectrum(samples, reduction_matrix(samples, **subtract), cov, BINS)
    got = forecast(scene, pipeline, {"bins": BINS})
    p = u.Quantity(got["power"]).value
    np.testing.assert_allclose(p, expect, rtol=1e-3)
    n = np.asarray(got["nmodes"], float)
    assert abs(np.sum(p * n) / np.sum(expect * n) - 1) < 1e-4
