"""The ``wiener`` strategy's side reference columns against a brute force and Monte Carlo draws.

The covariance of every sample of one channel's frame (phantom samples and pixels) is
built here from the noise components' structure functions at integer sample lags,
per scope: each channel draws its own channel-scope stream, every channel sees the same
common one (at the same sample time), ``acn`` components have independent even and odd
streams.  The observations are written here as the strategy defines them, as linear
functionals of those samples: each channel's reference read values, their mean over
channels, the phantom values, and the side value of every active read (the mean over
the channels with side columns of their side pixels' mean); the target is the channel
mean of the group's pixels at every read.  The bordered kriging system (one unknown
constant for the reference and pixel values, one for the phantom values, one for the
side values) is solved with numpy: the strategy's weights of the channel mean
(``w + wd`` and ``ws``) and its predicted variance must be those.
"""

import json

import numpy as np
import pytest
from _cli_helpers import run
from astropy.io import fits
from astropy.table import Table
from astropy.utils.exceptions import AstropyUserWarning

from spherex_reduce import DetectorGeometry, Exposure, ReadoutSchedule, dq, write
from spherex_reduce.core.block import Block, Context
from spherex_reduce.core.errors import ConfigError
from spherex_reduce.noise import NoiseComponent, slope_covariance
from spherex_reduce.reduce.steps.reference.wiener import _MODELS, WienerReference

NOISE_COLUMNS = ("name", "alpha", "beta", "gamma", "exponent", "scope", "visibility", "acn")
SLOPES = [
    NoiseComponent("roic", alpha=2e-3, gamma=0.1, visibility="pixels", acn=True),
    NoiseComponent("video8", alpha=4e-5, beta=8e-3, visibility="both"),
    NoiseComponent("bias", alpha=1e-4, beta=0.5, scope="common", visibility="both"),
]
FRAMES = [  # integrable PSDs: the draws have a covariance
    NoiseComponent("flicker", alpha=1e-3, gamma=3e-3, exponent=0.5, visibility="both"),
    NoiseComponent("amp", alpha=2e-3, gamma=1e-3, exponent=0.6, visibility="pixels",
                   acn=True),
    NoiseComponent("pink", alpha=1e-4, gamma=2e-2, exponent=0.8, scope="common",
                   visibility="both"),
]


@pytest.fixture(autouse=True)
def _fresh_models():
    _MODELS.clear()
    yield
    _MODELS.clear()


def _schedule(scan="same", phantom_reads=2, border=2, nch=4, ref_mode="distributed",
              ref_reads=6, width=4):
    g = DetectorGeometry(24, width * nch, nch, ref_border=border, scan=scan)
    return ReadoutSchedule(g, skip=3, ref_reads=ref_reads, ref_mode=ref_mode,
                           phantom_reads=phantom_reads, row_overhead=1, frame_overhead=40,
                           nframes=4)


def _strategy(components, tmp_path, **params):
    """The strategy with these components as its noise model (an ECSV noise table)."""
    path = tmp_path / "noise.ecsv"
    Table(rows=[tuple(getattr(c, n) for n in NOISE_COLUMNS) for c in components],
          names=NOISE_COLUMNS).write(path, format="ascii.ecsv", overwrite=True)
    return WienerReference(noise=str(path), **{"sigma": 1e9, **params})


# -- the brute force ---------------------------------------------------------------------
class Samples:
    """Every sample of one channel's frame: read ``i`` takes its ``c`` phantom samples at
    ``i * (c + w) + m`` and the pixel at offset ``o`` at ``i * (c + w) + c + o``."""

    def __init__(self, s):
        self.s, g = s, s.geometry
        self.c, self.w = s.phantom_reads, g.channel_width
        per = self.c + self.w
        rel = np.r_[np.arange(-self.c, 0), np.arange(self.w)]
        self.rel = np.tile(rel, s.n_reads)  # offset within the read
        self.times = np.repeat(np.asarray(s.starts), per) + self.rel
        self.phantom = self.rel < 0
        self.n, self.per = self.times.size, per

    def covariance(self, components, domain):
        """``{'channel': K, 'common': K}`` of the samples (e², or (e/s)² for slopes)."""
        lag = np.abs(self.times[:, None] - self.times[None, :])
        fs = self.s.geometry.pixel_rate
        out = {"channel": np.zeros((self.n, self.n)), "common": np.zeros((self.n, self.n))}
        for comp in components:
            if domain == "slopes":
                k = slope_covariance(comp, self.s, lag.ravel())[0].reshape(lag.shape)
            else:  # variance minus half the structure function
                e = comp.exponent
                assert comp.beta == 0
                var = comp.alpha * fs / 2 + comp.gamma * (fs / 2) ** (1 - e) / (1 - e)
                k = var - comp.structure_function(lag, fs) / 2
            seen = np.where(self.phantom, comp.seen_by_phantom, comp.seen_by_pixels)
            k = k * np.outer(seen, seen)
            if comp.acn:
                par = self.rel % 2
                k = k * (par[:, None] == par[None, :])
            out["common" if comp.scope == "common" else "channel"] += k
        return out

    def value(self, read, offsets, subtract):
        """Functional of the mean of the pixels at ``offsets`` of ``read`` (minus the read's
        phantom value)."""
        v = np.zeros(self.n)
        np.add.at(v, read * self.per + self.c + np.asarray(offsets), 1.0 / len(offsets))
        if subtract:
            v[read * self.per + np.arange(self.c)] -= 1.0 / self.c
        return v

    def phantom_value(self, read):
        v = np.zeros(self.n)
        v[read * self.per + np.arange(self.c)] = 1.0 / self.c
        return v


