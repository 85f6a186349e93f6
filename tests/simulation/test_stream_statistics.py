"""Statistics of simulated streams, ramps and slopes against independent expectations.

Ensemble sizes: an estimate of a variance from ``n`` independent Gaussian
values has the relative standard error ``sqrt(2 / n)``.  Where the ensemble
makes ``4 sigma <= 2 %`` the tests use the 2 % tolerance of the issue;
elsewhere (long exposures, whose slow noise makes every pixel of a channel
share one value) the tolerance is ``4 sigma`` of the estimator, stated per
test.  The bias of the simulator itself is tested without Monte Carlo noise in
``test_engine_expectation.py::test_simulator_expectation_matches_analytic`` (2 %).
"""

import itertools

import numpy as np
import pytest
import scipy.fft as sfft

from spherex_reduce import ReadoutSchedule, expected_slope_variance, simulate
from spherex_reduce.core.geometry import DetectorGeometry
from spherex_reduce.io.config import schedule_from_config
from spherex_reduce.simulation import (
    NoiseComponent,
    NoiseEngine,
    ls_weights,
    noise_components,
    synthesis,
)

TABLE = noise_components()


def _fit(frames, schedule):
    w = ls_weights(np.arange(schedule.nframes) * schedule.frame_time.value)
    return np.tensordot(w, np.asarray(frames, dtype=float), 1)


def _many_channels(n, nchannels=512, width=2, overhead=200):
    return schedule_from_config(
        {"nrows": 4, "ncols": nchannels * width, "nchannels": nchannels, "ref_border": 0},
        {"skip": 1, "ref_reads": 0, "phantom_reads": 0, "row_overhead": 0,
         "frame_overhead": overhead, "nframes": n})


# -- periodogram of synthesised streams ------------------------------------------------
def _expected_hann_periodogram(comps, L, fs):
    """E[one-sided Hann periodogram] from the structure function (exact, aperiodic)."""
    win = np.hanning(L)
    rw = sfft.irfft(np.abs(sfft.rfft(win, 2 * L)) ** 2, 2 * L)[:L]  # window autocorrelation
    lag = np.arange(L)
    d = sum(c.structure_function(lag, fs) for c in comps)
    g = np.zeros(2 * L)
    g[:L] = -0.5 * d * rw  # covariance up to a constant, which Hann removes for k >= 2
    g[L + 1:] = g[1:L][::-1]
    spec = sfft.rfft(g).real[::2]  # frequencies k / L
    return 2 * spec / (fs * np.sum(win**2))


@pytest.mark.parametrize("comp", [TABLE["video8"], TABLE["roic"], TABLE["bias_correlated"],
                                  TABLE["bias_pixels_only"],
                                  NoiseComponent("alpha_only", alpha=2e-3),
                                  NoiseComponent("beta_only", beta=8.4e-3),
                                  NoiseComponent("gamma_only", gamma=0.1)])
