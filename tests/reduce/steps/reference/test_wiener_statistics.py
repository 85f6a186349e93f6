"""The wiener strategy's statistics against Monte Carlo draws from the exact covariance.

Every sample a read takes (its phantom samples and its pixels) is drawn from a
multivariate normal whose covariance is built here by brute force from the
noise components' structure functions at integer sample lags (no frequency
grid, no quadrature: independent of the strategy's `ReadCovariance`).  The
strategy estimates each read's value from the reference reads (and the phantom
values); its errors must have the variance it predicts, under unknown
constants per channel added to the pixels and to the phantom values.
"""

import numpy as np
import pytest
from astropy.table import Table

from spherex_reduce import DetectorGeometry, ReadoutSchedule
from spherex_reduce.core.block import Block, Context
from spherex_reduce.noise import NoiseComponent, slope_covariance
from spherex_reduce.reduce.steps.reference.strategies import MeanReference
from spherex_reduce.reduce.steps.reference.wiener import _MODELS, WienerReference

NDRAWS = 3000


def _schedule(phantom_reads=2):
    g = DetectorGeometry(24, 8, 2, ref_border=2)  # 2 channels of 4 columns
    return ReadoutSchedule(g, skip=3, ref_reads=6, ref_mode="distributed",
                           phantom_reads=phantom_reads, row_overhead=1, frame_overhead=40,
                           nframes=4)


def _sample_times(s):
    """Sample index (within a frame) of every sample a read takes, and what it is."""
    g = s.geometry
    c, w = s.phantom_reads, g.channel_width
    offsets = g.column_offsets()[:w]
    times, kind, read, col = [], [], [], []
    for i, start in enumerate(s.starts):
        for m in range(c):
            times.append(start - c + m)
            kind.append("phantom")
            read.append(i)
            col.append(-1)
        for j in range(w):
            times.append(start + offsets[j])
            kind.append("pixel")
            read.append(i)
            col.append(j)
    return (np.array(times), np.array(kind), np.array(read), np.array(col),
            np.r_[np.arange(-c, 0), offsets])


def _covariance(components, s, domain):
    """Covariance of all the samples of one channel's frame, per component scope."""
    times, kind, read, _, _ = _sample_times(s)
    rel = times - s.starts[read]  # offset within the read: its parity picks the realisation
    lag = np.abs(times[:, None] - times[None, :])
    fs = s.geometry.pixel_rate
    out = {"channel": 0.0, "common": 0.0}
    for comp in components:
        if domain == "slopes":
            k = slope_covariance(comp, s, lag.ravel())[0].reshape(lag.shape)
        else:  # an integrable PSD: variance minus half the structure function
            e = comp.exponent
            var = comp.alpha * fs / 2 + comp.gamma * (fs / 2) ** (1 - e) / (1 - e)
            assert comp.beta == 0
            k = var - comp.structure_function(lag, fs) / 2
        seen = np.where(kind == "pixel", comp.seen_by_pixels, comp.seen_by_phantom)
        k = k * np.outer(seen, seen)
        if comp.acn:  # even and odd samples of a read: independent realisations
            par = rel % 2
            k = k * (par[:, None] == par[None, :])
        out["common" if comp.scope == "common" else "channel"] = (
            out["common" if comp.scope == "common" else "channel"] + k)
    return out


def _root(cov):
    vals, vecs = np.linalg.eigh(cov)
    return vecs * np.sqrt(np.clip(vals, 0, None))


def _draw(components, s, domain, rng, ndraws=NDRAWS):
    """Samples ``(ndraws, nch, nsamples)``, channel streams independent, common shared."""
    cov = _covariance(components, s, domain)
    nch = s.geometry.nchannels
    n = _sample_times(s)[0].size
    x = np.zeros((ndraws, nch, n))
    for scope, k in cov.items():
        if np.ndim(k) == 0:
            continue
        root = _root(k)
        if scope == "channel":
            x += rng.standard_normal((ndraws, nch, n)) @ root.T
        else:
            x += (rng.standard_normal((ndraws, n)) @ root.T)[:, None, :]
    return x


