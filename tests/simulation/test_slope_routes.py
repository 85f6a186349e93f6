"""Small scenes cost little: slope images drawn at the samples read (the exact route).

The scene of issue 11: 64 x 64 pixels, 16 channels of 4 columns, a 2000-sample
row overhead (frames of 178 520 samples for 88 reads of 4 pixels per channel),
all Table 2 terms.  The tiered synthesis made every sample of every frame and
took 1.3 s (N = 10) to 9 s (N = 74); the exact route draws the 88 x 4 pixels
and 88 phantom means per stream from their covariance (block Durbin-Levinson).
"""

import collections
import time

import numpy as np
import pytest

from spherex_reduce import expected_slope_variance, simulate
from spherex_reduce.core import limits
from spherex_reduce.core.errors import ResourceError
from spherex_reduce.simulation import (
    NoiseComponent,
    NoiseEngine,
    exact_slopes,
    load_scene,
    slope_covariance,
)
from spherex_reduce.simulation.exact_slopes import ExactSlopes


def _scene(n, **readout):
    return {"geometry": {"nrows": 64, "ncols": 64, "nchannels": 16},
            "readout": {"nframes": n, "row_overhead": 2000, **readout}}


#: Per-pixel and per-phantom-mean slope variance ((e/s)²) of ``_scene(n)`` with all Table 2
#: terms: ``expected_slope_variance`` of the code of commit b35dab9, before the exact route and
#: before `slope_covariance` existed (it summed each component's structure function frame lag
#: by frame lag), run on this scene with that checkout.  Independent of the code under test.
B35DAB9_VARIANCE = {
    2: (63.63533480281887, 0.3249341652051702),
    10: (0.39317453183099194, 0.00206400902911213),
    74: (0.0012224968607698985, 6.953688111611447e-06),
}


@pytest.mark.parametrize("n", [2, 10, 74])
def test_analytic_variance_equals_the_code_before_the_exact_route(n):
    sc = load_scene(_scene(n))
    pix = expected_slope_variance(list(sc.components), sc.schedule).value
    ph = expected_slope_variance(list(sc.components), sc.schedule, kind="phantom").value
    assert pix == pytest.approx(B35DAB9_VARIANCE[n][0], rel=1e-9)
    assert ph == pytest.approx(B35DAB9_VARIANCE[n][1], rel=1e-9)


@pytest.mark.parametrize("n, nreal", [(2, 64), (10, 64), (74, 400)])
def test_small_scene_slope_variance_within_2_percent(n, nreal):
    """Mean square slope over the image and ``nreal`` realisations against the analytic value.

    The mean square of one image scatters by 1.9 % (N = 2), 2.0 % (N = 10) and
    6.3 % (N = 74) from image to image (measured over 400 images each: the 1/f
    terms of one channel, and the common terms of all, are shared by many
    pixels), so with these ``nreal`` the standard error is 0.24 %, 0.25 % and
    0.32 %: 2 % is more than 6 standard errors.  Phantom means scatter about
    twice as much (3.7 %, 4.3 %, 12.0 % per image): tolerance 2 % or 4
    standard errors, whichever is larger (2 %, 2.1 %, 2.4 %).
    """
    sc = load_scene(_scene(n))
    ana, ana_ph = B35DAB9_VARIANCE[n]
    pix, ph = [], []
    for seed in range(nreal):
        e = simulate(sc, seed=seed, mode="slopes")
        pix.append(np.mean(np.asarray(e.data, float) ** 2))
        ph.append(np.mean(np.asarray(e.phantom, float) ** 2))
    assert np.mean(pix) / ana == pytest.approx(1, abs=0.02)
    tol_ph = max(0.02, 4 * {2: 0.037, 10: 0.043, 74: 0.120}[n] / np.sqrt(nreal))
    assert np.mean(ph) / ana_ph == pytest.approx(1, abs=tol_ph)


def test_small_scene_slopes_are_fast():
    """N = 74 in process, no cached factors: < 1 s (it took 6.7-9.3 s, 30-85 s on a loaded
    machine; now about 0.06 s); the target of the issue, <= 0.1 s, is measured in
    benchmarks/bench_simulate.py."""
    times = []
    for seed in range(2):
        exact_slopes._EXACT_FACTORS.clear()
        t = time.perf_counter()
        simulate(_scene(74), seed=seed, mode="slopes")
        times.append(time.perf_counter() - t)
    assert min(times) < 1.0, times


