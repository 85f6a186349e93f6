"""The ``wiener`` reference strategy on small layouts and edge cases.

Every check is against an exact expectation: a flat prior removes any constant per
channel (and parity) whatever the noise model; with a white-only model the estimate of
every read is the mean of the channel's reference pixels (numpy); masked pixels change
nothing when the pixels they replace carry the same value.  The statistical tests
(posterior variance against Monte Carlo) are elsewhere.
"""

import contextlib
import importlib.resources
import io
import re
import warnings

import numpy as np
import pytest
from _cli_helpers import one_line_error, run
from _one_by_one import one_by_one
from astropy.io import fits
from astropy.io.fits.verify import VerifyWarning
from astropy.table import Table
from astropy.utils.exceptions import AstropyUserWarning

from spherex_reduce import (
    DetectorGeometry,
    Exposure,
    Pipeline,
    ReadoutSchedule,
    correct_reference,
    dq,
    read,
    unchop,
    write,
)
from spherex_reduce.core.errors import ConfigError
from spherex_reduce.reduce import executor
from spherex_reduce.reduce.steps.reference.strategies import NoReferenceError, NoReferenceWarning
from spherex_reduce.simulation import simulate_to_fits

NCH, NCOLS = 4, 32
WIDTH = NCOLS // NCH
CONSTS = np.array([100.0, -20.0, 3.5, 250.0])
NOISE_COLUMNS = ("name", "alpha", "beta", "gamma", "exponent", "scope", "visibility", "acn")
SCENE = {"geometry": {"nrows": 64, "ncols": NCOLS, "nchannels": NCH, "ref_border": 4},
         "readout": {"skip": 4, "ref_reads": 8, "nframes": 4, "phantom_reads": 2}}


def sched(ref_reads=8, ref_mode="distributed", phantom=0, nframes=3, border=4, scan="same",
          nrows=64):
    return ReadoutSchedule(DetectorGeometry(nrows, NCOLS, NCH, ref_border=border, scan=scan),
                           skip=4, ref_reads=ref_reads, ref_mode=ref_mode,
                           phantom_reads=phantom, nframes=nframes)


def spherex_table2_path():
    """The shipped Table 2 file, read here with astropy alone."""
    return importlib.resources.files("spherex_reduce") / "data" / "spherex-table2.ecsv"


def noise_table(path, *rows):
    """An ECSV noise table of ``rows`` (dicts; missing fields: zero, channel, pixels)."""
    base = {"alpha": 0.0, "beta": 0.0, "gamma": 0.0, "exponent": 1.3, "scope": "channel",
            "visibility": "pixels", "acn": False}
    Table(rows=[tuple({**base, **r}[c] for c in NOISE_COLUMNS) for r in rows],
          names=NOISE_COLUMNS).write(path, format="ascii.ecsv")
    return str(path)


@pytest.fixture
def white(tmp_path):
    """A noise model whose only component is white (alpha only)."""
    return noise_table(tmp_path / "white.ecsv", {"name": "w", "alpha": 2e-3})


def channel_values(s, per_channel, even_odd=None):
    """Per-column values ``(ncols,)``: a constant per channel (and per sample parity)."""
    g = s.geometry
    col = np.repeat(np.asarray(per_channel, float), g.channel_width)
    if even_odd is not None:
        even = g.column_offsets() % 2 == 0
        col = col + np.where(even, np.repeat(even_odd[0], g.channel_width),
                             np.repeat(even_odd[1], g.channel_width))
    return col


def reference_means(data, s, mask=None):
    """Mean of each channel's reference pixels per frame ``(L, nch)``, by numpy alone."""
    ref = np.array(data, float)[:, s.is_reference]
    if mask is not None:
        ref[np.asarray(mask)[:, s.is_reference] != 0] = np.nan
    ref = ref.reshape(ref.shape[0], ref.shape[1], NCH, WIDTH)
    return np.nanmean(ref, axis=(1, 3))


def per_channel(offsets):
    """REFOFFS offsets as ``(L, nch)`` (one parity)."""
    return np.asarray(offsets["offset"], float).reshape(-1, NCH)


# -- 1. registration and configuration ------------------------------------------------------
def test_pipeline_yaml_strategy_wiener_runs_and_show_config_prints_the_shipped(tmp_path,
                                                                                capsys):
    s = sched(phantom=2)
    raw = write(Exposure.from_arrays(np.zeros((3, s.n_reads, NCOLS)) + channel_values(s, CONSTS),
                                     s, phantom=np.zeros((3, s.n_reads, NCH))),
                tmp_path / "raw.fits")
    cfg = tmp_path / "p.yaml"
    cfg.write_text("steps:\n  - correct_reference: {strategy: wiener}\n")
    out = Pipeline.from_yaml(cfg).run(raw)
    assert out.header["REFSTRAT"] == "wiener" and out.header["S_REFCOR"] == "COMPLETE"
    np.testing.assert_allclose(out.data.data, 0.0, atol=1e-9)  # constants removed exactly
    capsys.readouterr()
    assert run("show-config", "wiener") == 0
    shown = capsys.readouterr().out
    for text in ("name: wiener", "strategy: wiener", "noise: spherex-table2", "domain: slopes",
                 "- unchop", "- fit_ramp", "- sigma_clip"):
        assert text in shown, shown


@pytest.mark.parametrize("params,words", [
    ("{strategy: wiener, noise: no-such-table}", ["no-such-table"]),
    ("{strategy: wiener, common: [nonexistent]}", ["nonexistent"]),
    ("{strategy: wiener, domain: bogus}", ["bogus"]),
    ("{strategy: wiener, regularization: -1}", ["regularization"]),
    ("{strategy: wiener, phantom: maybe}", ["maybe"]),
])
def test_bad_parameters_are_one_line_errors_exit_2(tmp_path, capsys, params, words):
    s = sched(phantom=2)
    raw = write(Exposure.from_arrays(np.zeros((3, s.n_reads, NCOLS)), s,
                                     phantom=np.zeros((3, s.n_reads, NCH))), tmp_path / "raw.fits")
    cfg = tmp_path / "bad.yaml"
    cfg.write_text(f"steps:\n  - correct_reference: {params}\n")
    out = tmp_path / "out.fits"
    capsys.readouterr()
    assert run("reduce", raw, "-c", cfg, "-o", out) == 2
    one_line_error(capsys, *words)
    assert not out.exists()