def _exposure_parts(s, x, rng, subtract):
    """The side block values, phantom values and true read values of the draws."""
    g = s.geometry
    _, kind, _read, _col, _ = _sample_times(s)
    ndraws, nch, _ = x.shape
    w, c = g.channel_width, s.phantom_reads
    pix = x[:, :, kind == "pixel"].reshape(ndraws, nch, s.n_reads, w)
    pix = pix + rng.normal(0, 1e3, (ndraws, nch, 1, 1))  # unknown constants per channel
    if c:
        ph = x[:, :, kind == "phantom"].reshape(ndraws, nch, s.n_reads, c).mean(axis=-1)
        ph = ph + rng.normal(0, 1e3, (ndraws, nch, 1))  # and per channel's phantom
    else:
        ph = np.zeros((ndraws, nch, s.n_reads))
    if subtract:
        pix = pix - ph[..., None]
    truth = pix.mean(axis=-1)  # (ndraws, nch, n_reads)
    # columns of the frame: channel ch, column j read at offset column_offsets
    frame = np.empty((ndraws, s.n_reads, g.ncols))
    offs = g.column_offsets()
    order = _sample_times(s)[4][c:]  # offsets of the pixel samples, in sample order
    for ch in range(nch):
        for j in range(w):
            pos = int(np.flatnonzero(order == offs[ch * w + j])[0])
            frame[:, :, ch * w + j] = pix[:, ch, :, pos]
    return frame, np.moveaxis(ph, 1, 2), np.moveaxis(truth, 1, 2)


def _side(s, frame, phantom):
    idx = s.reference_read_indices
    return Block(frame[:, idx], idx, "readout", read_phantom=phantom)


COMPONENTS = [
    NoiseComponent("roic", alpha=2e-3, gamma=0.1, visibility="pixels", acn=True),
    NoiseComponent("video8", alpha=4e-5, beta=8e-3, visibility="both"),
    NoiseComponent("bias", beta=0.5, scope="common", visibility="both"),
]


def _strategy(components, tmp_path, **params):
    """The strategy with these components as its noise model (an ECSV noise table)."""
    path = tmp_path / "noise.ecsv"
    Table(rows=[(c.name, c.alpha, c.beta, c.gamma, c.exponent, c.scope, c.visibility, c.acn)
                for c in components],
          names=("name", "alpha", "beta", "gamma", "exponent", "scope", "visibility", "acn")
          ).write(path, format="ascii.ecsv", overwrite=True)
    return WienerReference(noise=str(path), sigma=1e9, **params)


@pytest.fixture(autouse=True)
def _fresh_models():
    _MODELS.clear()
    yield
    _MODELS.clear()


def _check(err, predicted, tol, s, exact_at_reference=True):
    """Error variance per active read (over draws and channels) against the prediction
    (the kriging estimate of a reference read is its own value: no error, none predicted)."""
    ref = s.reference_read_indices
    if exact_at_reference:
        assert np.allclose(err[:, ref], 0, atol=1e-6 * np.sqrt(predicted.max()))
        assert np.allclose(predicted[ref], 0, atol=1e-9 * predicted.max())
    active = s.active_read_indices
    err, predicted = err[:, active], predicted[active]
    ratio = (err ** 2).mean(axis=(0, 2)) / predicted
    se = np.sqrt(2 / (err.shape[0] * err.shape[2]))  # relative standard error of a variance
    assert abs(ratio.mean() - 1) < max(tol, 4 * se / np.sqrt(err.shape[1])), ratio
    assert np.all(np.abs(ratio - 1) < 5 * se), ratio
    return ratio


@pytest.mark.parametrize("use_phantom", [True, False])
def test_slopes_error_variance_is_the_predicted_one(use_phantom, tmp_path):
    s = _schedule()
    rng = np.random.default_rng(5)
    x = _draw(COMPONENTS, s, "slopes", rng)
    frame, phantom, truth = _exposure_parts(s, x, rng, subtract=not use_phantom)
    ctx = Context(s, "readout", True, has_phantom=use_phantom)
    strat = _strategy(COMPONENTS, tmp_path, domain="slopes")  # the model the draws follow
    assert strat.common == {"bias"}
    est = strat.estimate(_side(s, frame, phantom if use_phantom else None), ctx)
    err = est.rows[..., 0] - truth
    wiener, mean = strat.predicted_variance(ctx)
    _check(err, wiener, 0.03, s)
    # the mean of the reference pixels (the mean strategy, computed here with numpy)
    ref = frame[:, s.reference_read_indices].reshape(NDRAWS, -1, 2, 4)
    if not use_phantom:
        m_err = ref.mean(axis=(1, 3))[:, None, :] - truth
        _check(m_err, mean, 0.03, s, exact_at_reference=False)
        assert (m_err ** 2).mean() > (err ** 2).mean()
    else:  # with the phantom values the estimate beats the mean of the subtracted reads
        assert wiener.mean() < 0.9 * mean.mean()


