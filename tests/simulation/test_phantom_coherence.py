"""A component seen by the pixels and the phantom reads is one realisation at every frequency.

The statistic is the change from one row read to the next of a channel's
pixel mean (``U``, per column parity with ACN) and of its phantom mean
(``V``): a difference over one read interval is driven by frequencies above
about a sixth of the row rate, far above the simulator's fast-tier crossover
``f_B / 2`` (``f_B`` = row rate / 32 here), so it measures the coherence of the
fast tier.  The expectation is written here from the structure function of the
sampled stream, ``D(lag) = alpha fs + 2 beta Cin(pi lag)`` (lag > 0, samples):
for zero-sum coefficients ``a``, ``b`` on one realisation,
``Cov(a.x, b.x) = -1/2 sum_ij a_i b_j D(t_i - s_j)``, summed over the
realisations a pair shares (the even and the odd one with ACN, where a sample
at position ``q`` of its read belongs to parity ``(q - c) % 2``).
"""

import numpy as np
import pytest
from scipy import special

from spherex_reduce.io.config import schedule_from_config
from spherex_reduce.simulation import NoiseComponent, NoiseEngine


def _structure(comp, lag, fs):
    lag = np.abs(np.asarray(lag, dtype=float))
    x = np.pi * np.maximum(lag, 1e-300)
    ci = special.sici(x)[1]
    cin = np.euler_gamma + np.log(x) - ci
    return np.where(lag > 0, comp.alpha * fs + 2 * comp.beta * cin, 0.0)


def _schedule(c, nframes, scan="same"):
    return schedule_from_config(
        {"nrows": 32, "ncols": 128, "nchannels": 8, "ref_border": 0, "scan": scan},
        {"skip": 1, "ref_reads": 0, "phantom_reads": c, "row_overhead": 0,
         "frame_overhead": 0, "nframes": nframes})


def _functional(kind, parity, s):
    """Sample times (relative to the later read's start), parities and coefficients of U or V."""
    c, rs, w = s.phantom_reads, s.row_samples, s.geometry.channel_width
    if kind == "pixels":
        pos = c + np.arange(w)
        if parity is not None:
            pos = pos[(pos - c) % 2 == parity]
    else:
        pos = np.arange(c)
    coef = np.full(pos.size, 1.0 / pos.size)
    par = np.tile((pos - c) % 2, 2)
    return np.concatenate([pos, pos - rs]), par, np.concatenate([coef, -coef])


def _expected_cov(comps, qa, qb, s):
    """Cov(A, B) of two functionals ``(kind, parity)`` of the same read and channel."""
    fs = s.geometry.pixel_rate
    total = 0.0
    for comp in comps:
        seen = {"pixels": comp.seen_by_pixels, "phantom": comp.seen_by_phantom}
        if not (seen[qa[0]] and seen[qb[0]]):
            continue
        if qa[0] != qb[0] and comp.visibility != "both":
            continue
        ta, pa, a = _functional(*qa, s)
        tb, pb, b = _functional(*qb, s)
        for p in ((0, 1) if comp.acn else (None,)):
            ma = np.ones(ta.size, bool) if p is None else pa == p
            mb = np.ones(tb.size, bool) if p is None else pb == p
            d = _structure(comp, ta[ma][:, None] - tb[mb][None, :], fs)
            total += -0.5 * float(a[ma] @ d @ b[mb])
    return total


def _measured(engine, s, parities):
    """Sample covariances of (U_p, V), (U_p, U_p), (V, V) over reads, channels, frames."""
    w, nch = s.geometry.channel_width, s.geometry.nchannels
    off = s.geometry.column_offsets().reshape(nch, w)
    us, vs = {p: [] for p in parities}, []
    for pix, ph in engine.frames():
        pix = np.asarray(pix, dtype=float).reshape(-1, nch, w)
        vs.append(np.diff(ph, axis=0))
        for p in parities:
            sel = np.ones((nch, w), bool) if p is None else (off % 2 == p)
            mean = np.stack([pix[:, ch, sel[ch]].mean(axis=1) for ch in range(nch)], axis=1)
            us[p].append(np.diff(mean, axis=0))
    v = np.concatenate(vs).ravel()
    out = {"VV": float(np.mean(v * v))}
    for p in parities:
        u = np.concatenate(us[p]).ravel()
        out[p, "UV"] = float(np.mean(u * v))
        out[p, "UU"] = float(np.mean(u * u))
    return out, v.size


BOTH_ACN = NoiseComponent("both_acn", alpha=2e-7, beta=2e-2, scope="channel",
                          visibility="both", acn=True)