def test_stream_periodogram_matches_psd(comp):
    """Contiguous samples (no overheads, 1-row reads back to back) give each channel's stream.

    Per log-frequency bin (8 per decade above the 8th frequency) the ensemble
    periodogram must be within 2 % of the exact expectation, or within 4
    standard errors of the bin where that is larger (the lowest bins hold few
    frequencies).
    """
    comp = comp.replace(scope="channel", visibility="pixels", acn=False)
    nch, width, n = 64, 64, 16
    s = schedule_from_config(
        {"nrows": 16, "ncols": nch * width, "nchannels": nch, "ref_border": 0},
        {"skip": 1, "ref_reads": 0, "phantom_reads": 0, "row_overhead": 0,
         "frame_overhead": 0, "nframes": n})
    L = s.frame_samples * n
    fs = s.geometry.pixel_rate
    win = np.hanning(L)
    acc = np.zeros(L // 2 + 1)
    nreal = 4
    for seed in range(nreal):
        frames = np.array([f for f, _ in NoiseEngine(s, [comp], seed).frames()])
        x = frames.reshape(n, s.n_reads, nch, width).transpose(2, 0, 1, 3).reshape(nch, L)
        x = x.astype(float) - x.mean(axis=1, keepdims=True)
        acc += np.sum(np.abs(sfft.rfft(x * win, axis=1)) ** 2, axis=0)
    per = 2 * acc / (fs * np.sum(win**2) * nch * nreal)
    expect = _expected_hann_periodogram([comp], L, fs)
    k = np.arange(per.size)
    edges = np.unique(np.geomspace(8, L // 2, int(8 * np.log10(L / 16)) + 1).astype(int))
    for lo, hi in itertools.pairwise(edges):
        sel = (k >= lo) & (k < hi)
        ratio = per[sel].sum() / expect[sel].sum()
        # Hann bins are correlated in pairs: ~ half as many independent values
        sigma = np.sqrt(2.0 / (sel.sum() * nch * nreal))
        tol = max(0.02, 4 * sigma)
        assert abs(ratio - 1) < tol, (lo, hi, ratio, tol)


# -- per-pixel slope variance, both modes ---------------------------------------------------
@pytest.mark.parametrize("comp, nreal", [(NoiseComponent("alpha_only", alpha=2e-3), 6),
                                         (NoiseComponent("beta_only", beta=8.4e-3, acn=True), 40),
                                         (NoiseComponent("gamma_only", gamma=0.1, acn=True), 40)])
@pytest.mark.parametrize("mode", ["ramps", "slopes", "slopes-tiered"])
def test_slope_variance_n10_within_2_percent(comp, nreal, mode):
    """N = 10, 1024 channels with even/odd realisations: 2048 independent streams.

    40 realisations: 81920 values, sigma = 0.49 %, 2 % = 4 sigma.  White noise:
    every pixel is independent (6 x 8192 values, sigma = 0.57 %).  Slope mode
    takes the exact route for this small scene; ``slopes-tiered`` forces the
    synthesised tiers that large scenes use.
    """
    s = _many_channels(10, nchannels=1024)
    ana = expected_slope_variance(comp, s).value
    vals = []
    route = "tiered" if mode == "slopes-tiered" else None
    for seed in range(nreal):
        eng = NoiseEngine(s, [comp], seed, slope_route=route)
        img = _fit([f for f, _ in eng.frames()], s) if mode == "ramps" else eng.slopes()[0]
        img = np.asarray(img, dtype=float)
        vals.append(img if comp.alpha else img[1])  # slow noise: one read per stream
    v = np.array(vals)
    assert np.mean(v**2) / ana == pytest.approx(1, abs=0.02)


@pytest.mark.parametrize("n, nreal", [(2, 12), (74, 4), (386, 2)])
def test_slope_variance_other_n_both_modes(n, nreal):
    """N = 2, 74, 386 for the Table 2 terms seen by pixels, ramps and slopes.

    The common bias terms are run with channel scope here (same synthesis,
    but one stream per channel gives an ensemble).  Tolerance: 4 standard
    errors of the estimator, ``4 sqrt(2 / n_streams)``; the bias itself is
    tested to 2 % in ``test_engine_expectation.py``.
    """
    s = _many_channels(n, nchannels=256 if n < 386 else 64)
    nch = s.geometry.nchannels
    comps = [TABLE["video8"], TABLE["roic"],
             TABLE["bias_correlated"].replace(scope="channel", acn=True),
             TABLE["bias_pixels_only"].replace(scope="channel", acn=True)]
    for comp in comps:
        ana = expected_slope_variance(comp, s).value
        ramps, slopes = [], []
        for seed in range(nreal):
            eng = NoiseEngine(s, [comp], seed)
            ramps.append(_fit([f for f, _ in eng.frames()], s)[1])
            slopes.append(np.asarray(NoiseEngine(s, [comp], 1000 + seed).slopes()[0][1], float))
        tol = 4 * np.sqrt(2 / (nreal * 2 * nch))
        for name, v in (("ramps", ramps), ("slopes", slopes)):
            ratio = np.mean(np.square(v)) / ana
            assert abs(ratio - 1) < tol, (comp.name, name, ratio, tol)


def test_slopes_mode_equals_fit_of_ramps_for_slow_noise():
    """Same seed: slow tiers are the same streams, so only the fast tier differs.

    The tiered route of slope mode (a scene this small takes the exact route by
    default, whose numbers are its own).
    """
    s = _many_channels(10, nchannels=16)
    comp = NoiseComponent("b", beta=1e-2)
    eng = NoiseEngine(s, [comp], 7)
    fitted = _fit([f for f, _ in eng.frames()], s)
    direct = NoiseEngine(s, [comp], 7, slope_route="tiered").slopes()[0]
    # short frames: the fast tier blocks are fitted too, so they agree to rounding
    np.testing.assert_allclose(direct, fitted, rtol=1e-4, atol=1e-4 * np.std(fitted))


# -- structure of the noise -----------------------------------------------------------------
def _schedule(**kw):
    g = DetectorGeometry(32, 64, 4, ref_border=2)
    params = {"skip": 4, "ref_reads": 4, "phantom_reads": 4, "frame_overhead": 100,
              "nframes": 6}
    params.update(kw)
    return ReadoutSchedule(g, **params)


@pytest.mark.parametrize("mode", ["ramps", "slopes"])
def test_common_terms_identical_across_channels(mode):
    comps = [TABLE["bias_correlated"], TABLE["bias_pixels_only"]]
    s = _schedule()
    eng = NoiseEngine(s, comps, 3)
    img = np.array([f for f, _ in eng.frames()]) if mode == "ramps" else eng.slopes()[0]
    chans = np.split(np.asarray(img), 4, axis=-1)
    for ch in chans[1:]:
        np.testing.assert_array_equal(ch, chans[0])
    assert np.std(chans[0]) > 0


def test_channel_terms_independent_across_channels():
    s = _schedule(nframes=4)
    img = NoiseEngine(s, [TABLE["video8"]], 3).slopes()[0]
    a, b = np.split(img, 4, axis=-1)[:2]
    assert not np.allclose(a, b)


def test_phantom_visible_terms_cancel_invisible_do_not():
    """Paper Fig. 5: subtracting each read's phantom removes what the phantom sees.

    Channel-mean slopes (the large spatial scales) of ``data - phantom``: a
    1/f term seen by both (Video8-like, no ACN) drops by > 20x; a term the
    phantom does not see (ROIC-like) is unchanged; one only the phantom sees is
    added.
    """
    s = schedule_from_config({"nrows": 64, "ncols": 256, "nchannels": 32, "ref_border": 0},
                             {"skip": 4, "ref_reads": 0, "phantom_reads": 4, "nframes": 10,
                              "frame_overhead": 2000})
    both = NoiseComponent("v8", beta=8.4e-3, visibility="both")
    pix = NoiseComponent("roic_like", beta=8.4e-3, visibility="pixels")

    def channel_means(comp, seed):
        data, ph = NoiseEngine(s, [comp], seed).slopes()
        d = np.asarray(data, float).reshape(s.n_reads, 32, 8)
        raw = d.mean(axis=(0, 2))
        corr = (d - np.asarray(ph, float)[:, :, None]).mean(axis=(0, 2))
        return raw, corr

    r = [channel_means(both, k) for k in range(4)]
    raw, corr = np.concatenate([x[0] for x in r]), np.concatenate([x[1] for x in r])
    assert np.var(corr) < np.var(raw) / 20
    r = [channel_means(pix, k) for k in range(4)]
    raw, corr = np.concatenate([x[0] for x in r]), np.concatenate([x[1] for x in r])
    np.testing.assert_allclose(corr, raw)


def test_acn_gives_two_offsets_per_channel():
    s = schedule_from_config({"nrows": 32, "ncols": 256, "nchannels": 16, "ref_border": 0},
                             {"skip": 4, "ref_reads": 0, "phantom_reads": 0, "nframes": 6})
    diffs = {}
    for acn in (True, False):
        comp = NoiseComponent("v8", beta=8.4e-3, acn=acn)
        d = np.asarray(NoiseEngine(s, [comp], 11).slopes()[0], float).reshape(32, 16, 8, 2)
        even, odd = d[..., 0].mean(axis=(0, 2)), d[..., 1].mean(axis=(0, 2))
        diffs[acn] = np.std(even - odd) / np.std(even)
    assert diffs[True] > 0.8  # independent even/odd offsets: difference ~ sqrt(2) x
    assert diffs[False] < 0.2  # one offset per channel


# -- hard cases ---------------------------------------------------------------------------------
@pytest.mark.parametrize("kw", [{"nframes": 2}, {"phantom_reads": 0}, {"ref_reads": 0},
                                {"skip": 1}, {"skip": 40}, {"ref_mode": "none"},
                                {"nframes": 386, "frame_overhead": 0}])
@pytest.mark.parametrize("mode", ["ramps", "slopes"])
def test_hard_schedules(kw, mode):
    s = _schedule(**kw)
    scene = {"geometry": s.geometry.to_dict(), "readout": s.to_dict()}
    e = simulate(scene, seed=1, mode=mode)
    assert np.all(np.isfinite(e.data.data))
    assert e.shape == ((s.nframes,) if mode == "ramps" else ()) + (s.n_reads, 64)
    if s.phantom_reads == 0:
        assert e.phantom is None
    else:
        assert np.all(np.isfinite(e.phantom))


def test_one_channel_subarray():
    scene = {"geometry": {"nrows": 64, "ncols": 64, "nchannels": 1, "ref_border": 0},
             "readout": {"skip": 8, "ref_reads": 0, "nframes": 5}}
    e = simulate(scene, seed=2)
    assert e.shape == (64, 64) and e.phantom.shape == (64, 1)


def test_lowest_bin_dominating_by_1e5():
    """A 1/f stream whose lowest frequency bin has 1e5 x the white level (the peer-tool trap)."""
    s = _many_channels(10, nchannels=64)
    fs = s.geometry.pixel_rate
    f_low = 1 / (s.nframes * s.frame_time.value)
    beta = 1e5 * 1e-3 * f_low  # beta / f_low = 1e5 x alpha
    comp = NoiseComponent("steep", alpha=1e-3, beta=beta, acn=True)
    assert comp.psd(f_low) / comp.psd(fs / 2) > 1e5 * 1e-3 / (1e-3 + beta / (fs / 2))
    ana = expected_slope_variance(comp, s).value
    v = np.array([np.asarray(NoiseEngine(s, [comp], k, dtype=np.float64).slopes()[0][0], float)
                  for k in range(16)])
    assert np.all(np.isfinite(v))
    assert np.mean(v**2) / ana == pytest.approx(1, abs=4 * np.sqrt(2 / (16 * 128)))


def test_zero_and_unused_terms_cost_nothing():
    s = _schedule(phantom_reads=0)
    comps = [NoiseComponent("zero"), TABLE["bias_phantom_only"], TABLE["roic"]]
    eng = NoiseEngine(s, comps, 0)
    assert [c.name for c in eng.components] == ["roic"]
    data, ph = eng.slopes()
    assert ph is None and np.all(np.isfinite(data))
    eng = NoiseEngine(s, [], 0)
    assert not eng.slow_groups and not np.any(eng.slopes()[0])


# -- determinism ---------------------------------------------------------------------------------
def test_same_seed_same_result_any_workers(monkeypatch):
    s = _schedule(nframes=5)
    a = simulate({"geometry": s.geometry.to_dict(), "readout": s.to_dict()}, seed=9,
                 mode="ramps").data.data
    monkeypatch.setattr(synthesis, "WORKERS", 1)
    monkeypatch.setattr(synthesis, "_POOL", None)
    b = simulate({"geometry": s.geometry.to_dict(), "readout": s.to_dict()}, seed=9,
                 mode="ramps").data.data
    np.testing.assert_array_equal(a, b)
    c = simulate({"geometry": s.geometry.to_dict(), "readout": s.to_dict()}, seed=10,
                 mode="ramps").data.data
    assert not np.array_equal(a, c)


def test_synthesis_independent_of_chunking():
    lam = np.linspace(1, 2, 2049)
    rngs = lambda: [synthesis.rng_for(5, 0, i) for i in range(6)]  # noqa: E731
    whole = synthesis.synthesize(lam, 4096, 4000, rngs())
    parts = np.concatenate([synthesis.synthesize(lam, 4096, 4000, rngs()[i:i + 2])
                            for i in (0, 2, 4)])
    np.testing.assert_array_equal(whole, parts)


def test_scene_terms():
    s = _schedule(nframes=20, phantom_reads=2)
    base = {"geometry": s.geometry.to_dict(), "readout": s.to_dict(),
            "noise": {"components": []}}
    e = simulate({**base, "scene": {"photocurrent": 1000.0, "leakage": 5.0}}, seed=1)
    active = (~s.is_reference)[:, None] & ~s.geometry.reference_column_mask()[None, :]
    assert np.mean(e.data.data[active]) == pytest.approx(1005.0, rel=0.01)
    np.testing.assert_allclose(e.data.data[~active], 5.0, rtol=1e-5)
    np.testing.assert_allclose(e.phantom, 5.0, rtol=1e-5)
    r = simulate({**base, "scene": {"photocurrent": 1000.0}}, seed=1, mode="ramps")
    fitted = _fit(r.data.data, s)
    # Poisson: slope variance = rate * T_frame * sum_kl w_k w_l min(k, l)
    w = ls_weights(np.arange(s.nframes) * s.frame_time.value)
    k = np.arange(s.nframes)
    var = 1000.0 * s.frame_time.value * np.sum(np.outer(w, w) * np.minimum.outer(k, k))
    assert np.var(fitted[active]) == pytest.approx(var, rel=0.1)
    assert np.var(e.data.data[active]) == pytest.approx(var, rel=0.1)
    hot = simulate({**base, "scene": {"hot_pixel_fraction": 0.1, "hot_pixel_current": 500.0,
                                      "poisson": False}}, seed=1)
    assert np.mean(hot.data.data[active] > 250) == pytest.approx(0.1, abs=0.03)
    rtn = simulate({**base, "scene": {"rtn": {"fraction": 0.2, "amplitude": 50.0,
                                              "rate": 5.0}}}, seed=1, mode="ramps")
    steps = np.abs(np.diff(rtn.data.data, axis=0))
    assert np.isclose(steps, 50.0).any() and np.mean(np.any(steps > 1, axis=0)[active]) < 0.3


@pytest.mark.parametrize("comp", [NoiseComponent("a", alpha=3.71e-5, visibility="both"),
                                  NoiseComponent("b", beta=8.4e-3, visibility="both"),
                                  NoiseComponent("g", gamma=0.1, visibility="phantom")])
def test_phantom_slope_variance(comp):
    """Phantom slopes (mean of c = 4 samples per read) against the analytic phantom variance.

    512 channels x 20 realisations: sigma = 1.4 %; tolerance 4 sigma.
    """
    s = schedule_from_config({"nrows": 8, "ncols": 1024, "nchannels": 512, "ref_border": 0},
                             {"skip": 1, "ref_reads": 0, "phantom_reads": 4, "row_overhead": 4,
                              "frame_overhead": 300, "nframes": 10})
    ana = expected_slope_variance(comp, s, kind="phantom").value
    v = np.array([NoiseEngine(s, [comp], seed).slopes()[1][3] for seed in range(20)])
    assert np.mean(v**2) / ana == pytest.approx(1, abs=4 * np.sqrt(2 / v.size))


@pytest.mark.parametrize("mode", ["ramps", "slopes"])
def test_streamed_slow_tier_statistics(mode):
    """The window-by-window slow tier (used for long or large exposures) against analytic.

    N = 10, 2048 even/odd streams x 16 realisations: sigma = 0.78 %, tolerance 4 sigma;
    the phantom slopes (512 channels x 16) to 4 sigma as well.
    """
    s = schedule_from_config({"nrows": 4, "ncols": 2048, "nchannels": 1024, "ref_border": 0},
                             {"skip": 1, "ref_reads": 0, "phantom_reads": 2, "row_overhead": 0,
                              "frame_overhead": 200, "nframes": 10})
    comp = NoiseComponent("b", beta=8.4e-3, acn=True, visibility="both")
    ana = expected_slope_variance(comp, s).value
    ana_ph = expected_slope_variance(comp, s, kind="phantom").value
    pix, ph = [], []
    for seed in range(16):
        eng = NoiseEngine(s, [comp], seed, streaming=True)
        assert eng.streaming
        if mode == "ramps":
            frames = list(eng.frames())
            pix.append(_fit([f for f, _ in frames], s)[1])
            ph.append(_fit([p for _, p in frames], s)[1])
        else:
            d, p = eng.slopes()
            pix.append(np.asarray(d[1], float))
            ph.append(np.asarray(p[1], float))
    assert np.mean(np.square(pix)) / ana == pytest.approx(1, abs=4 * np.sqrt(2 / (16 * 2048)))
    assert np.mean(np.square(ph)) / ana_ph == pytest.approx(1, abs=4 * np.sqrt(2 / (16 * 1024)))