# -- 2. deterministic drifts ----------------------------------------------------------------
@pytest.mark.parametrize("layout", ["readout", "physical", "image"])
@pytest.mark.parametrize("domain", ["frames", "slopes"])
def test_white_only_model_estimates_every_read_as_the_reference_mean(white, layout, domain):
    """White noise only: every active read's estimate is the mean of the channel's reference
    pixels; a reference read's own value is an observation without error beyond its
    pixels' noise, which the target includes: its estimate is its own pixels' mean."""
    s = sched(phantom=0)
    rng = np.random.default_rng(1)
    nf = 1 if layout == "image" else 3
    data = rng.normal(0, 1, (nf, s.n_reads, NCOLS)) + channel_values(s, CONSTS)
    expected = reference_means(data, s)  # (nf, nch)
    per_read = np.repeat(expected[:, None, :], s.n_reads, axis=1)  # (nf, n_reads, nch)
    own = data.reshape(nf, s.n_reads, NCH, WIDTH).mean(axis=-1)
    per_read[:, s.is_reference] = own[:, s.is_reference]
    e = Exposure.from_arrays(data[0] if layout == "image" else data, s)
    src = unchop(e) if layout == "physical" else e
    out = correct_reference(src, "wiener", noise=white, domain=domain)
    assert out.tables["REFDRIFT"].meta["domain"] == domain
    # REFOFFS: the mean over the active reads, i.e. the reference mean
    np.testing.assert_allclose(per_channel(out.tables["REFOFFS"]), expected, rtol=0, atol=1e-10)
    drift = np.asarray(out.tables["REFDRIFT"]["drift"]).reshape(nf, NCH, s.n_reads)
    np.testing.assert_allclose(drift, per_read.transpose(0, 2, 1), rtol=1e-6)  # float32
    subtracted = (np.asarray(src.data.data, float) - out.data.data).reshape(nf, -1, NCOLS)
    if layout == "physical":  # every row is read once here: the offset of its read
        assert np.bincount(s.rows).max() == 1
        rows = np.zeros((nf, s.geometry.nrows, NCH))
        rows[:, s.rows] = per_read
        per_read = rows
    # (a reference read's own value to the regularisation, 1e-9 of the diagonal)
    np.testing.assert_allclose(subtracted, np.repeat(per_read, WIDTH, axis=2), rtol=1e-8)
    # the corrected reference pixels have zero mean per channel and frame
    corrected = (out.reference.data if layout == "physical" else
                 out.data.data.reshape(nf, s.n_reads, NCOLS)[:, s.is_reference])
    means = np.asarray(corrected, float).reshape(nf, -1, NCH, WIDTH).mean(axis=(1, 3))
    np.testing.assert_allclose(means, 0.0, atol=1e-8)


@pytest.mark.parametrize("domain", ["frames", "slopes"])
@pytest.mark.parametrize("phantom", [False, True])
def test_constant_per_channel_is_removed_exactly_under_the_paper_model(domain, phantom):
    """A flat prior: any constant per channel (in pixels, and in the phantom values, whose
    weights sum to zero) is removed exactly, whatever the PSDs."""
    s = sched(phantom=2)
    data = np.zeros((3, s.n_reads, NCOLS)) + channel_values(s, CONSTS)
    ph = np.zeros((3, s.n_reads, NCH)) + np.array([40.0, -7.0, 1.0, 0.0]) if phantom else None
    out = correct_reference(Exposure.from_arrays(data, s, phantom=ph), "wiener", domain=domain)
    assert out.header.get("REFPHANT", False) is phantom
    np.testing.assert_allclose(out.data.data, 0.0, atol=1e-9)
    np.testing.assert_allclose(per_channel(out.tables["REFOFFS"]), np.tile(CONSTS, (3, 1)),
                               rtol=1e-12)
    assert (out.tables["REFOFFS"]["flag"] == 0).all()


def test_domain_auto_is_frames_for_ramps_and_slopes_for_an_image():
    s = sched()
    ramps = Exposure.from_arrays(np.zeros((3, s.n_reads, NCOLS)) + channel_values(s, CONSTS), s)
    image = Exposure.from_arrays(np.zeros((s.n_reads, NCOLS)) + channel_values(s, CONSTS), s)
    for e, domain in ((ramps, "frames"), (image, "slopes")):
        out = correct_reference(e, "wiener")
        assert out.tables["REFDRIFT"].meta["domain"] == domain
        assert ("frame" in out.tables["REFDRIFT"].colnames) is (domain == "frames")
        np.testing.assert_allclose(out.data.data, 0.0, atol=1e-9)


def test_a_one_frame_image_is_corrected_in_the_frames_domain():
    s = sched(nframes=1)
    image = Exposure.from_arrays(np.zeros((s.n_reads, NCOLS)) + channel_values(s, CONSTS), s)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        out = correct_reference(image, "wiener")
    assert out.tables["REFDRIFT"].meta["domain"] == "frames"
    np.testing.assert_allclose(out.data.data, 0.0, atol=1e-9)


def test_domain_slopes_with_one_frame_is_a_config_error():
    s = sched(nframes=1)
    ramps = Exposure.from_arrays(np.zeros((1, s.n_reads, NCOLS)), s)
    with pytest.raises(ConfigError, match="slopes"):
        correct_reference(ramps, "wiener", domain="slopes")


@pytest.mark.parametrize("common", ["auto", "none", ["roic"], ["bias_correlated", "video8"]])
def test_common_components_are_recorded_and_constants_still_removed(common):
    table = Table.read(spherex_table2_path(), format="ascii.ecsv")
    if common == "auto":  # the components of scope common in the table
        expected = sorted(str(n) for n, sc in zip(table["name"], table["scope"], strict=True)
                          if sc == "common")
    else:
        expected = [] if common == "none" else sorted(common)
    s = sched(phantom=2)
    e = Exposure.from_arrays(np.zeros((3, s.n_reads, NCOLS)) + channel_values(s, CONSTS), s,
                             phantom=np.zeros((3, s.n_reads, NCH)) + 2.0)
    out = correct_reference(e, "wiener", common=common)
    assert out.tables["REFDRIFT"].meta["common"] == expected
    np.testing.assert_allclose(out.data.data, 0.0, atol=1e-9)