def _groups(g, acn, parity):
    """Columns of each channel in the group, and side columns, by numpy on the geometry."""
    w, off = g.channel_width, g.column_offsets()
    side = np.zeros(g.ncols, bool)
    side[:g.border.left] = True
    side[g.ncols - g.border.right:] = True
    cols, sides = [], []
    for ch in range(g.nchannels):
        c = np.arange(ch * w, (ch + 1) * w)
        if acn:
            c = c[off[c] % 2 == parity]
        cols.append(c)
        sides.append(c[side[c]])
    return cols, sides


def _functionals(smp, cols, sides, subtract, use_phantom):
    """Per channel ``(nch, m, n)`` functionals of the mean system's observations (reference
    reads' channel mean, phantom values' channel mean, side values) and ``(nch, T, n)`` of
    the target (channel mean at every read), and each observation's constant."""
    s, g = smp.s, smp.s.geometry
    off = g.column_offsets()
    nch = g.nchannels
    side_ch = [ch for ch in range(nch) if sides[ch].size]
    ref, active = s.reference_read_indices, np.sort(s.active_read_indices)
    obs, tgt = [], []
    for ch in range(nch):
        rows = [smp.value(r, off[cols[ch]], subtract) / nch for r in ref]
        if use_phantom:
            rows += [smp.phantom_value(i) / nch for i in range(s.n_reads)]
        rows += [(smp.value(i, off[sides[ch]], subtract) / len(side_ch) if ch in side_ch
                  else np.zeros(smp.n)) for i in active]
        obs.append(rows)
        tgt.append([smp.value(i, off[cols[ch]], subtract) / nch for i in range(s.n_reads)])
    constants = np.r_[np.zeros(ref.size, int), np.ones(s.n_reads * use_phantom, int),
                      np.full(active.size, 1 + int(use_phantom))]
    return np.array(obs), np.array(tgt), constants


def _cov(a, b, k):
    """Covariance of functionals ``a (nch, m, n)`` and ``b (nch, T, n)``: channel streams
    independent, the common one shared by every channel."""
    return (np.einsum("cmn,nk,ctk->mt", a, k["channel"], b)
            + a.sum(axis=0) @ k["common"] @ b.sum(axis=0).T)


def _krige(c_oo, c_ot, c_tt, constants):
    """Bordered kriging: weights ``(T, m)`` and error variances, numpy only."""
    m, q = c_oo.shape[0], int(constants.max()) + 1
    f = np.zeros((m, q))
    f[np.arange(m), constants] = 1.0
    a = np.block([[c_oo, f], [f.T, np.zeros((q, q))]])
    rhs = np.vstack([c_ot, np.zeros((q, c_ot.shape[1]))])
    rhs[m] = 1.0  # the targets share constant 0
    sol = np.linalg.solve(a, rhs)
    lam = sol[:m]
    var = c_tt - 2 * np.sum(lam * c_ot, axis=0) + np.einsum("it,ij,jt->t", lam, c_oo, lam)
    return lam.T, var


def _light_cross(smp, components, domain, k):
    """``k`` without the pixels' own white noise: the covariance of a side pixel with the
    target, whose pixels are the light ones (other samples than the side pixels, with
    independent white noise; a phantom sample is the same sample for both)."""
    colored = smp.covariance([c.replace(alpha=0.0) for c in components], domain)
    return {scope: k[scope] - np.diag((np.diag(k[scope]) - np.diag(colored[scope]))
                                      * ~smp.phantom) for scope in k}


def _cross(obs, tgt, k, k_light, nside):
    """Covariance of the observations with the target: the last ``nside`` (side values)
    with the light pixels' white noise apart."""
    out = _cov(obs, tgt, k)
    if nside:
        out[-nside:] = _cov(obs[:, -nside:], tgt, k_light)
    return out