@pytest.mark.parametrize("n", [2, 74])
def test_exact_route_covariance_is_the_analytic_one(n):
    """No Monte Carlo: the drawn vectors' variances (rows of the factors) sum, per pixel and per
    phantom mean, to the analytic variance of the code before the exact route."""
    sc = load_scene(_scene(n))
    eng = NoiseEngine(sc.schedule, sc.components, 0)
    assert eng.slope_route == "exact"
    nr, w = eng.n_reads, eng.width
    var_pix = np.zeros((nr, w))
    var_ph = np.zeros(nr)
    for plan, pix, phq in eng.exact.factors().values():
        m = nr * plan.k  # the draw is linear: unit vectors give the factor L, L L^T = Sigma
        factor = plan.draw(np.eye(m).reshape(nr, plan.k, m)).reshape(m, m)
        d = np.sum(factor**2, axis=1).reshape(nr, -1)
        var_pix[:, pix] += d[:, :pix.size]
        if phq.size:
            var_ph += d[:, -1]
    ana, ana_ph = B35DAB9_VARIANCE[n]
    np.testing.assert_allclose(var_pix, ana, rtol=1e-9)
    np.testing.assert_allclose(var_ph, ana_ph, rtol=1e-9)


def test_block_levinson_draws_have_the_covariance_asked_for():
    """The sampler against a dense block-Toeplitz covariance (a moving average of 3-vectors)."""
    rng = np.random.default_rng(1)
    nr, k = 12, 3
    a = [rng.standard_normal((k, k)) * 0.7**i for i in range(30)]
    gam = np.array([sum(a[i + h] @ a[i].T for i in range(30 - h)) for h in range(nr)])
    full = np.block([[gam[r - c] if r >= c else gam[c - r].T for c in range(nr)]
                     for r in range(nr)])
    plan = exact_slopes._BlockLevinson(gam)
    factor = plan.draw(np.eye(nr * k).reshape(nr, k, nr * k)).reshape(nr * k, nr * k)
    np.testing.assert_allclose(factor @ factor.T, full, atol=1e-12 * np.abs(full).max())


def test_slope_covariance_against_frames_of_white_and_pink_noise():
    """Independent check of `slope_covariance`: covariance of two least-squares slopes written
    out as a double sum over frames of the (stationary) autocovariance.  White noise of variance
    ``s2`` per sample: ``s2 sum w^2`` at lag 0, 0 elsewhere; a 1/f term: from the structure
    function summed frame pair by frame pair."""
    s = load_scene(_scene(10)).schedule
    fs, big_f = s.geometry.pixel_rate, s.frame_samples
    w = np.arange(10) - 4.5
    w = w / np.sum(w * (np.arange(10) * big_f / fs))
    white = NoiseComponent("w", alpha=2e-3)
    cov = slope_covariance(white, s, [0, 1, 2008])[0]
    np.testing.assert_allclose(cov, [white.white_variance(fs) * np.sum(w**2), 0, 0], atol=1e-9)
    pink = NoiseComponent("p", beta=1e-2)
    for lag in (0, 7, 2008, 150000):
        jk = np.arange(10)[:, None] - np.arange(10)[None, :]
        direct = -0.5 * np.sum(w[:, None] * w[None, :] *
                               pink.structure_function(lag + jk * big_f, fs))
        assert slope_covariance(pink, s, [lag])[0, 0] == pytest.approx(direct, rel=1e-10)


def test_slope_route_is_chosen_by_cost():
    small = load_scene(_scene(10))
    assert NoiseEngine(small.schedule, small.components, 0).slope_route == "exact"
    full = load_scene({"readout": {"nframes": 74}})  # the paper's 2048^2 case
    eng = NoiseEngine(full.schedule, full.components, 0)
    assert eng.slope_route == "tiered"
    with pytest.raises(ValueError, match="exact"):
        NoiseEngine(full.schedule, full.components, 0, slope_route="exact").slopes()
    # the paper's periodic random-phase synthesis is reproduced, never replaced
    rp = NoiseEngine(small.schedule, small.components, 0, method="random_phase", padding=1)
    assert rp.slope_route == "tiered"
    assert simulate(small, seed=1).header["SIMROUTE"] == "exact"
    with pytest.raises(ValueError, match="slope_route"):
        NoiseEngine(small.schedule, small.components, 0, slope_route="fast")


