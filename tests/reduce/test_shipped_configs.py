"""Shipped configs end to end: FITS file in, same numbers as the functions by hand."""

import importlib.metadata
import json

import numpy as np
import pytest
from _one_by_one import one_by_one

from spherex_reduce import (
    Exposure,
    Pipeline,
    correct_reference,
    dq,
    fit_ramp,
    pair_difference,
    read,
    rechop,
    sigma_clip,
    subtract_phantom,
    unchop,
    write,
)
from spherex_reduce.cli import main
from spherex_reduce.core.errors import ConfigError
from spherex_reduce.io.config import shipped_configs
from spherex_reduce.io.examples import example_raw_exposure, tiny_schedule
from spherex_reduce.reduce.steps.reference.strategies import NoReferenceError

CONFIGS = ["spherex-default", "spherex-slopes", "measured-dark-pair", "acn", "median",
           "phantom-only"]


def by_hand(raw, strategy="mean", **params):
    e = correct_reference(subtract_phantom(unchop(raw)), strategy, **params)
    return sigma_clip(fit_ramp(e), sigma=5.0)


def test_configs_are_shipped_listed_and_valid(capsys):
    assert set(CONFIGS) <= set(shipped_configs())
    assert main(["show-config", "--list"]) == 0
    listed = capsys.readouterr().out.split()
    for name in CONFIGS:
        assert name in listed
        Pipeline.from_yaml(name)


def test_default_pipeline_on_a_fits_file_equals_the_functions_by_hand(tmp_path, capsys):
    raw = example_raw_exposure(tiny_schedule(nframes=5))
    path = write(raw, tmp_path / "raw.fits")
    out_path = tmp_path / "out.fits"
    assert main(["-q", "reduce", str(path), "-c", "spherex-default", "-o", str(out_path)]) == 0
    assert "S_RAMPFT" not in capsys.readouterr().err
    out = read(out_path)
    ref = by_hand(raw)
    np.testing.assert_allclose(out.data.data, ref.data.data, rtol=1e-5, atol=1e-4)
    # the output flags its reference pixels (a border of 4 on the 64 x 64 array)
    border = np.ones((64, 64), bool)
    border[4:-4, 4:-4] = False
    np.testing.assert_array_equal(out.dq, ref.dq | np.where(border, dq.REFERENCE, 0))
    for key in ("S_UNCHOP", "S_PHANTM", "S_REFCOR", "S_RAMPFT", "S_SIGCLP"):
        assert out.header[key] == "COMPLETE"
    t = out.tables["REFOFFS"]
    assert len(t) == 5 * 4 and set(t["frame"]) == set(range(5))
    np.testing.assert_allclose(t["offset"], ref.tables["REFOFFS"]["offset"], rtol=1e-5,
                               atol=1e-4)
    # and the same through the in-memory, non-streamed path
    whole = one_by_one(Pipeline.from_yaml("spherex-default"), raw)
    np.testing.assert_allclose(whole.data.data, out.data.data, rtol=1e-5, atol=1e-4)


def test_slope_order_equals_ramp_order_without_clipping():
    raw = example_raw_exposure(tiny_schedule(nframes=6))
    ramps = by_hand(raw, sigma=1e6)
    slopes = correct_reference(subtract_phantom(unchop(fit_ramp(raw))), "mean", sigma=1e6)
    np.testing.assert_allclose(slopes.data.data, ramps.data.data, rtol=1e-5, atol=1e-3)
    a = Pipeline.from_yaml("spherex-slopes").run(raw)
    b = Pipeline.from_yaml("spherex-default").run(raw)
    # with clipping the two orders keep different reference pixels: the images then
    # differ by one offset per channel only
    diff = (a.data.data - b.data.data).reshape(64, 4, 16)
    assert np.nanstd(diff, axis=(0, 2)).max() < 1e-3