def test_frames_error_variance_is_the_predicted_one(tmp_path):
    """Frames domain (the stream itself): an integrable PSD, so the draws have a covariance;
    the strategy uses the generalised covariance -D/2 (the constant does not matter)."""
    s = _schedule()
    comps = [NoiseComponent("flicker", alpha=1e-3, gamma=3e-3, exponent=0.5,
                            visibility="both"),
             NoiseComponent("amp", alpha=2e-3, gamma=1e-3, exponent=0.6, visibility="pixels")]
    rng = np.random.default_rng(7)
    x = _draw(comps, s, "frames", rng)
    frame, phantom, truth = _exposure_parts(s, x, rng, subtract=False)
    ctx = Context(s, "readout", True, has_phantom=True)
    strat = _strategy(comps, tmp_path, domain="frames")
    est = strat.estimate(_side(s, frame, phantom), ctx)
    wiener, _ = strat.predicted_variance(ctx)
    _check(est.rows[..., 0] - truth, wiener, 0.03, s)


def test_white_noise_gives_the_mean_of_the_reference_pixels(tmp_path):
    """With no correlated part left the estimate is the reference mean, exactly."""
    s = _schedule(phantom_reads=0)
    rng = np.random.default_rng(1)
    frame = rng.normal(0, 3, (5, s.n_reads, s.geometry.ncols)) + rng.normal(0, 50, (5, 1, 8))
    ctx = Context(s, "readout", True, has_phantom=False)
    strat = _strategy([NoiseComponent("white", alpha=2e-3)], tmp_path, domain="frames")
    est = strat.estimate(_side(s, frame, None), ctx)
    ref = frame[:, s.reference_read_indices].reshape(5, -1, 2, 4)
    expected = ref.mean(axis=(1, 3))  # (frames, channels): numpy's mean
    active = s.active_read_indices
    assert np.allclose(est.rows[:, active][..., 0], expected[:, None, :], rtol=0, atol=1e-12)
    # a reference read's own value is known: its estimate is that value
    own = ref.mean(axis=3)
    assert np.allclose(est.rows[:, s.reference_read_indices][..., 0], own, rtol=0, atol=1e-6)
    # and the mean strategy (no clipping) gives the same offsets
    mean = MeanReference(sigma=1e9).estimate(_side(s, frame, None), ctx)
    assert np.allclose(mean.offsets[..., 0], expected, rtol=0, atol=1e-12)


def test_read_covariance_matches_the_brute_force_sums():
    """The read values' covariance (with its quadrature for distant reads) against the
    double sum over the samples of the brute-force covariance above."""
    from spherex_reduce.noise.read_covariance import ReadCovariance

    s = _schedule()
    c, w = s.phantom_reads, s.geometry.channel_width
    cov = _covariance(COMPONENTS, s, "slopes")
    _, kind, _read, _, _ = _sample_times(s)
    rc = ReadCovariance(s, COMPONENTS, s.geometry.column_offsets()[:w], "slopes",
                        common={"bias"})
    for scope in ("channel", "common"):
        k = cov[scope]
        pix = np.where(kind == "pixel")[0].reshape(s.n_reads, w)
        ph = np.where(kind == "phantom")[0].reshape(s.n_reads, c)
        for a, b, ia, ib in (("pixels", "pixels", pix, pix), ("phantom", "phantom", ph, ph),
                             ("pixels", "phantom", pix, ph), ("phantom", "pixels", ph, pix)):
            # the second read m reads after the first, m of either sign
            m = np.arange(-(s.n_reads - 1), s.n_reads)
            first = np.maximum(-m, 0)
            brute = np.array([k[np.ix_(ia[i], ib[i + d])].mean()
                              for i, d in zip(first, m, strict=True)])
            white = rc.white(a, w, scope) if a == b else 0.0
            model = rc.colored(m, a, b)[scope]
            model[m == 0] += white
            assert np.allclose(model, brute, rtol=1e-6, atol=1e-9 * np.abs(brute).max()), (
                scope, a, b)
