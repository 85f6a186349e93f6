"""The forecast through the ``wiener`` reference strategy (analysis/forecast/wiener.py): against
a brute-force covariance of every sample propagated by the strategy's own weights as an
explicit matrix (tests/_forecast_brute.py), and against the shipped ``wiener`` pipeline on the
package's own simulator."""

import numpy as np
import pytest
from _forecast_brute import Samples, expected_spectrum, wiener_matrix
from _forecast_scenes import BINS, BOTH, COMMON, PHANTOM, PINK_ACN, ROIC, tiny
from astropy import units as u

from spherex_reduce.analysis import forecast, power_spectrum
from spherex_reduce.analysis.light import light_sensitive_image
from spherex_reduce.core.block import Context
from spherex_reduce.reduce.pipeline import as_pipeline
from spherex_reduce.reduce.steps.reference.wiener import WienerReference
from spherex_reduce.simulation import simulate

WIENER_CASES = {
    # (strategy parameters, subtract_phantom first, on ramps)
    "phantom-observed": ({}, False, True),
    "phantom-subtracted": ({}, True, True),
    "acn-slopes": ({"acn": True}, False, False),
    "phantom-ignored": ({"phantom": "ignore"}, False, True),
    "side-columns": ({"side_columns": True}, False, True),
    "side-columns-subtracted-acn": ({"side_columns": True, "acn": True}, True, False),
}


@pytest.mark.parametrize("case", WIENER_CASES)
def test_wiener_equals_brute_force(case):
    """The strategy's own weights (the same code) applied as an explicit matrix to every
    sample, under the scene's noise."""
    params, first, ramps = WIENER_CASES[case]
    scene = tiny([PINK_ACN, BOTH, COMMON, PHANTOM], scan="alternate")
    strategy = WienerReference(noise="spherex-table2", **params)
    context = Context(scene.schedule, "readout", ramps, has_phantom=not first)
    groups = range(2 if strategy.acn else 1)
    weights = [strategy.read_weights(context, p) for p in groups]
    sides = [strategy.side_weights(context, p) for p in groups]
    assert all(w is not None for w, *_ in sides) == bool(params.get("side_columns"))
    samples = Samples(scene)
    cov = sum(samples.covariance(scene.components).values())
    lmat = wiener_matrix(samples, weights, strategy.acn, phantom=first, sides=sides)
    expect = expected_spectrum(samples, lmat, cov, BINS)
    steps = [{"unchop": {}}, *([{"subtract_phantom": {}}] if first else []),
             *([] if ramps else [{"fit_ramp": {}}]),
             {"correct_reference": {"strategy": "wiener", "noise": "spherex-table2", **params}}]
    got = forecast(scene, {"steps": steps}, {"bins": BINS})
    p = u.Quantity(got["power"]).value
    np.testing.assert_allclose(p, expect, rtol=1e-3)
    n = np.asarray(got["nmodes"], float)
    assert abs(np.sum(p * n) / np.sum(expect * n) - 1) < 1e-4


def test_wiener_monte_carlo_of_the_shipped_pipeline():
    """300 slope images reduced by the shipped ``wiener`` pipeline (its drift estimate from
    the reference reads and phantom values) against the forecast in every bin."""
    scene = tiny([ROIC, PINK_ACN, COMMON, BOTH, PHANTOM], scan="alternate",
                 terms={"dark_current": 20.0})
    p = as_pipeline("wiener")
    runs = np.array([power_spectrum(light_sensitive_image(p.run(simulate(scene, seed=i))),
                                    bins=BINS)["power"].value for i in range(300)])
    mean, se = runs.mean(axis=0), runs.std(axis=0, ddof=1) / np.sqrt(len(runs))
    expect = u.Quantity(forecast(scene, "wiener", measure={"bins": BINS})["power"]).value
    assert np.all(np.abs(mean - expect) < 3 * se), (mean - expect) / se