# -- 3. r = 0 and no reference rows ----------------------------------------------------------
def test_ref_mode_none_uses_the_border_rows_read_first_and_last(white):
    s = sched(ref_mode="none", ref_reads=0)
    assert s.is_reference[:4].all() and s.is_reference[-4:].all() and s.is_reference.sum() == 8
    rng = np.random.default_rng(2)
    data = rng.normal(0, 1, (3, s.n_reads, NCOLS)) + channel_values(s, CONSTS)
    border = np.concatenate([data[:, :4], data[:, -4:]], axis=1)
    expected = border.reshape(3, 8, NCH, WIDTH).mean(axis=(1, 3))
    for e in (Exposure.from_arrays(data, s), unchop(Exposure.from_arrays(data, s))):
        out = correct_reference(e, "wiener", noise=white)
        np.testing.assert_allclose(per_channel(out.tables["REFOFFS"]), expected, atol=1e-10)
    # the paper's model: the border rows remove the constants exactly
    const = Exposure.from_arrays(np.zeros_like(data) + channel_values(s, CONSTS), s)
    np.testing.assert_allclose(correct_reference(const, "wiener").data.data, 0, atol=1e-9)


def test_no_reference_rows_is_an_error_and_a_one_line_cli_error(tmp_path, capsys):
    g = DetectorGeometry(64, NCOLS, NCH, ref_border={"left": 4, "right": 4, "top": 0,
                                                     "bottom": 0})
    s = ReadoutSchedule(g, skip=4, ref_reads=0, ref_mode="none", phantom_reads=0, nframes=3)
    assert not s.is_reference.any()
    e = Exposure.from_arrays(np.ones((3, s.n_reads, NCOLS)), s)
    with pytest.raises(NoReferenceError, match="no reference rows"):
        correct_reference(e, "wiener")
    raw = write(e, tmp_path / "raw.fits")
    cfg = tmp_path / "w.yaml"
    cfg.write_text("steps:\n  - correct_reference: {strategy: wiener}\n")
    capsys.readouterr()
    assert run("reduce", raw, "-c", cfg, "-o", tmp_path / "out.fits") == 2
    one_line_error(capsys, "no reference rows")
    assert not (tmp_path / "out.fits").exists()


# -- 4. ACN ------------------------------------------------------------------------------------
@pytest.mark.parametrize("scan", ["same", "alternate"])
def test_acn_even_odd_constants_are_removed_on_both_parities(scan):
    s = sched(scan=scan, phantom=2)
    even, odd = np.array([0.5, -1.0, 2.0, 0.0]), np.array([-0.7, 3.0, 0.0, 1.5])
    col = channel_values(s, CONSTS, (even, odd))
    ph = np.zeros((3, s.n_reads, NCH)) + np.array([3.0, -1.0, 0.0, 8.0])  # per channel
    e = unchop(Exposure.from_arrays(np.zeros((3, s.n_reads, NCOLS)) + col, s, phantom=ph))
    out = correct_reference(e, "wiener", acn=True)
    assert out.header["REFPHANT"] is True
    np.testing.assert_allclose(out.data.data, 0.0, atol=1e-9)
    np.testing.assert_allclose(out.reference.data, 0.0, atol=1e-9)
    t = out.tables["REFOFFS"]
    assert len(t) == 3 * NCH * 2 and list(t["parity"][:2]) == [0, 1]
    offs = np.asarray(t["offset"]).reshape(3, NCH, 2)
    np.testing.assert_allclose(offs[..., 0], np.tile(CONSTS + even, (3, 1)), rtol=1e-12)
    np.testing.assert_allclose(offs[..., 1], np.tile(CONSTS + odd, (3, 1)), rtol=1e-12)
    drift = out.tables["REFDRIFT"]
    assert len(drift) == 3 * NCH * 2 and set(drift["parity"]) == {0, 1}
    # one offset per channel cannot: the parity difference stays
    mean_only = correct_reference(e, "wiener")
    diff = np.abs(mean_only.data.data).max()
    assert diff == pytest.approx(np.abs(even - odd).max() / 2, rel=1e-9)


def test_acn_white_model_gives_each_parity_its_reference_mean(white):
    s = sched(scan="alternate")
    rng = np.random.default_rng(3)
    data = rng.normal(0, 1, (3, s.n_reads, NCOLS))
    # a model without ACN: told that splitting the parities only adds noise between them
    with pytest.warns(AstropyUserWarning, match="no ACN component.*set acn: false"):
        out = correct_reference(Exposure.from_arrays(data, s), "wiener", noise=white, acn=True)
    ref = data[:, s.is_reference]
    parity = s.geometry.column_offsets() % 2
    offs = np.asarray(out.tables["REFOFFS"]["offset"]).reshape(3, NCH, 2)
    for ch in range(NCH):
        cols = np.arange(ch * WIDTH, (ch + 1) * WIDTH)
        for p in (0, 1):
            mine = cols[parity[cols] == p]
            np.testing.assert_allclose(offs[:, ch, p], ref[:, :, mine].mean(axis=(1, 2)),
                                       atol=1e-10)


# -- 5. masked reference pixels ------------------------------------------------------------
def _drifting_reference(s, rng):
    """Ramps whose reference pixels carry a per-read, per-channel value (the same in every
    pixel of a read and channel) and whose active pixels are noisy."""
    drift = (np.linspace(-1, 1, s.n_reads)[None, :, None] * np.array([1.0, 2.0, -0.5, 0.3])
             + CONSTS + rng.normal(0, 0.05, (3, s.n_reads, NCH)))
    data = np.repeat(drift, WIDTH, axis=2)
    active = ~s.is_reference
    data[:, active] += rng.normal(0, 1, (3, active.sum(), NCOLS))
    return data