def _brute_mean(s, components, domain, acn, parity, subtract, use_phantom):
    smp = Samples(s)
    k = smp.covariance(components, domain)
    cols, sides = _groups(s.geometry, acn, parity)
    obs, tgt, constants = _functionals(smp, cols, sides, subtract, use_phantom)
    c_tt = np.diag(_cov(tgt, tgt, k))
    nside = np.sort(s.active_read_indices).size
    c_ot = _cross(obs, tgt, k, _light_cross(smp, components, domain, k), nside)
    lam, var = _krige(_cov(obs, obs, k), c_ot, c_tt, constants)
    return lam, var, smp, k, cols, sides


def _brute_channel(smp, k, cols, subtract, use_phantom):
    """The deviations' system: one channel, its own terms alone (variance ``v1``)."""
    s, off = smp.s, smp.s.geometry.column_offsets()
    ref = s.reference_read_indices
    obs = [smp.value(r, off[cols[0]], subtract) for r in ref]
    if use_phantom:
        obs += [smp.phantom_value(i) for i in range(s.n_reads)]
    obs = np.array(obs)
    tgt = np.array([smp.value(i, off[cols[0]], subtract) for i in range(s.n_reads)])
    kc = k["channel"]
    constants = np.r_[np.zeros(ref.size, int), np.ones(s.n_reads * use_phantom, int)]
    return _krige(obs @ kc @ obs.T, obs @ kc @ tgt.T, np.einsum("tn,nk,tk->t", tgt, kc, tgt),
                  constants)


CASES = {  # scan, phantom reads, phantom used, domain, acn, parity, border
    "same-phantom-slopes": ("same", 2, True, "slopes", False, 0, 2),
    "alternate-no-phantom-slopes": ("alternate", 0, False, "slopes", False, 0, 2),
    "alternate-phantom-subtracted": ("alternate", 2, False, "slopes", False, 0, 2),
    "same-phantom-frames": ("same", 2, True, "frames", False, 0, 2),
    "alternate-acn-odd": ("alternate", 2, True, "slopes", True, 1, 2),
    "same-acn-even-frames": ("same", 0, False, "frames", True, 0, 2),
    "uneven-sides": ("same", 2, True, "slopes", False, 0,
                     {"top": 2, "bottom": 2, "left": 2, "right": 1}),
    "left-only": ("alternate", 0, False, "slopes", False, 0,
                  {"top": 2, "bottom": 2, "left": 2}),
}


@pytest.mark.parametrize("case", list(CASES))
def test_side_weights_are_the_brute_force_kriging_weights(case, tmp_path):
    scan, c, use_phantom, domain, acn, parity, border = CASES[case]
    s = _schedule(scan, c, border)
    comps = SLOPES if domain == "slopes" else FRAMES
    strat = _strategy(comps, tmp_path, domain=domain, side_columns=True, acn=acn)
    ctx = Context(s, "readout", True, has_phantom=use_phantom)
    subtract = bool(c) and not use_phantom
    lam, var, smp, k, cols, sides = _brute_mean(s, comps, domain, acn, parity, subtract,
                                                use_phantom)
    w, wd, kind, used = strat.read_weights(ctx, parity)
    ws, reads, groups = strat.side_weights(ctx, parity)
    assert used == use_phantom and kind == ("subtracted" if subtract else "pixels")
    # the side channels and columns: those with ref_border's left/right columns in the group
    assert [ch for ch, _ in groups] == [ch for ch in range(4) if sides[ch].size]
    for ch, cc in groups:
        np.testing.assert_array_equal(cc, sides[ch])
    np.testing.assert_array_equal(reads, np.sort(s.active_read_indices))
    mean_w = np.hstack([w + wd, ws])
    assert mean_w.shape == lam.shape
    np.testing.assert_allclose(mean_w, lam, rtol=0, atol=1e-6 * np.abs(lam).max())
    # the side values are used: their weights are not negligible
    assert np.abs(ws).max() > 1e-3 * np.abs(lam).max()
    # the prediction: v0 / nch (the channel mean, brute force) + (1 - 1/nch) v1 (deviations)
    _, v1 = _brute_channel(smp, k, cols, subtract, use_phantom)
    predicted, _ = strat.predicted_variance(ctx, parity=parity)
    nch = s.geometry.nchannels
    np.testing.assert_allclose(predicted, var + (1 - 1 / nch) * v1, rtol=1e-6,
                               atol=1e-8 * predicted.max())
    # and the exact error variance of the strategy's own per-channel estimates, averaged
    # over channels, is the prediction (the side values' correlation with the outer
    # channels' deviations cancels in that average)
    k_light = _light_cross(smp, comps, domain, k)
    np.testing.assert_allclose(_channel_error_variances(strat, ctx, parity, smp, k, cols,
                                                        sides, subtract, k_light).mean(axis=0),
                               predicted, rtol=1e-6, atol=1e-8 * predicted.max())


