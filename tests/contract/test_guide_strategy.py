"""The plugin guide's streaming strategy: it streams like ``mean`` and gives its own numbers."""

import importlib.util
import warnings

import numpy as np
import pytest
from _one_by_one import one_by_one
from _paths import ROOT

from spherex_reduce import Pipeline, unchop, write
from spherex_reduce.io.examples import example_raw_exposure
from spherex_reduce.reduce.plugins import Registry, get_plugin_manager

EXAMPLE = ROOT / "docs" / "examples" / "reference_median.py"


@pytest.fixture(scope="module")
def plugin():
    spec = importlib.util.spec_from_file_location("reference_median", EXAMPLE)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.fixture
def registry(plugin):
    return Registry(get_plugin_manager(entry_points=False, plugins=[plugin]))


STEPS = ["unchop", "subtract_phantom", {"correct_reference": {"strategy": "refmedian"}},
         "fit_ramp"]


def test_the_guide_strategy_streams_from_a_file_in_one_pass(tmp_path, small_schedule, registry):
    raw = example_raw_exposure(small_schedule, seed=4)
    path = write(raw, tmp_path / "raw.fits")
    pipe = Pipeline({"steps": STEPS}, registry=registry)
    out = pipe.run(path, threads=2)
    routes = out.tables["PROVENANCE"]["route"].tolist()
    assert all("pass of 4 step(s)" in r and "from a file" in r for r in routes)
    by_hand = one_by_one(pipe, raw)
    np.testing.assert_array_equal(out.data.data, by_hand.data.data)
    assert out.header["REFSTRAT"] == "refmedian"


def test_the_guide_strategy_subtracts_the_median_of_each_channels_reference_pixels(
        small_schedule, registry):
    raw = example_raw_exposure(small_schedule, seed=6)
    pipe = Pipeline({"steps": ["unchop", "subtract_phantom",
                               {"correct_reference": {"strategy": "refmedian"}}]},
                    registry=registry)
    out = pipe.run(raw)
    # independently: phantom-subtracted reference reads, median per frame and channel
    s, g = raw.schedule, raw.geometry
    idx = s.reference_read_indices
    ref = raw.data.data[:, idx].astype(np.float64)
    ph = np.repeat(raw.phantom[:, idx], g.channel_width, axis=-1)
    ref = ref - ph
    med = np.median(ref.reshape(s.nframes, idx.size, g.nchannels, g.channel_width),
                    axis=(1, 3))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        phys = unchop(raw)
    expected = (phys.data.data.astype(np.float64)
                - np.repeat(phys.phantom, g.channel_width, axis=-1)
                - np.repeat(med, g.channel_width, axis=-1)[:, None, :])
    np.testing.assert_allclose(out.data.data, expected, rtol=0, atol=2e-3)
    np.testing.assert_allclose(out.tables["REFOFFS"]["offset"],
                               med.ravel(), rtol=1e-5, atol=1e-4)
