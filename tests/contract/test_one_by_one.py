"""A pipeline's passes, streamed from a file or from memory, give the steps called one by one."""

import warnings

import numpy as np
import pytest
from _one_by_one import one_by_one
from _toy_steps import ToyPlugin, registry_with, write_raw

from spherex_reduce import Pipeline, dq, unchop
from spherex_reduce.io.examples import example_raw_exposure, tiny_schedule


@pytest.fixture
def raw(small_schedule):
    return example_raw_exposure(small_schedule, seed=5)


def test_a_plugin_kernel_and_consumer_stream_like_the_steps_called_one_by_one(tmp_path, raw):
    path = write_raw(tmp_path, raw)
    registry = registry_with(ToyPlugin())
    pipe = Pipeline({"steps": ["unchop", "note", "framesum"]}, registry=registry)
    s = raw.schedule
    # independently: the reference reads' mean of each frame, off the un-chopped pixels
    means = raw.data.data[:, s.reference_read_indices].mean(axis=(1, 2), dtype=np.float64)
    expected = (unchop(raw).data.data - means[:, None, None]).sum(axis=0)
    by_hand = one_by_one(pipe, raw)
    for source in (raw, path):
        out = pipe.run(source, threads=3)
        np.testing.assert_allclose(out.data.data, expected, rtol=1e-12)
        np.testing.assert_array_equal(out.data.data, by_hand.data.data)
        assert out.order == "physical" and out.data.data.ndim == 2
        for key in ("S_UNCHOP", "S_NOTE", "S_FSUM"):
            assert out.header[key] == by_hand.header[key] == "COMPLETE"
        np.testing.assert_allclose(out.tables["NOTE"]["mean"], means, rtol=1e-12)
        routes = out.tables["PROVENANCE"]["route"].tolist()
        assert all("pass of 3 step(s)" in r for r in routes)


def test_streamed_summary_keywords_cover_every_frame():
    s = tiny_schedule(nframes=4)
    raw = example_raw_exposure(s, seed=3)
    flags = np.zeros(raw.shape, np.uint16)
    for f in (0, 1):
        flags[f][np.ix_(s.reference_read_indices, np.arange(16))] = dq.DO_NOT_USE
    raw = raw.replace(dq=flags)
    cfg = {"steps": ["unchop", "subtract_phantom", "correct_reference", "fit_ramp"]}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # "no usable reference pixels", tested elsewhere
        streamed = Pipeline(cfg).run(raw)
        in_memory = one_by_one(cfg, raw)
    assert streamed.header["NNOREF"] == in_memory.header["NNOREF"] == 2