def _channel_error_variances(strat, ctx, parity, smp, k, cols, sides, subtract, k_light):
    """Exact error variance ``(nch, T)`` of each channel's estimate ``w @ y_c + wd @
    mean(y) + ws @ s`` with the strategy's weights, under the brute-force covariance (the
    side values' covariance with the target, whose pixels are the light ones, from
    ``k_light``)."""
    s = smp.s
    g = s.geometry
    nch = g.nchannels
    w, wd, _, use_phantom = strat.read_weights(ctx, parity)
    ws, _, _ = strat.side_weights(ctx, parity)
    obs, tgt, _ = _functionals(smp, cols, sides, subtract, use_phantom)
    m = w.shape[1]
    own = obs[:, :m] * nch  # each channel's own values (the functionals are / nch)
    out = []
    for c in range(nch):
        main = np.einsum("tm,dmn->dtn", wd, obs[:, :m])
        main[c] += w @ own[c]
        side = np.einsum("tr,drn->dtn", ws, obs[:, m:])
        target = np.zeros_like(main)
        target[c] = tgt[c] * nch
        est = main + side
        out.append(np.diag(_cov(est, est, k)) - 2 * np.diag(_cov(main, target, k))
                   - 2 * np.diag(_cov(side, target, k_light))
                   + np.diag(_cov(target, target, k)))
    return np.array(out)


# -- Monte Carlo ---------------------------------------------------------------------------
def _draw(smp, k, nch, ndraws, rng):
    """Samples ``(ndraws, nch, n)``: channel streams independent, the common one shared."""
    x = np.zeros((ndraws, nch, smp.n))
    for scope, cov in k.items():
        vals, vecs = np.linalg.eigh(cov)
        root = vecs * np.sqrt(np.clip(vals, 0, None))
        if scope == "channel":
            x += rng.standard_normal((ndraws, nch, smp.n)) @ root.T
        else:
            x += (rng.standard_normal((ndraws, smp.n)) @ root.T)[:, None, :]
    return x