@pytest.mark.parametrize("c, scan, comps", [
    # odd row_samples: the ACN realisations drawn at full rate; the one phantom sample is odd
    (1, "same", [BOTH_ACN]),
    # even row_samples: ACN at half rate; pixels-only and phantom-only terms drawn apart;
    # every second channel read right to left (column parity in the read's time order)
    (2, "alternate", [BOTH_ACN,
         NoiseComponent("pix", alpha=1e-6, beta=1e-2, scope="channel", visibility="pixels",
                        acn=True),
         NoiseComponent("ph", alpha=1e-6, beta=5e-3, scope="channel", visibility="phantom")]),
    # one stream for all channels, without ACN
    (4, "same", [NoiseComponent("both_common", alpha=1e-7, beta=3e-2, scope="common",
                        visibility="both"),
         NoiseComponent("pix_common", alpha=1e-6, beta=1e-3, scope="common",
                        visibility="pixels")]),
], ids=["acn-c1", "acn-c2-mixed", "common-c4"])
def test_pixels_and_phantom_share_the_fast_tier(c, scan, comps):
    """Read-to-read changes of the pixel and phantom means covary as one stream predicts.

    Tolerance: 4 standard errors of a sample covariance from ``n`` values
    (``sqrt((var_U var_V + cov^2) / n)``), ``n`` halved for the overlap of
    consecutive differences and divided by the channels for a common stream,
    plus 3 % for the simulator's slow-tier interpolation.  Drawing the fast
    tier of the phantom means apart from the pixels' (the former simulator)
    leaves ``Cov(U, V)`` near zero, 6 to 15 standard errors below.
    """
    s = _schedule(c, nframes=64, scan=scan)
    assert (s.geometry.scan_directions < 0).any() == (scan == "alternate")
    engine = NoiseEngine(s, comps, seed=7)
    parities = (0, 1) if any(cp.acn for cp in comps) else (None,)
    got, n = _measured(engine, s, parities)
    if all(cp.scope == "common" for cp in comps):
        n /= s.geometry.nchannels
    n /= 2
    vv = _expected_cov(comps, ("phantom", None), ("phantom", None), s)
    assert got["VV"] == pytest.approx(vv, rel=4 * np.sqrt(2 / n) + 0.03)
    for p in parities:
        uu = _expected_cov(comps, ("pixels", p), ("pixels", p), s)
        uv = _expected_cov(comps, ("pixels", p), ("phantom", None), s)
        assert got[p, "UU"] == pytest.approx(uu, rel=4 * np.sqrt(2 / n) + 0.03)
        se = np.sqrt((uu * vv + uv**2) / n)
        assert abs(got[p, "UV"] - uv) <= 4 * se + 0.03 * abs(uv), (p, got[p, "UV"], uv, se)
        # with ACN and one phantom sample (odd), the even columns share nothing with it
        assert uv > 6 * se or (c == 1 and p == 0 and uv == 0)


@pytest.mark.parametrize("overhead", [0, 20_000], ids=["blocks-of-frames", "one-frame-blocks"])
def test_tiered_slopes_share_the_fast_tier(overhead):
    """The same in slope mode on the tiered route: the least-squares slopes of U and V.

    With a 20 000-sample frame overhead a frame outlasts the fast tier's
    correlation, so the slope's fast part is one frame-length stream (its
    phantom means from the same stream); without it the frames' blocks are
    fitted.  The expectation sums the structure function over the samples of
    all frames, each weighted by its frame's least-squares weight (1/s).
    Tolerances as above (the slopes of one draw counted as independent
    values, halved for the overlap of the differences).
    """
    c, nframes, draws = 2, 6, 24
    s = schedule_from_config(
        {"nrows": 32, "ncols": 128, "nchannels": 8, "ref_border": 0},
        {"skip": 1, "ref_reads": 0, "phantom_reads": c, "row_overhead": 0,
         "frame_overhead": overhead, "nframes": nframes})
    comps = [BOTH_ACN, NoiseComponent("pix", alpha=1e-6, beta=1e-2, scope="channel",
                                      visibility="pixels", acn=True)]
    t = np.arange(nframes) * s.frame_samples / s.geometry.pixel_rate
    w = (t - t.mean()) / np.sum((t - t.mean()) ** 2)
    nch, width = s.geometry.nchannels, s.geometry.channel_width
    off = s.geometry.column_offsets().reshape(nch, width)
    uvs, uus, vvs = {0: [], 1: []}, {0: [], 1: []}, []
    for seed in range(draws):
        eng = NoiseEngine(s, comps, seed=seed, slope_route="tiered")
        assert (eng.block == 1) == (overhead > 0)
        pix, ph = eng.slopes()
        pix = np.asarray(pix, dtype=float).reshape(-1, nch, width)
        v = np.diff(ph, axis=0)
        vvs.append(v * v)
        for p in (0, 1):
            mean = np.stack([pix[:, ch, off[ch] % 2 == p].mean(axis=1) for ch in range(nch)],
                            axis=1)
            u = np.diff(mean, axis=0)
            uvs[p].append(u * v)
            uus[p].append(u * u)
    n = draws * (s.n_reads - 1) * nch / 2
    fs = s.geometry.pixel_rate

    def expected(qa, qb):
        total = 0.0
        for comp in comps:
            if "phantom" in (qa[0], qb[0]) and comp.visibility != "both":
                continue
            ta, pa, a = _functional(*qa, s)
            tb, pb, b = _functional(*qb, s)
            for q in (0, 1):
                ma, mb = pa == q, pb == q
                fa = (np.arange(nframes)[:, None] * s.frame_samples + ta[ma]).ravel()
                fb = (np.arange(nframes)[:, None] * s.frame_samples + tb[mb]).ravel()
                ca, cb = np.outer(w, a[ma]).ravel(), np.outer(w, b[mb]).ravel()
                total += -0.5 * float(ca @ _structure(comp, fa[:, None] - fb[None, :], fs) @ cb)
        return total

    vv = expected(("phantom", None), ("phantom", None))
    assert np.mean(vvs) == pytest.approx(vv, rel=4 * np.sqrt(2 / n) + 0.03)
    for p in (0, 1):
        uu = expected(("pixels", p), ("pixels", p))
        uv = expected(("pixels", p), ("phantom", None))
        assert np.mean(uus[p]) == pytest.approx(uu, rel=4 * np.sqrt(2 / n) + 0.03)
        se = np.sqrt((uu * vv + uv**2) / n)
        assert uv > 6 * se
        assert abs(np.mean(uvs[p]) - uv) <= 4 * se + 0.03 * abs(uv), (p, np.mean(uvs[p]), uv, se)