@pytest.mark.parametrize("name,strategy", [("acn", "acn")])
def test_acn_config(name, strategy):
    raw = example_raw_exposure(tiny_schedule(nframes=4))
    out = Pipeline.from_yaml(name).run(raw)
    np.testing.assert_allclose(out.data.data, by_hand(raw, strategy).data.data, rtol=1e-5,
                               atol=1e-4)


def test_median_config():
    raw = example_raw_exposure(tiny_schedule(nframes=4))
    out = Pipeline.from_yaml("median").run(raw)
    ref = correct_reference(fit_ramp(subtract_phantom(unchop(raw))), "median")
    np.testing.assert_allclose(out.data.data, sigma_clip(ref).data.data, rtol=1e-5, atol=1e-4)


def test_measured_dark_pair_reduces_the_other_exposure_the_same_way(tmp_path):
    s = tiny_schedule(nframes=4)
    a, b = (example_raw_exposure(s, seed=k) for k in (1, 2))
    pa, pb = write(a, tmp_path / "a.fits"), write(b, tmp_path / "b.fits")
    config = Pipeline.from_yaml("measured-dark-pair").config
    with pytest.raises(ConfigError, match=r"pair_difference\.other"):
        Pipeline(config).run(pa)
    config["steps"][3]["pair_difference"]["other"] = str(pb)
    out = Pipeline(config).run(pa)

    def slopes(raw):
        return fit_ramp(subtract_phantom(unchop(raw)))

    ref = sigma_clip(correct_reference(pair_difference(slopes(a), slopes(b)), "mean"))
    np.testing.assert_allclose(out.data.data, ref.data.data, rtol=1e-5, atol=1e-4)
    assert out.header["S_PAIRDF"] == "COMPLETE" and out.header["PAIRDIFF"]
    # the provenance of the first exposure goes on through the difference
    prov = out.tables["PROVENANCE"]
    assert prov["step"].tolist() == [name for name, _ in Pipeline(config).steps]
    assert json.loads(prov["inputs"][3]) == {"other": str(pb)}
    assert out.header["PAIROTHR"] == str(pb)[-68:]


def test_subtract_dark_step(tmp_path):
    raw = example_raw_exposure(tiny_schedule(nframes=4))
    reduced = Pipeline.from_yaml("spherex-default").run(raw)
    dark = write(reduced, tmp_path / "dark.fits")
    out = Pipeline({"steps": [{"subtract_dark": {"dark": str(dark)}}]}).run(reduced)
    # the file holds the dark as float32: what is left is the rounding of each value
    left = reduced.data.data - reduced.data.data.astype(np.float32)
    np.testing.assert_allclose(out.data.data[~reduced.data.mask], left[~reduced.data.mask],
                               atol=1e-9)
    assert out.header["S_DARK"] == "COMPLETE"


@pytest.mark.parametrize("skip,ref_reads,phantom", [(1, 8, 2), (5, 8, 2), (100, 8, 2),
                                                     (4, 8, 0), (7, 3, 1)])
def test_schedule_edge_cases_reduce(skip, ref_reads, phantom):
    s = tiny_schedule(nframes=3, skip=skip, ref_reads=ref_reads, phantom_reads=phantom)
    raw = example_raw_exposure(s)
    out = Pipeline.from_yaml("spherex-default").run(raw)
    assert out.shape == (64, 64) and np.isfinite(out.data.data[4:-4]).all()
    assert out.header["S_PHANTM"] == ("COMPLETE" if phantom else "SKIPPED")
    assert np.array_equal(rechop(unchop(raw)).data.data, raw.data.data)


def test_r_zero_gives_a_clear_error():
    raw = example_raw_exposure(tiny_schedule(nframes=3, ref_reads=0))
    with pytest.raises(NoReferenceError, match="no reference rows"):
        Pipeline.from_yaml("spherex-default").run(raw)