def test_flagged_and_nan_reference_pixels_are_not_used():
    s = sched(ref_reads=8)
    rng = np.random.default_rng(4)
    clean = _drifting_reference(s, rng)
    refs = np.flatnonzero(s.is_reference)
    bad = clean.copy()
    mask = np.zeros(bad.shape, np.uint16)
    # flagged: huge values, and values within the spread that no clipping would drop
    for f, read_, col, value in [(0, refs[0], 1, 1e6), (0, refs[0], 2, 1e6),
                                 (1, refs[3], 9, 1e6), (2, refs[5], 30, 1e6),
                                 (0, refs[1], 3, 1.5), (1, refs[4], 12, -1.5),
                                 (2, refs[7], 17, 1.0), (2, refs[6], 25, 1.0)]:
        mask[f, read_, col] = dq.DO_NOT_USE
        bad[f, read_, col] += value
    bad[1, refs[2], 12] = np.nan  # not flagged, but unusable
    # the values of unusable pixels must not matter: the same flags on the clean values
    same = clean.copy()
    same[1, refs[2], 12] = np.nan
    a = correct_reference(Exposure.from_arrays(bad, s, mask=mask), "wiener")
    b = correct_reference(Exposure.from_arrays(same, s, mask=mask), "wiener")
    ta, tb = a.tables["REFOFFS"], b.tables["REFOFFS"]
    assert (ta["n_clipped"] == 0).all() and (tb["n_clipped"] == 0).all()
    np.testing.assert_allclose(per_channel(ta), per_channel(tb), rtol=1e-12)
    np.testing.assert_allclose(_drift(a), _drift(b), rtol=1e-6)
    active = ~s.is_reference
    np.testing.assert_allclose(a.data.data[:, active], b.data.data[:, active], rtol=0,
                               atol=1e-9)
    # n_used counts the usable pixels (numpy)
    usable = (mask == 0) & np.isfinite(bad)
    n_used = usable[:, s.is_reference].reshape(3, -1, NCH, WIDTH).sum(axis=(1, 3))
    np.testing.assert_array_equal(np.asarray(ta["n_used"]).reshape(3, NCH), n_used)


def test_masked_pixels_weigh_as_pixels_under_white_noise(white):
    """With white noise only, a read's weight follows its usable pixels: the estimate is the
    mean of all usable reference pixels of the channel (numpy), as for ``mean``."""
    s = sched(ref_reads=8)
    rng = np.random.default_rng(8)
    data = rng.normal(0, 1, (3, s.n_reads, NCOLS)) + rng.normal(0, 20, (3, 1, NCOLS))
    mask = np.zeros(data.shape, np.uint16)
    refs = np.flatnonzero(s.is_reference)
    mask[0, refs[1], 1:WIDTH] = dq.DO_NOT_USE      # channel 0 keeps 1 pixel of that read
    mask[2, refs[4], WIDTH + 2] = dq.DO_NOT_USE    # channel 1 loses one pixel
    out = correct_reference(Exposure.from_arrays(data, s, mask=mask), "wiener", noise=white,
                            sigma=1e9)
    vals = np.where(mask == 0, data, np.nan)[:, refs].reshape(3, -1, NCH, WIDTH)
    expected = np.nanmean(vals, axis=(1, 3))  # (frames, channels)
    np.testing.assert_allclose(np.asarray(out.tables["REFOFFS"]["offset"]).reshape(3, NCH),
                               expected, rtol=0, atol=1e-9)


def test_a_read_without_usable_pixels_in_one_channel_drops_out(white):
    s = sched(ref_reads=8)
    rng = np.random.default_rng(5)
    data = rng.normal(0, 1, (3, s.n_reads, NCOLS))
    mask = np.zeros(data.shape, np.uint16)
    mask[1, np.flatnonzero(s.is_reference)[2], WIDTH:2 * WIDTH] = dq.DO_NOT_USE  # channel 1
    data[mask != 0] += 2.0  # within the spread: only the flags keep them out
    out = correct_reference(Exposure.from_arrays(data, s, mask=mask), "wiener", noise=white)
    assert (out.tables["REFOFFS"]["n_clipped"] == 0).all()
    np.testing.assert_allclose(per_channel(out.tables["REFOFFS"]),
                               reference_means(data, s, mask), atol=1e-9)


def _all_flagged_channel():
    s = sched(ref_reads=8, phantom=2)
    rng = np.random.default_rng(6)
    data = rng.normal(0, 1, (3, s.n_reads, NCOLS)) + channel_values(s, CONSTS)
    mask = np.zeros(data.shape, np.uint16)
    mask[:, s.is_reference, WIDTH:2 * WIDTH] = dq.DO_NOT_USE  # every reference pixel of ch 1
    data[mask != 0] = 1e6
    return s, data, mask


@pytest.mark.filterwarnings("ignore:Mean of empty slice:RuntimeWarning")
def test_a_channel_without_usable_reference_pixels_is_flagged_and_left(white):
    s, data, mask = _all_flagged_channel()
    e = Exposure.from_arrays(data, s, mask=mask)
    with pytest.warns(NoReferenceWarning, match=r"channel\(s\) \[1\]"):
        out = correct_reference(e, "wiener", noise=white, phantom="ignore")
    t = out.tables["REFOFFS"]
    offs = per_channel(t)
    assert np.isnan(offs[:, 1]).all() and np.isfinite(offs[:, [0, 2, 3]]).all()
    flags = np.asarray(t["flag"]).reshape(3, NCH)
    assert (flags[:, 1] == dq.NO_REFERENCE).all() and (flags[:, [0, 2, 3]] == 0).all()
    ch1 = slice(WIDTH, 2 * WIDTH)
    assert (out.dq[:, :, ch1] & dq.NO_REFERENCE).all()
    assert not (out.dq[:, :, :WIDTH] & dq.NO_REFERENCE).any()
    np.testing.assert_array_equal(out.data.data[:, :, ch1], data[:, :, ch1])  # left alone
    expected = reference_means(data, s, mask)  # the other channels: their means (white)
    np.testing.assert_allclose(offs[:, [0, 2, 3]], expected[:, [0, 2, 3]], atol=1e-10)
    assert np.isnan(np.asarray(out.tables["REFDRIFT"]["drift"]).reshape(3, NCH, -1)[:, 1]).all()


def test_a_channel_without_reference_pixels_warns_only_no_reference(white):
    s, data, mask = _all_flagged_channel()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        correct_reference(Exposure.from_arrays(data, s, mask=mask), "wiener", noise=white)
    kinds = {type(w.message) for w in caught}
    assert kinds == {NoReferenceWarning}, [str(w.message) for w in caught]