def test_exact_route_common_terms_follow_the_scan_direction():
    """A common stream is read by every channel at once: with alternating fast-scan directions
    column j of channel 0 and column width - 1 - j of channel 1 see the same sample."""
    sc = {"geometry": {"nrows": 32, "ncols": 32, "nchannels": 4, "ref_border": 2,
                       "scan": "alternate"},
          "readout": {"nframes": 6, "row_overhead": 500},
          "noise": {"components": ["bias_correlated", "bias_pixels_only"]}}
    scene = load_scene(sc)
    eng = NoiseEngine(scene.schedule, scene.components, 3)
    assert eng.slope_route == "exact"
    img, ph = eng.slopes()
    w = eng.width
    np.testing.assert_array_equal(img[:, :w], img[:, 2 * w - 1:w - 1:-1])
    np.testing.assert_array_equal(img[:, :w], img[:, 2 * w:3 * w])
    assert np.all(ph == ph[:, :1])  # bias_correlated reaches every phantom mean alike
    assert np.std(img) > 0


def _tiny(n):
    """A small scene (16 x 16 pixels, 4 channels) whose exact factors build in milliseconds."""
    return {"geometry": {"nrows": 16, "ncols": 16, "nchannels": 4},
            "readout": {"nframes": n, "row_overhead": 50}}


def _held(factors):
    """Bytes of the predictors and innovation factors of an exact-route entry."""
    return sum(a.nbytes for plan, _, _ in factors.values() for a in plan.pred + plan.innov)


def _cached_bytes():
    entries = exact_slopes._EXACT_FACTORS.values()
    return sum(_held(v[0] if isinstance(v, tuple) else v) for v in entries)


def test_exact_factor_cache_is_bounded_by_bytes(monkeypatch):
    """Several distinct scenes (a sweep over N) keep at most the byte bound alive (it was 8
    scenes whatever their size: up to 2.4 GB); an entry larger than the bound is used, not
    kept."""
    monkeypatch.setattr(exact_slopes, "_EXACT_FACTORS", collections.OrderedDict())
    scenes = [load_scene(_tiny(n)) for n in range(2, 8)]
    engines = [NoiseEngine(sc.schedule, sc.components, 0) for sc in scenes]
    assert {e.slope_route for e in engines} == {"exact"}
    size = _held(engines[0].exact.factors())  # the same reads and widths: the same size
    assert size > 0
    exact_slopes._EXACT_FACTORS.clear()
    bound = int(2.5 * size)
    monkeypatch.setattr(ExactSlopes, "CACHE_BYTES", bound)
    for sc in scenes:
        img = simulate(sc, seed=1, mode="slopes")
        assert img.header["SIMROUTE"] == "exact"
        assert 0 < _cached_bytes() <= bound
    assert len(exact_slopes._EXACT_FACTORS) == 2  # the two most recent scenes
    # an entry larger than the bound: drawn, not kept, and the others left alone
    monkeypatch.setattr(ExactSlopes, "CACHE_BYTES", size // 2)
    exact_slopes._EXACT_FACTORS.clear()
    img, ph = engines[0].slopes()
    assert np.std(img) > 0 and np.std(ph) > 0
    assert len(exact_slopes._EXACT_FACTORS) == 0


def test_exact_route_is_not_chosen_beyond_the_memory_budget(monkeypatch):
    """The exact route's factors must fit in what the process may allocate: a 1024-row, 64-col,
    32-channel scene with a 2000-sample overhead at N = 74 keeps 79 MB of predictors (measured,
    1.1 s to build), so with a 100 MB budget it takes the tiered route; asked for explicitly,
    the exact route is refused before anything is allocated."""
    big = load_scene({"geometry": {"nrows": 1024, "ncols": 64, "nchannels": 32},
                      "readout": {"nframes": 74, "row_overhead": 2000}})
    eng = NoiseEngine(big.schedule, big.components, 0)
    monkeypatch.setattr(limits, "memory_budget", lambda: 2**40)
    assert eng.slope_route == "exact"
    monkeypatch.setattr(limits, "memory_budget", lambda: 100 * 10**6)
    assert eng.slope_route == "tiered"
    forced = NoiseEngine(big.schedule, big.components, 0, slope_route="exact")
    with pytest.raises(ResourceError, match="exact slope route"):
        forced.slopes()
    # the estimate bounds what a small scene really keeps
    small = load_scene(_tiny(3))
    eng = NoiseEngine(small.schedule, small.components, 0)
    held = _held(eng.exact.factors())
    assert eng.exact.memory() >= held
    monkeypatch.setattr(limits, "memory_budget", lambda: held // 2)
    assert eng.slope_route == "tiered"