def _frames(smp, x, rng, offset=1e3):
    """Readout-order frames ``(L, n_reads, ncols)`` and phantom values ``(L, n_reads, nch)``
    of the draws, with an unknown constant per draw and channel (and phantom)."""
    s, g = smp.s, smp.s.geometry
    ndraws, nch, _ = x.shape
    per, c, w = smp.per, smp.c, smp.w
    x = x.reshape(ndraws, nch, s.n_reads, per)
    off = g.column_offsets()
    frame = np.empty((ndraws, s.n_reads, g.ncols))
    for col in range(g.ncols):
        frame[:, :, col] = x[:, col // w, :, c + off[col]]
    frame += np.repeat(rng.normal(0, offset, (ndraws, 1, nch)), w, axis=2)
    ph = (x[..., :c].mean(axis=-1) + rng.normal(0, offset, (ndraws, nch, 1)) if c
          else np.zeros((ndraws, nch, s.n_reads)))
    return frame, np.moveaxis(ph, 1, 2)


def _run(strat, s, frame, phantom, ctx, mask=None):
    idx = s.reference_read_indices
    side = Block(frame[:, idx], idx, "readout", read_phantom=phantom,
                 dq=None if mask is None else mask[:, idx])
    # the draws are the frames: the exposure's schedule has as many (the side values do not
    # depend on the frame count; the weights are the strategy's, for ``s``)
    exposure = Exposure.from_arrays(frame, s.replace(nframes=frame.shape[0]), mask=mask)
    return strat.estimate(side, ctx, exposure).rows[..., 0]  # (L, n_reads, nch)


@pytest.mark.parametrize("scan,domain", [("alternate", "slopes"), ("same", "frames")])
def test_monte_carlo_channel_mean_error_has_the_brute_force_variance(scan, domain, tmp_path):
    s = _schedule(scan, 2)
    comps = SLOPES if domain == "slopes" else FRAMES
    _, var, smp, k, _, _ = _brute_mean(s, comps, domain, False, 0, False, True)
    rng = np.random.default_rng(11)
    ndraws = 3000
    # the colored terms and the white ones drawn apart: the truth's side pixels get white
    # noise of their own (the light pixels a correction is for are other samples)
    colored = smp.covariance([c.replace(alpha=0.0) for c in comps], domain)
    white = {scope: np.sqrt(np.clip(np.diag(k[scope]) - np.diag(colored[scope]), 0, None))
             for scope in k}

    def white_draw():
        return (rng.standard_normal((ndraws, 4, smp.n)) * white["channel"]
                + rng.standard_normal((ndraws, 1, smp.n)) * white["common"])

    x = _draw(smp, colored, 4, ndraws, rng)
    w1 = white_draw()
    frame, phantom = _frames(smp, x + w1, rng)
    xt = x + w1
    _, sides = _groups(s.geometry, False, 0)
    off = s.geometry.column_offsets()
    w2 = white_draw()
    for ch in range(4):
        at = (s.active_read_indices[:, None] * smp.per + smp.c  # the side values' reads
              + off[sides[ch]][None, :]).ravel()
        xt[:, ch, at] = x[:, ch, at] + w2[:, ch, at]
    # the truth: each channel's pixel mean at every read, without the constants
    truth = xt.reshape(ndraws, 4, s.n_reads, smp.per)[..., smp.c:].mean(axis=-1)
    strat = _strategy(comps, tmp_path, domain=domain, side_columns=True)
    ctx = Context(s, "readout", True, has_phantom=True)
    rows = _run(strat, s, frame, phantom, ctx)
    err = rows.mean(axis=2) - truth.mean(axis=1)  # (draws, reads): constants cancel
    err -= err[:, s.reference_read_indices[:1]]  # ...up to one constant, taken out here
    active = s.active_read_indices
    # the same difference predicted by the brute force: error at an active read minus the
    # error at the first reference read (whose estimate is its own value: no error)
    assert np.allclose(var[s.reference_read_indices], 0, atol=1e-9 * var.max())
    ratio = (err[:, active] ** 2).mean(axis=0) / var[active]
    se = np.sqrt(2 / ndraws)
    assert abs(ratio.mean() - 1) < 4 * se / np.sqrt(active.size) + 0.02, ratio
    assert np.all(np.abs(ratio - 1) < 5 * se), ratio


def test_monte_carlo_strong_common_drift_side_columns_beat_the_reference_rows(tmp_path):
    """SIDECAR-like: reference rows read only at the start and end of the frame, a strong
    1/f common to every output; the side columns see it at every row."""
    comps = [NoiseComponent("white", alpha=2e-4),
             NoiseComponent("c_pink", alpha=0.0, beta=20.0, scope="common")]
    s = _schedule("alternate", 0, ref_mode="none", ref_reads=0)
    smp = Samples(s)
    k = smp.covariance(comps, "slopes")
    rng = np.random.default_rng(3)
    x = _draw(smp, k, 4, 1000, rng)
    frame, _ = _frames(smp, x, rng)
    truth = x.reshape(1000, 4, s.n_reads, smp.per).mean(axis=-1)
    ctx = Context(s, "readout", True, has_phantom=False)
    active = s.active_read_indices
    mse = {}
    for side in (False, True):
        strat = _strategy(comps, tmp_path, domain="slopes", side_columns=side)
        err = _run(strat, s, frame, None, ctx)[:, active] - np.moveaxis(truth, 1, 2)[:, active]
        # each channel's constant (unknown): out with the channel's mean error
        err -= err.mean(axis=1, keepdims=True)
        mse[side] = float((err ** 2).mean())
    assert mse[True] < 0.6 * mse[False], mse  # the model predicts 0.40


# -- robustness ----------------------------------------------------------------------------
@pytest.fixture
def drawn(tmp_path):
    """40 frames of 4 channels of 8 columns, 4 side columns in each outer channel: the
    draws, frames, truth and strategy (the clip at 5 robust deviations)."""
    s = _schedule("alternate", 0, border=4, width=8)
    smp = Samples(s)
    k = smp.covariance(SLOPES, "slopes")
    rng = np.random.default_rng(5)
    x = _draw(smp, k, 4, 40, rng)
    frame, _ = _frames(smp, x, rng, offset=50.0)
    truth = np.moveaxis(x.reshape(40, 4, s.n_reads, smp.per).mean(axis=-1), 1, 2)
    strat = _strategy(SLOPES, tmp_path, domain="slopes", side_columns=True, sigma=5.0)
    return s, frame, truth, strat, Context(s, "readout", True, has_phantom=False)


def _rms(a):
    return float(np.sqrt(np.mean(np.square(a))))


@pytest.mark.parametrize("where", ["side-pixels", "every-pixel"])
def test_a_fixed_bias_per_pixel_does_not_change_the_slopes_correction(where, drawn, tmp_path):
    """Raw-like: every pixel its own large level (300 e rms, the noise's rms is ~3000), the
    same in every frame; the side pixels' level is their median over frames, so the
    correction changes by a pattern constant over frames (no change to a slope).  On every
    pixel, the reference rows' clip is left out (sigma: 1e9): it is the reference reads'
    own robustness, not the side values'."""
    s, frame, _, strat, ctx = drawn
    g = s.geometry
    bias = np.random.default_rng(8).normal(0, 300.0, (g.nrows, g.ncols))[s.rows]
    if where == "side-pixels":
        bias[s.is_reference] = 0.0
        bias[:, ~g.reference_column_mask()] = 0.0
    else:
        strat = _strategy(SLOPES, tmp_path, domain="slopes", side_columns=True)
    clean = _run(strat, s, frame, None, ctx)
    biased = _run(strat, s, frame + bias, None, ctx)
    diff = biased - clean
    assert np.isfinite(diff).all()
    # constant across frames: the spread over frames is float rounding
    assert np.ptp(diff, axis=0).max() < 1e-9 * np.abs(frame).max(), np.ptp(diff, axis=0).max()
    if where == "every-pixel":  # the reference reads' bias moves each frame alike
        assert _rms(diff) > 1.0


def _close(bad, clean, truth, s, factor=0.15):
    """No NaN, and ``bad`` within ``factor`` of the clean estimate's own error."""
    active = s.active_read_indices
    assert np.isfinite(bad).all()
    err = clean[:, active] - truth[:, active]
    err -= err.mean(axis=1, keepdims=True)
    assert _rms(bad[:, active] - clean[:, active]) < factor * _rms(err), (
        _rms(bad[:, active] - clean[:, active]), _rms(err))


def test_a_flagged_side_pixel_is_left_out(drawn):
    s, frame, truth, strat, ctx = drawn
    clean = _run(strat, s, frame, None, ctx)
    mask = np.zeros(frame.shape, np.uint32)
    read = s.active_read_indices[3]
    bad = frame.copy()
    bad[:, read, 0] = 1e6  # flagged and absurd
    mask[:, read, 0] = dq.DO_NOT_USE
    out = _run(strat, s, bad, None, ctx, mask)
    _close(out, clean, truth, s)


def test_a_noisy_side_column_is_left_out_like_a_flagged_one(drawn):
    """A noisy side column (its own white noise 10x the drift's rms): left out, as if
    flagged."""
    s, frame, truth, strat, ctx = drawn
    clean = _run(strat, s, frame, None, ctx)
    noisy = frame.copy()
    col = s.geometry.ncols - 2
    noisy[..., col] += np.random.default_rng(2).normal(0, 10 * np.std(truth), frame.shape[:2])
    out = _run(strat, s, noisy, None, ctx)
    mask = np.zeros(frame.shape, np.uint32)
    mask[:, s.active_read_indices, col] = dq.DO_NOT_USE  # its side pixels only
    flagged = _run(strat, s, noisy, None, ctx, mask)
    np.testing.assert_allclose(out, flagged, rtol=0, atol=1e-9)
    _close(out, clean, truth, s, factor=0.3)  # one of 8 side pixels fewer: 0.17 measured


# the reference rows' clip (on values about the channel's median, a drift of 30 per read)
# leaves a whole read out in one channel now and then: that frame goes without side values
@pytest.mark.filterwarnings("ignore:correct_reference \\(wiener\\). .* without the side values")
@pytest.mark.parametrize("left,right", [(4, 3), (2, 1)])
def test_the_side_clip_leaves_out_almost_nothing_of_gaussian_data(left, right, tmp_path):
    """Side pixels with white noise about a drift shared by the channel's pixels: a clip at
    5 robust deviations should leave out ~6e-7 of the pixel reads (a deviation from the
    other pixels' median has the noise of a pixel, whatever the number of pixels; with 3
    the median of all 3 is one of them, and the deviations from it are not Gaussian)."""
    s = _schedule("same", 0, border={"top": 2, "bottom": 2, "left": left, "right": right},
                  width=8)
    g = s.geometry
    rng = np.random.default_rng(6)
    frame = (rng.normal(0, 3, (200, s.n_reads, g.ncols))
             + np.repeat(rng.normal(0, 30, (200, s.n_reads, 4)), 8, axis=2))
    strat = _strategy(SLOPES, tmp_path, domain="slopes", side_columns=True, sigma=5.0)
    ctx = Context(s, "readout", True, has_phantom=False)
    idx = s.reference_read_indices
    exposure = Exposure.from_arrays(frame, s.replace(nframes=200))
    meta = strat.estimate(Block(frame[:, idx], idx, "readout"), ctx, exposure
                          ).tables["REFDRIFT"].meta
    reads = 200 * s.active_read_indices.size * (left + right)
    assert meta["side_pixels_left_out"] == 0
    assert meta["side_reads_clipped"] <= 1e-4 * reads, (meta["side_reads_clipped"], reads)


def test_a_hot_side_pixel_read_is_clipped(drawn):
    """One pixel read far off in one frame (a cosmic ray on a side pixel)."""
    s, frame, truth, strat, ctx = drawn
    clean = _run(strat, s, frame, None, ctx)
    hot = frame.copy()
    hot[7, s.active_read_indices[5], 1] += 5e4
    out = _run(strat, s, hot, None, ctx)
    _close(out, clean, truth, s, factor=0.05)


def test_a_read_whose_side_pixels_are_all_flagged_is_filled(drawn):
    s, frame, truth, strat, ctx = drawn
    clean = _run(strat, s, frame, None, ctx)
    mask = np.zeros(frame.shape, np.uint32)
    cols = np.flatnonzero(s.geometry.reference_column_mask())
    for read in s.active_read_indices[[0, 8]]:  # the first active read, and one inside
        mask[:, read, cols] = dq.DO_NOT_USE
    out = _run(strat, s, np.where(mask != 0, np.nan, frame), None, ctx, mask)
    _close(out, clean, truth, s, factor=0.3)


@pytest.mark.parametrize("what", ["one-channel", "no-side-columns"])
def test_side_columns_change_nothing_without_them_or_with_one_channel(what, tmp_path):
    if what == "one-channel":
        s = _schedule("same", 2, nch=1, width=8)
    else:
        s = _schedule("alternate", 2, border={"top": 2, "bottom": 2})
    g = s.geometry
    rng = np.random.default_rng(4)
    frame = rng.normal(0, 3, (4, s.n_reads, g.ncols)) + np.cumsum(
        rng.normal(0, 1, (4, s.n_reads, 1)), axis=1)
    phantom = rng.normal(0, 3, (4, s.n_reads, g.nchannels))
    ctx = Context(s, "readout", True, has_phantom=True)
    idx = s.reference_read_indices
    side = Block(frame[:, idx], idx, "readout", read_phantom=phantom)
    off = _strategy(SLOPES, tmp_path, side_columns=False).estimate(side, ctx)
    on = _strategy(SLOPES, tmp_path, side_columns=True)
    assert on.side_groups(g) is None
    got = on.estimate(side, ctx, Exposure.from_arrays(frame, s))
    np.testing.assert_array_equal(got.rows, off.rows)
    assert got.tables["REFDRIFT"].meta["side_channels"] == ""


def test_a_window_is_refused_with_side_columns(tmp_path):
    from spherex_reduce.core.window import Window

    full = DetectorGeometry(64, 64, 4, ref_border=4)
    g = Window(0, 0, full).geometry(24, 16)  # the corner: the full array's left columns
    s = ReadoutSchedule(g, skip=1, ref_mode="none", phantom_reads=0, nframes=3,
                        frame_time=0.05)
    frame = np.zeros((3, s.n_reads, g.ncols))
    ctx = Context(s, "readout", True)
    idx = s.reference_read_indices
    strat = _strategy(SLOPES, tmp_path, side_columns=True)
    with pytest.raises(ConfigError, match="wiener does not model a window"):
        strat.estimate(Block(frame[:, idx], idx, "readout"), ctx,
                       Exposure.from_arrays(frame, s))


# -- the pipeline --------------------------------------------------------------------------
@pytest.mark.filterwarnings("ignore::astropy.io.fits.verify.VerifyWarning")
def test_the_cli_runs_side_columns_and_records_them(tmp_path):
    """``spherex-reduce reduce`` with side_columns: the parameter is in the header's step
    cards and the PROVENANCE row, the side channels in REFDRIFT; the side values change
    the correction (side_columns false on the same file gives another one)."""
    s = _schedule("alternate", 0)
    rng = np.random.default_rng(9)
    common = np.cumsum(rng.normal(0, 5, (4, s.n_reads, 1)), axis=1)  # shared by every output
    raw = write(Exposure.from_arrays(rng.normal(0, 3, (4, s.n_reads, 16)) + common, s),
                tmp_path / "raw.fits")
    _strategy(SLOPES, tmp_path)  # writes noise.ecsv
    sci = {}
    for side in ("true", "false"):
        cfg = tmp_path / f"{side}.yaml"
        cfg.write_text("steps:\n  - correct_reference: {strategy: wiener, side_columns: "
                       f"{side}, noise: {tmp_path / 'noise.ecsv'}}}\n")
        out = tmp_path / f"{side}.fits"
        assert run("reduce", raw, "-c", cfg, "-o", out) == 0
        with fits.open(out) as hdul:
            header = hdul[0].header
            assert header["REFSTRAT"] == "wiener" and header["S_REFCOR"] == "COMPLETE"
            assert header["SXR CORRECT_REFERENCE SIDE_COLUMNS"] is (side == "true")
            row = Table.read(hdul["PROVENANCE"])
            params = json.loads(row[list(row["step"]).index("correct_reference")]["parameters"])
            assert params["side_columns"] is (side == "true")
            # the side channels as one card (a list would be one card per item)
            channels = hdul["REFDRIFT"].header.get("side_channels")
            assert channels == ("0 3" if side == "true" else "")
            sci[side] = hdul["SCI"].data.astype(float)
    assert np.isfinite(sci["true"]).all()
    assert np.abs(sci["true"] - sci["false"]).max() > 1.0


def _sidecar_like():
    """Four outputs, side columns on the outer two, white noise and a common pink."""
    g = DetectorGeometry(24, 32, 4, ref_border=4, scan="alternate")
    s = ReadoutSchedule(g, skip=1, ref_mode="repeated", ref_reads=4, phantom_reads=0,
                        nframes=6)
    return g, s, [NoiseComponent("white", alpha=2e-4),
                  NoiseComponent("c_pink", beta=2.0, scope="common")]


def _offset_frames(rng, s, g, nframes=6, offset=10.0):
    """White frames with a large offset per frame and channel (8 columns per channel)."""
    return rng.normal(0, 1, (nframes, s.n_reads, g.ncols)) + np.repeat(
        rng.normal(0, offset, (nframes, 1, g.nchannels)), g.channel_width, axis=2)


def test_a_read_one_side_channel_misses_does_not_take_the_other_channels_offset(tmp_path):
    """Channel 0's side pixels flagged in one read: that read's side value is the other
    side channel's alone, which must not bring its frame offset (rms 10 against a pixel
    noise of 1) into every channel's correction (it moved it by 3.9)."""
    g, s, comps = _sidecar_like()
    frame = _offset_frames(np.random.default_rng(1), s, g)
    strat = _strategy(comps, tmp_path, side_columns=True, domain="slopes", sigma=5.0)
    ctx = Context(s, "readout", True, has_phantom=False)
    clean = _run(strat, s, frame, None, ctx)
    mask = np.zeros(frame.shape, np.uint32)
    mask[2, s.active_read_indices[7], :4] = dq.DO_NOT_USE
    flagged = _run(strat, s, frame, None, ctx, mask=mask)
    assert np.abs(flagged - clean).max() < 1.5  # the read lost half its side pixels


def test_reference_flags_leave_the_side_pixels_usable(tmp_path):
    """REFERENCE (and JUMP) alone leave a read usable, as for the reference rows: the side
    pixels of a file whose reference pixels are flagged REFERENCE give the same estimate."""
    g, s, comps = _sidecar_like()
    frame = _offset_frames(np.random.default_rng(2), s, g)
    strat = _strategy(comps, tmp_path, side_columns=True, domain="slopes")
    ctx = Context(s, "readout", True, has_phantom=False)
    mask = np.zeros(frame.shape, np.uint32)
    mask[..., g.reference_column_mask()] = dq.REFERENCE
    mask[:, s.reference_read_indices] = dq.REFERENCE
    np.testing.assert_allclose(_run(strat, s, frame, None, ctx, mask=mask),
                               _run(strat, s, frame, None, ctx), rtol=0, atol=1e-9)


def test_a_frame_that_falls_back_to_each_channels_weights_says_it_loses_the_side_values(
        tmp_path):
    """A reference read flagged in one channel only: that frame is estimated per channel,
    without the side values, and a one-line warning says so (it was silent)."""
    g, s, comps = _sidecar_like()
    frame = _offset_frames(np.random.default_rng(4), s, g)
    strat = _strategy(comps, tmp_path, side_columns=True, domain="slopes")
    ctx = Context(s, "readout", True, has_phantom=False)
    mask = np.zeros(frame.shape, np.uint32)
    mask[3, s.reference_read_indices[0], g.channel_width:2 * g.channel_width] = dq.DO_NOT_USE
    with pytest.warns(AstropyUserWarning, match=r"1 frame\(s\) .* without the side values"):
        rows = _run(strat, s, frame, None, ctx, mask=mask)
    assert np.isfinite(rows).all()


@pytest.mark.parametrize(("shape", "axis"), [((10, 64, 4), 2), ((10, 64, 3), 2),
                                             ((10, 64, 1), 2), ((7, 50, 4), 0)])
def test_the_side_values_short_medians_are_numpys(shape, axis):
    """The side values take medians over a channel's few side pixels and a dark's frames
    with a sort (numpy's masked-array path took ~0.1 s of an exposure): numpy's numbers,
    NaN, inf and all-NaN lines included."""
    import warnings

    from spherex_reduce.reduce.steps.reference.telegraph import nanmedian

    rng = np.random.default_rng(51)
    v = rng.normal(size=shape)
    v[rng.random(shape) < 0.25] = np.nan
    v[0, 0] = np.nan
    v.flat[7], v.flat[11] = np.inf, -np.inf
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # numpy's all-NaN slices
        want = np.nanmedian(v, axis=axis)
    np.testing.assert_array_equal(nanmedian(v, axis), want)