# -- 6. streaming ------------------------------------------------------------------------------
def test_wiener_streamed_from_a_file_equals_in_memory_and_one_by_one(tmp_path, monkeypatch):
    monkeypatch.setattr(executor, "BAND_PIXELS", 5 * NCOLS)  # bands of 5 rows of a file
    path = simulate_to_fits(SCENE, tmp_path / "raw.fits", mode="ramps", seed=11)
    pipe = Pipeline.from_yaml("wiener")
    streamed = pipe.run(path)
    route = str(streamed.tables["PROVENANCE"]["route"][1])
    assert "from a file" in route and " 1 band" not in route, route
    memory = pipe.run(read(path))
    np.testing.assert_array_equal(streamed.data.data, memory.data.data)
    np.testing.assert_array_equal(streamed.tables["REFDRIFT"]["drift"],
                                  memory.tables["REFDRIFT"]["drift"])
    steps = one_by_one(pipe, path)
    for name in ("S_UNCHOP", "S_REFCOR", "S_RAMPFT", "S_SIGCLP"):
        assert steps.header[name] == streamed.header[name] == "COMPLETE"
    np.testing.assert_array_equal(steps.data.data, streamed.data.data)
    np.testing.assert_array_equal(steps.tables["REFOFFS"]["offset"],
                                  streamed.tables["REFOFFS"]["offset"])
    assert streamed.header["REFPHANT"] is True and steps.header["REFPHANT"] is True


# -- 7. phantom consumption ----------------------------------------------------------------
def _with_phantom(seed=7, ref_reads=8):
    s = sched(phantom=2, ref_reads=ref_reads)
    rng = np.random.default_rng(seed)
    data = rng.normal(0, 1, (3, s.n_reads, NCOLS)) + channel_values(s, CONSTS)
    ph = rng.normal(0, 1, (3, s.n_reads, NCH))
    return s, data, ph


def _drift(out):
    return np.asarray(out.tables["REFDRIFT"]["drift"], float)


def test_phantom_auto_is_consumed_and_a_later_subtract_phantom_skipped():
    s, data, ph = _with_phantom()
    e = Exposure.from_arrays(data, s, phantom=ph)
    out = Pipeline({"steps": [{"correct_reference": {"strategy": "wiener", "domain": "frames"}},
                              "subtract_phantom"]}).run(e)
    assert out.header["REFPHANT"] is True and out.tables["REFDRIFT"].meta["phantom_used"]
    assert out.header["S_PHANTM"] == "SKIPPED" and out.phantom is None
    alone = correct_reference(e, "wiener", domain="frames")
    np.testing.assert_array_equal(out.data.data, alone.data.data)
    # used: a per-channel constant in the phantom values changes nothing (their weights sum
    # to 0), a per-read change does
    shift = np.array([5.0, -3, 0, 9])
    shifted = correct_reference(Exposure.from_arrays(data, s, phantom=ph + shift), "wiener",
                                domain="frames")
    np.testing.assert_allclose(shifted.data.data, alone.data.data, rtol=0, atol=1e-8)
    other = correct_reference(Exposure.from_arrays(data, s, phantom=ph[:, ::-1]), "wiener",
                              domain="frames")
    assert np.abs(_drift(other) - _drift(alone)).max() > 1e-3


def test_phantom_ignore_does_not_use_them_and_subtract_phantom_still_runs():
    s, data, ph = _with_phantom()
    e = Exposure.from_arrays(data, s, phantom=ph)
    params = {"strategy": "wiener", "domain": "frames", "phantom": "ignore"}
    out = Pipeline({"steps": [{"correct_reference": params}, "subtract_phantom"]}).run(e)
    assert "REFPHANT" not in out.header and not out.tables["REFDRIFT"].meta["phantom_used"]
    assert out.header["S_PHANTM"] == "COMPLETE"
    alone = correct_reference(e, **params)
    expected = alone.data.data - np.repeat(ph, WIDTH, axis=2)  # then the phantom subtracted
    np.testing.assert_allclose(out.data.data, expected, rtol=0, atol=1e-12)
    other = correct_reference(Exposure.from_arrays(data, s, phantom=ph[:, ::-1] * 7), **params)
    np.testing.assert_array_equal(_drift(other), _drift(alone))  # the values are not used