def test_input_is_never_modified():
    raw = example_raw_exposure(tiny_schedule(nframes=3))
    raw.data.data.setflags(write=False)
    raw.phantom.setflags(write=False)
    before = raw.data.data.copy()
    for name in ("spherex-default", "spherex-slopes", "acn"):
        Pipeline.from_yaml(name).run(raw)
    assert np.array_equal(raw.data.data, before)


def _fourier_installed():
    eps = importlib.metadata.entry_points(group="spherex_reduce")
    return any(ep.name == "fourier_filter" for ep in eps)


def test_fourier_filter_plugin_through_the_entry_point():
    from spherex_reduce.reduce.plugins import Registry

    # the test command installs it; a missing plugin is a failure, not a skip
    assert _fourier_installed(), "install the plugin: pip install ./plugins/fourier_filter"

    reg = Registry()
    assert reg.providers["strategy"]["reference/fourier"] == "fourier_filter"
    s = tiny_schedule(nframes=3, phantom_reads=0)
    g = s.geometry
    offs = np.repeat([5.0, -1.0, 2.0, 7.0], g.channel_width)
    rng = np.random.default_rng(0)
    data = rng.normal(0, 1, (3, s.n_reads, g.ncols)) + offs
    raw = Exposure.from_arrays(data, s)
    p = Pipeline({"steps": ["unchop", {"correct_reference": {"strategy": "fourier"}},
                            "fit_ramp"]}, registry=reg)
    out = p.run(raw)
    assert out.header["REFSTRAT"] == "fourier"
    phys = unchop(raw).data.data
    col_means = phys.mean(axis=1, keepdims=True)
    expected = phys - col_means + phys.mean(axis=(1, 2), keepdims=True)
    streamed_frames = correct_reference(unchop(raw), "fourier", registry=reg)
    np.testing.assert_allclose(streamed_frames.data.data, expected, atol=1e-9)
    assert len(out.tables["REFOFFS"]) == 3 * 4


def test_phantom_only_is_the_corrections_without_the_reference_step():
    """The demo's comparison pipeline, shipped: slopes, unchop, phantom, 5 sigma clip."""
    raw = example_raw_exposure(tiny_schedule(nframes=5))
    out = Pipeline.from_yaml("phantom-only").run(raw)
    ref = sigma_clip(subtract_phantom(unchop(fit_ramp(raw))), sigma=5.0)
    np.testing.assert_allclose(out.data.data, ref.data.data, rtol=1e-6, atol=1e-6)
    assert "S_REFCOR" not in out.header


def test_sidecar_wiener_config_equals_the_functions_by_hand(tmp_path, capsys):
    """The shipped SIDECAR config, its noise: set as its comments say, through the CLI: the
    same numbers as the steps called by hand, and the side columns of the first and last
    channel observed."""
    import yaml

    assert main(["show-config", "sidecar-wiener"]) == 0
    cfg = yaml.safe_load(capsys.readouterr().out)
    step = cfg["steps"][1]["correct_reference"]
    assert step["side_columns"] is True and step["noise"] is None
    step["noise"] = "spherex-table2"
    (tmp_path / "p.yaml").write_text(yaml.safe_dump(cfg))
    raw = example_raw_exposure(tiny_schedule(nframes=5))
    path = write(raw, tmp_path / "raw.fits")
    out_path = tmp_path / "out.fits"
    assert main(["-q", "reduce", str(path), "-c", str(tmp_path / "p.yaml"), "-o",
                 str(out_path)]) == 0
    out = read(out_path)
    corrected = correct_reference(unchop(raw), "wiener", side_columns=True,
                                  noise="spherex-table2", domain="slopes")
    ref = sigma_clip(fit_ramp(corrected), sigma=5.0)
    np.testing.assert_allclose(out.data.data, ref.data.data, rtol=1e-5, atol=1e-4)
    nch = raw.schedule.geometry.nchannels
    assert corrected.tables["REFDRIFT"].meta["side_channels"] == f"0 {nch - 1}"
