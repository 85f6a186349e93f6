"""The simulator's exact expectation against the analytic slope variance.

The engine's own ensemble variance (its tiers, padding and interpolation) is
checked against the analytic value for every Table 2 component and
N = 2, 10, 74, 386, at full size and small; the analytic value itself is
checked against quadrature in ``tests/noise/test_noise_model.py``.
"""

import pytest

from spherex_reduce import expected_slope_variance
from spherex_reduce.io.config import schedule_from_config
from spherex_reduce.simulation import NoiseComponent, NoiseEngine, noise_components

SINGLE = [NoiseComponent("alpha_only", alpha=2e-3), NoiseComponent("beta_only", beta=8.4e-3),
          NoiseComponent("gamma_only", gamma=0.1)]
SMALL = ({"nrows": 16, "ncols": 64, "nchannels": 32, "ref_border": 0},
         {"skip": 1, "ref_reads": 0, "phantom_reads": 0, "row_overhead": 0,
          "frame_overhead": 200})


@pytest.mark.parametrize("geo", ["full", "small"])
@pytest.mark.parametrize("n", [2, 10, 74, 386])
def test_simulator_expectation_matches_analytic(geo, n):
    """The engine's exact ensemble variance (both modes) is within 2 % of the aperiodic value."""
    g, r = ({}, {}) if geo == "full" else SMALL
    s = schedule_from_config(g, {**r, "nframes": n})
    comps = [c for c in noise_components().values() if c.seen_by_pixels] + SINGLE
    for comp in comps:
        eng = NoiseEngine(s, [comp.replace(acn=False) if comp.scope == "channel" else comp], 0)
        sim = eng.expected_slope_variance(read=3, column=5)
        ana = expected_slope_variance(comp, s).value
        assert sim == pytest.approx(ana, rel=0.02), comp.name


@pytest.mark.parametrize("streaming", [False, True])
def test_expectation_streamed_and_in_memory_slow_tier(streaming):
    g, r = SMALL
    s = schedule_from_config(g, {**r, "nframes": 74})
    for comp in SINGLE[1:]:
        eng = NoiseEngine(s, [comp], 0, streaming=streaming)
        assert eng.streaming is streaming
        ana = expected_slope_variance(comp, s).value
        assert eng.expected_slope_variance(2, 7) == pytest.approx(ana, rel=0.02)


def test_random_phase_without_padding_reproduces_the_low_bias():
    """The paper's method (period = exposure) is ~50 % low for gamma/f^1.3 at N = 10."""
    s = schedule_from_config({}, {"nframes": 10})
    comp = NoiseComponent("g", gamma=0.1)
    ana = expected_slope_variance(comp, s).value
    biased = NoiseEngine(s, [comp], 0, method="random_phase", padding=1).expected_slope_variance()
    padded = NoiseEngine(s, [comp], 0, padding=16).expected_slope_variance()
    assert biased / ana < 0.6
    assert padded / ana == pytest.approx(1, abs=0.01)