def test_readout_and_physical_order_give_the_same_estimate():
    s, data, ph = _with_phantom(ref_reads=12)  # 12 reads of 8 reference rows: some twice
    twice = np.flatnonzero(np.bincount(s.rows, minlength=s.geometry.nrows) > 1)
    assert twice.size
    e = Exposure.from_arrays(data, s, phantom=ph)
    a = correct_reference(e, "wiener")
    b = correct_reference(unchop(e), "wiener")
    assert a.header["REFPHANT"] is True and b.header["REFPHANT"] is True
    np.testing.assert_allclose(_drift(b), _drift(a), rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(per_channel(b.tables["REFOFFS"]),
                               per_channel(a.tables["REFOFFS"]), rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(b.data.data, unchop(a).data.data, rtol=0, atol=1e-10)
    # a row read twice: the mean of its reads minus the mean of their offsets (numpy)
    drift = np.asarray(a.data.data, float) - data  # minus the offset of every read
    for row in twice:
        reads = np.flatnonzero(s.rows == row)
        expected = (data[:, reads] + drift[:, reads]).mean(axis=1)
        np.testing.assert_allclose(b.data.data[:, row], expected, rtol=0, atol=1e-10)


# -- 8. the reduced file -------------------------------------------------------------------
@pytest.mark.filterwarnings("ignore::astropy.io.fits.verify.VerifyWarning")
def test_reduced_file_has_the_refdrift_table_of_the_in_memory_run(tmp_path, capsys):
    path = simulate_to_fits(SCENE, tmp_path / "raw.fits", mode="ramps", seed=12)
    out = tmp_path / "out.fits"
    assert run("reduce", path, "-c", "wiener", "-o", out) == 0
    memory = Pipeline.from_yaml("wiener").run(read(path))
    n_reads = memory.schedule.n_reads
    with fits.open(out) as hdul:
        assert hdul[0].header["REFSTRAT"] == "wiener"
        assert hdul["REFOFFS"].header["STRATEGY"] == "wiener"
        drift = hdul["REFDRIFT"].data
        assert drift["drift"].shape == (4 * NCH, n_reads)
        np.testing.assert_array_equal(drift["drift"], memory.tables["REFDRIFT"]["drift"])
        np.testing.assert_array_equal(drift["frame"], np.repeat(np.arange(4), NCH))
        np.testing.assert_array_equal(drift["channel"], np.tile(np.arange(NCH), 4))
        np.testing.assert_array_equal(hdul["REFOFFS"].data["offset"],
                                      memory.tables["REFOFFS"]["offset"])
        np.testing.assert_array_equal(hdul["SCI"].data, memory.data.data.astype(np.float32))
    # REFOFFS's offset is the mean of the drift over the active reads
    active = memory.schedule.active_read_indices
    np.testing.assert_allclose(np.asarray(memory.tables["REFOFFS"]["offset"]),
                               np.asarray(memory.tables["REFDRIFT"]["drift"], float)[:, active]
                               .mean(axis=1), rtol=1e-5, atol=1e-5)


def test_writing_a_wiener_result_warns_nothing(tmp_path):
    s, data, ph = _with_phantom()
    out = correct_reference(Exposure.from_arrays(data, s, phantom=ph), "wiener")
    with warnings.catch_warnings():
        warnings.simplefilter("error", VerifyWarning)
        write(out, tmp_path / "w.fits")
    back = Table.read(tmp_path / "w.fits", hdu="REFDRIFT")  # (a readout-order ramp whose
    # phantom is consumed does not read back whole: NPHANT without PHANTOM, as after
    # subtract_phantom)
    np.testing.assert_array_equal(back["drift"], out.tables["REFDRIFT"]["drift"])
    assert back.meta["phantom_used"] is True


# -- 9. the noise parameter ---------------------------------------------------------------
def _fit_noise_result(tmp_path):
    """``spherex-reduce fit-noise`` of a small raw file, its fitted coefficients kept >= 0
    (a small file's fit can put one below zero, which no noise model accepts)."""
    raw = simulate_to_fits(SCENE, tmp_path / "fitraw.fits", mode="ramps", seed=3)
    out = tmp_path / "fit.ecsv"
    with contextlib.redirect_stdout(io.StringIO()):
        assert run("fit-noise", raw, "-o", out) == 0
    t = Table.read(out)
    assert list(t["stream"]) == ["reference", "phantom"]
    for name in ("alpha", "beta", "gamma"):
        t[name] = np.maximum(t[name], 0.0)
    t.write(out, format="ascii.ecsv", overwrite=True)
    return str(out)


def test_a_fit_noise_result_as_written_gives_finite_estimates(tmp_path):
    raw = simulate_to_fits(SCENE, tmp_path / "fitraw.fits", mode="ramps", seed=3)
    fit = tmp_path / "fit.ecsv"
    with contextlib.redirect_stdout(io.StringIO()):
        assert run("fit-noise", raw, "-o", fit) == 0
    s, data, ph = _with_phantom()
    out = correct_reference(Exposure.from_arrays(data, s, phantom=ph), "wiener", noise=str(fit))
    assert np.isfinite(_drift(out)).all()
    const = Exposure.from_arrays(np.zeros_like(data) + channel_values(s, CONSTS), s)
    np.testing.assert_allclose(correct_reference(const, "wiener", noise=str(fit)).data.data, 0,
                               atol=1e-9)


@pytest.mark.parametrize("kind", ["builtin", "table", "fit-noise", "scene"])
def test_noise_sources_give_finite_estimates(tmp_path, kind):
    if kind == "builtin":
        source = "spherex-table2"
    elif kind == "table":
        source = noise_table(tmp_path / "t.ecsv", {"name": "w", "alpha": 2e-3, "beta": 1e-2},
                             {"name": "b", "beta": 1e-4, "scope": "common",
                              "visibility": "both"})
    elif kind == "fit-noise":
        source = _fit_noise_result(tmp_path)
    else:
        (tmp_path / "scene.yaml").write_text(
            "noise:\n  components: [roic, {name: extra, beta: 1.0e-3, visibility: both}]\n")
        source = str(tmp_path / "scene.yaml")
    s, data, ph = _with_phantom()
    out = correct_reference(Exposure.from_arrays(data, s, phantom=ph), "wiener", noise=source)
    assert np.isfinite(_drift(out)).all() and np.isfinite(out.data.data).all()
    assert out.tables["REFDRIFT"].meta["noise"] == source
    # whatever the model, the flat prior: a constant per channel is removed exactly
    const = Exposure.from_arrays(np.zeros_like(data) + channel_values(s, CONSTS), s,
                                 phantom=np.zeros_like(ph) + 4.0)
    np.testing.assert_allclose(correct_reference(const, "wiener", noise=source).data.data, 0,
                               atol=1e-9)


def test_white_scene_and_white_fit_noise_models_give_the_mean(tmp_path):
    s = sched(phantom=2)
    rng = np.random.default_rng(8)
    data = rng.normal(0, 1, (3, s.n_reads, NCOLS))
    e = Exposure.from_arrays(data, s, phantom=rng.normal(0, 1, (3, s.n_reads, NCH)))
    scene = tmp_path / "white.yaml"
    scene.write_text("noise:\n  components: [{name: w, alpha: 1.0e-3}]\n")
    fit = tmp_path / "fitwhite.ecsv"
    Table({"stream": ["reference", "phantom"], "alpha": [1e-3, 1e-4], "beta": [0.0, 0.0],
           "gamma": [0.0, 0.0], "exponent": [1.3, 1.3]}).write(fit, format="ascii.ecsv")
    for source in (scene, fit):
        out = correct_reference(e, "wiener", noise=str(source))
        np.testing.assert_allclose(per_channel(out.tables["REFOFFS"]), reference_means(data, s),
                                   atol=1e-9)


@pytest.mark.parametrize(("gamma", "err", "used"), [(-2.0, 1.0, 0.0), (-3.5, 1.0, None),
                                                    (-1e-9, 0.0, None), (2.5, 0.0, 2.5)])
def test_a_fitted_coefficient_below_zero_is_zero_within_three_sigma(tmp_path, gamma, err,
                                                                     used):
    """A fit-noise coefficient below zero by at most 3 standard errors is used as 0 (the
    estimate is that of the table with 0); further below it is refused, naming it."""
    def table(path, value, error):
        Table({"stream": ["reference", "phantom"], "alpha": [1e-3, 1e-4], "beta": [1e-2, 0.0],
               "gamma": [value, 0.0], "gamma_err": [error, 0.0], "exponent": [1.3, 1.3]}
              ).write(path, format="ascii.ecsv")
        return str(path)

    s, data, ph = _with_phantom()
    e = Exposure.from_arrays(data, s, phantom=ph)
    source = table(tmp_path / "fit.ecsv", gamma, err)
    if used is None:
        with pytest.raises(ConfigError, match=rf"reference gamma = {gamma:g} ± {err:g} is "
                                              r"below zero by more than 3 standard errors"):
            correct_reference(e, "wiener", noise=source)
        return
    same = table(tmp_path / "same.ecsv", used, 0.0)
    np.testing.assert_array_equal(correct_reference(e, "wiener", noise=source).data.data,
                                  correct_reference(e, "wiener", noise=same).data.data)


@pytest.mark.parametrize(("streams", "words"), [
    (["reference", "phantom", "roic"], "row 2: stream 'roic' is not a stream fit-noise writes"),
    (["Reference", "phantom"], "row 0: stream 'Reference' is not a stream fit-noise writes"),
    (["reference", "reference"], "row 1: stream 'reference' twice"),
])
def test_a_fit_noise_row_of_another_stream_is_refused_naming_it(tmp_path, streams, words):
    """Such a row was left out of the model without a word (a misspelt ``reference`` left
    the phantom stream alone); a stream twice would count its noise twice."""
    n = len(streams)
    path = tmp_path / "fit.ecsv"
    Table({"stream": streams, "alpha": [1e-3] * n, "beta": [1e-2] * n, "gamma": [0.0] * n,
           "exponent": [1.3] * n}).write(path, format="ascii.ecsv")
    s, data, ph = _with_phantom()
    with pytest.raises(ConfigError, match=re.escape(f"correct_reference.noise: {path}: {words}")):
        correct_reference(Exposure.from_arrays(data, s, phantom=ph), "wiener", noise=str(path))


@pytest.mark.parametrize("text", ["steps:\n  - unchop: {}\n", "colour: blue\n"])
def test_a_yaml_without_a_noise_section_is_refused(tmp_path, text):
    """A pipeline (or any other) YAML is not a noise model: not the paper's Table 2."""
    (tmp_path / "p.yaml").write_text(text)
    s, data, ph = _with_phantom()
    with pytest.raises(ConfigError, match=r"correct_reference\.noise: .*p\.yaml has no noise: "
                                          "section"):
        correct_reference(Exposure.from_arrays(data, s, phantom=ph), "wiener",
                          noise=str(tmp_path / "p.yaml"))


def test_the_memory_of_the_solve_is_checked_before_it_starts(monkeypatch):
    """The estimate the memory check uses is at least what the solve allocates (traced by
    tracemalloc, which sees numpy's arrays), and at most twice; a budget below it is
    refused before anything is allocated."""
    import tracemalloc

    from spherex_reduce.core import limits
    from spherex_reduce.core.errors import ResourceError
    from spherex_reduce.reduce.steps.reference import wiener

    def tall(nrows):  # one channel read by a tall array: the solve dominates
        s = ReadoutSchedule(DetectorGeometry(nrows, 8, 1, ref_border=1), skip=1, ref_reads=4,
                            phantom_reads=1, nframes=2)
        rng = np.random.default_rng(1)
        return s, Exposure.from_arrays(rng.normal(0, 1, (2, s.n_reads, 8)), s,
                                       phantom=rng.normal(0, 1, (2, s.n_reads, 1)))

    correct_reference(tall(64)[1], "wiener")  # the caches of the first call: not the solve's
    s, e = tall(512)
    wiener._MODELS.clear()
    tracemalloc.start()
    try:
        correct_reference(e, "wiener")
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    need = next(iter(wiener._MODELS.values())).nbytes(s.reference_read_indices.size, True)
    assert peak <= need <= 2 * peak, (need, peak)
    wiener._MODELS.clear()
    monkeypatch.setattr(limits, "memory_budget", lambda: int(need / 2))
    with pytest.raises(ResourceError, match=r"correct_reference \(wiener\): the kriging solve "
                                            r"of 514 reads .* needs 17.2 MB of memory"):
        correct_reference(e, "wiener")
    wiener._MODELS.clear()


@pytest.mark.parametrize("name", ["raw.fits", "missing.ecsv"])
def test_a_fits_or_missing_noise_file_is_a_one_line_config_error(tmp_path, capsys, name):
    s = sched()
    raw = write(Exposure.from_arrays(np.zeros((3, s.n_reads, NCOLS)), s), tmp_path / "raw.fits")
    source = tmp_path / name
    with pytest.raises(ConfigError, match=r"correct_reference\.noise") as err:
        correct_reference(read(raw), "wiener", noise=str(source))
    assert "\n" not in str(err.value)
    cfg = tmp_path / "w.yaml"
    cfg.write_text(f"steps:\n  - correct_reference: {{strategy: wiener, noise: '{source}'}}\n")
    capsys.readouterr()
    assert run("reduce", raw, "-c", cfg, "-o", tmp_path / "out.fits") == 2
    one_line_error(capsys, "correct_reference.noise", name)


def test_a_frame_with_a_non_finite_phantom_value_uses_its_reference_reads_alone():
    """One NaN phantom value: that frame is estimated as with ``phantom: ignore`` (a
    warning says so), the other frames with their phantom values; nothing is NaN."""
    s = sched(ref_reads=8, phantom=2)
    rng = np.random.default_rng(11)
    data = rng.normal(0, 1, (3, s.n_reads, NCOLS)) + 5.0
    ph = rng.normal(0, 1, (3, s.n_reads, NCH))
    ph_bad = ph.copy()
    ph_bad[1, 10, 2] = np.nan
    with pytest.warns(AstropyUserWarning, match="1 frame"):
        out = correct_reference(Exposure.from_arrays(data, s, phantom=ph_bad), "wiener")
    used = correct_reference(Exposure.from_arrays(data, s, phantom=ph), "wiener")
    ignored = correct_reference(Exposure.from_arrays(data, s, phantom=ph), "wiener",
                                phantom="ignore")
    assert np.isfinite(out.data.data).all()
    np.testing.assert_allclose(out.data.data[[0, 2]], used.data.data[[0, 2]], rtol=0,
                               atol=1e-12)
    np.testing.assert_allclose(out.data.data[1], ignored.data.data[1], rtol=0, atol=1e-12)


def _count_solves(monkeypatch):
    """A list that grows by one at every kriging system solved (`Kriging` made)."""
    from spherex_reduce.reduce.steps.reference import drift_model

    solved = []
    real = drift_model.Kriging

    class Counting(real):
        def __init__(self, *args, **kwargs):
            solved.append(1)
            super().__init__(*args, **kwargs)

    monkeypatch.setattr(drift_model, "Kriging", Counting)
    return solved


def _phantom_exposure(seed):
    """Three frames of white noise with 8 reference reads and 2 phantom reads per frame."""
    s = sched(ref_reads=8, phantom=2)
    return Exposure.from_arrays(np.random.default_rng(seed).normal(0, 1, (3, s.n_reads, NCOLS)),
                                s, phantom=np.zeros((3, s.n_reads, NCH)))


def test_threads_asking_for_one_model_solve_it_once(monkeypatch):
    """Bands or dask threads asking at once: each system is solved once."""
    import threading

    from spherex_reduce.reduce.steps.reference import wiener as wmod

    solved = _count_solves(monkeypatch)
    wmod._MODELS.clear()
    e = _phantom_exposure(2)
    outs = [None] * 4

    def run(i):
        outs[i] = correct_reference(e, "wiener").data.data

    threads = [threading.Thread(target=run, args=(i,)) for i in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert len(solved) == 2  # the channel deviations and the channel mean, once each
    for o in outs[1:]:
        np.testing.assert_array_equal(o, outs[0])
    wmod._MODELS.clear()


def _fit_noise_table(path, unit):
    """A fit-noise result (ECSV) of data in ``unit``: a white reference stream."""
    from astropy import units as u

    t = Table({"stream": ["reference"], "alpha": [2e-3], "alpha_err": [1e-5], "beta": [0.0],
               "beta_err": [1e-5], "gamma": [0.0], "gamma_err": [1e-5], "exponent": [1.3]})
    for name in ("alpha", "alpha_err"):
        t[name].unit = unit**2 / u.Hz
    t.write(path, format="ascii.ecsv")
    return str(path)


def test_a_noise_model_in_another_unit_than_the_data_is_refused(tmp_path):
    """A fit-noise result in electrons on ADU data (no gain): the predictions were labelled
    electrons; now refused.  The same model on data in its unit is used."""
    from astropy import units as u

    s = sched()
    data = np.zeros((3, s.n_reads, NCOLS)) + channel_values(s, CONSTS)
    adu = Exposure.from_arrays(data, s, unit=u.adu)
    in_electrons = _fit_noise_table(tmp_path / "e.ecsv", u.electron)
    with pytest.raises(ConfigError, match=r"noise model .*e\.ecsv is in electron, the data "
                                          r"in adu"):
        correct_reference(adu, "wiener", noise=in_electrons)
    in_adu = _fit_noise_table(tmp_path / "a.ecsv", u.adu)
    out = correct_reference(adu, "wiener", noise=in_adu)
    np.testing.assert_allclose(out.data.data, 0.0, atol=1e-9)  # channel constants removed


@pytest.mark.parametrize("what", ["adu", "200 kHz"])
def test_the_paper_model_is_used_on_other_data_only_when_named(what):
    """With no noise: given, wiener applied Table 2 (electrons at 100 kHz) to any data."""
    from astropy import units as u

    s = sched()
    unit = u.electron
    if what == "adu":
        unit = u.adu
    else:
        g = s.geometry
        s = ReadoutSchedule(DetectorGeometry(g.nrows, g.ncols, g.nchannels, ref_border=4,
                                             pixel_rate=2e5), skip=4, ref_reads=8,
                            ref_mode="distributed", phantom_reads=0, nframes=3)
    data = np.zeros((3, s.n_reads, NCOLS)) + channel_values(s, CONSTS)
    e = Exposure.from_arrays(data, s, unit=unit)
    with pytest.raises(ConfigError, match=r"the default noise model .* does not describe"):
        correct_reference(e, "wiener")
    if what == "200 kHz":  # named: the user's choice
        out = correct_reference(e, "wiener", noise="spherex-table2")
        np.testing.assert_allclose(out.data.data, 0.0, atol=1e-9)


def test_a_scene_in_adu_is_a_noise_model_of_adu_data_and_with_its_gain_of_electrons(tmp_path):
    """A scene (characterize's MODEL.yaml) with ``unit: adu`` describes ADU data (it was
    taken as electrons and refused); with its gain g it describes data in electrons too,
    its coefficients times g² (numpy below); without a gain, electrons are refused."""
    import yaml
    from astropy import units as u

    from spherex_reduce.reduce.steps.reference.wiener import WienerReference

    s = sched()
    data = np.zeros((3, s.n_reads, NCOLS)) + channel_values(s, CONSTS)
    comps = [{"name": "w", "alpha": 2e-3, "beta": 1e-4}]
    path = tmp_path / "model.yaml"
    path.write_text(yaml.safe_dump({"unit": "adu", "gain": 2.0,
                                    "noise": {"components": comps}}))
    adu = Exposure.from_arrays(data, s, unit=u.adu)
    out = correct_reference(adu, "wiener", noise=str(path))
    np.testing.assert_allclose(out.data.data, 0.0, atol=1e-9)  # channel constants removed
    electrons = Exposure.from_arrays(data * 2.0, s, unit=u.electron)
    out = correct_reference(electrons, "wiener", noise=str(path))
    np.testing.assert_allclose(out.data.data, 0.0, atol=1e-9)
    step = WienerReference(noise=str(path))
    step.check_data(type("Context", (), {"unit": "electron", "schedule": s})())
    (c,) = step.components
    assert (c.alpha, c.beta, step.model_unit) == (2e-3 * 4, 1e-4 * 4, u.electron)
    path.write_text(yaml.safe_dump({"unit": "adu", "noise": {"components": comps}}))
    with pytest.raises(ConfigError, match=r"noise model .*model\.yaml is in adu, the data "
                                          r"in electron"):
        correct_reference(electrons, "wiener", noise=str(path))


def test_several_wiener_configurations_in_one_process_keep_their_solves(monkeypatch):
    """Six models used in turn (the peers' benchmark, compare-strategies) are kept within
    the models' byte budget: a second round solves nothing (four were kept by count, so
    every exposure solved them all again); beyond the budget the oldest are let go."""
    from spherex_reduce.reduce.steps.reference import wiener as wmod

    solved = _count_solves(monkeypatch)
    e = _phantom_exposure(3)
    configs = [{"strategy": "wiener", "regularization": r}
               for r in (1e-9, 2e-9, 3e-9, 4e-9, 5e-9, 6e-9)]
    wmod._MODELS.clear()
    try:
        for cfg in configs:
            correct_reference(e, **cfg)
        first = len(solved)
        for cfg in configs:  # the second round: no solve
            correct_reference(e, **cfg)
        assert first > 0 and len(solved) == first
        # a budget below one model's bytes keeps only the newest: every config solves again
        monkeypatch.setattr(wmod, "_MODEL_BYTES", 1)
        before = len(solved)
        for cfg in configs[:2]:
            correct_reference(e, **cfg)
        assert len(solved) > before
        assert len(wmod._MODELS) == 1
    finally:
        wmod._MODELS.clear()
