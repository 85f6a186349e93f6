"""What a slope marginalised over "no jump" and "a jump at read k" would buy (issue 35).

A numpy study, not the pipeline: white read noise (10 e, 74 reads of 1.5 s by default,
``--reads``; no dark), four populations of ramps:

* clean ramps;
* *hit*: one jump of log-uniform amplitude 10-1e4 e at a random read;
* *mid*: one jump of 10-30 e in the middle third of the ramp (the issue's
  "jumps nobody can see"; on 4 reads always at read 1);
* *hot*: clean ramps whose rate is 50 sigma0 above the others';
* *warm*: clean ramps whose rate is 2 to 8 sigma0 above the others' (uniform): a step at
  mid-ramp and such a slope are nearly the same change of the reads.

``--rate-spread S`` gives the clean, hit and mid ramps true rates spread by S sigma0
(a dark whose current varies, or a sky); errors are taken about each ramp's own rate.

Estimators of the slope and its error:

* *detect*: a jump where the largest matched-filter ``|z_k|`` (a step at read k with
  the slope free, read noise known) reaches 4; the two-segment slope at that read
  (a step of free amplitude), else the line's.  This is what ``detect_jumps`` +
  ``fit_ramp`` do for one jump on such ramps.
* *marginal, p*: the posterior mean and standard deviation of the slope over "no
  jump" (prior 1 - p) and "a jump at read k" (p / 73 each), the amplitude a scale
  mixture of Gaussians (sigma 10, 30, ..., 1e4 e, equal weights), the line's
  intercept and slope flat.  Each model's evidence and slope are exact for white
  noise (the step's amplitude is independent of the line's slope given the
  residuals).
* *flagged jump, marginal over k*: as *detect* where it flags, but the flagged
  ramps take the posterior over the jump's read (no "no jump"), the others the
  marginal one.
* *detect, bulk's slope*: as *detect*, but the search tests a step against the line whose
  slope has the prior N(m, tau**2), the bulk's: m the median of the line slopes of an
  exposure of the clean ramps with 1 % of each other population, tau**2 their MAD**2
  less the line's noise (the true rates' spread; on a flat dark the 4 % of outliers
  make it ~0.3 sigma0), so a step at mid-ramp is no longer nearly degenerate with a
  change of slope.  A ramp whose two-segment slope at the prior search's best step is
  `OWN_SIGMA` sigmas off m (a hot pixel, a source) keeps the slope-free search.  The
  flagged ramps' slope is still the two-segment fit with the slope free (the bulk
  informs the search, never a slope).  At 4 sigma, and at the threshold whose false
  alarms on the clean ramps are *detect*'s (calibrated on the prior's statistic alone).
* *bulk's slope, odds*: instead of the guard, a step against the bulk's slope is flagged
  where the posterior odds of "a bulk ramp with a step" (the jump rate, 3 %, spread over
  the reads; the amplitude prior of *marginal*) over "no step" reach ``K`` (ln K = 0, 2,
  4), "no step" being a bulk ramp or a ramp of the exposure's warm tail with its own
  slope: the tail's density is the excess of the upper side of the exposure's
  two-segment slopes (each ramp's best prior step taken out, so that stepped bulk ramps
  stay in the bulk) over the mirrored lower side, in bins of 2 sigma0, floored at 1e-4
  of the ramps spread over 80 sigma0.  The slope-free search's flags are kept as well.
  ``--warm-share F``: the warm ramps' share of the bulk's exposure (default 0.01).

Columns: clean rms of (slope - truth) / sigma0; pull rms (slope - truth) / error on
clean ramps, and on the clean ramps the estimator flags; wrong (> 5 sigma0) and > 5
errors among *hit*; mean error of *mid* (sigma0) and its > 5 errors; the *hot* and
*warm* ramps flagged.

Run: ``python benchmarks/bench_jump_marginal.py [--clean 300000] [--seed 2]
[--rate-spread S] [--reads N] [--warm-share F]`` (about a
minute; the ramps are weighed in parts of `CHUNK`, ~0.5 GB at the peak).
"""

import argparse

import numpy as np
from scipy.special import logsumexp

READS, DT, RN, THRESHOLD = 74, 1.5, 10.0, 4.0
JUMP_RATE = 0.03  #: *bulk's slope, odds*: the share of ramps with a jump
#: a ramp whose two-segment slope at the prior search's best step is this many sigmas off
#: the bulk's is searched with its slope free
OWN_SIGMA = 4.0
TAUS = np.array([10, 30, 100, 300, 1000, 3000, 10000.0])
CHUNK = 10000  #: ramps whose models are weighed at once (~0.3 GB of float64 arrays at 74 reads)


def steps(n):
    """``(n - 1, n)``: row k - 1 a step at read k (1 from read k on)."""
    return (np.arange(n)[None, :] >= np.arange(1, n)[:, None]).astype(float)


def design(n):
    """Centred times of ``n`` reads, the line's residual maker applied to each step, and per
    read k: ``q_k`` (step variance / RN**2 inverse), ``c_k`` (slope change per unit step)."""
    N = n  # the ramps' length, as in the formulas
    t = np.arange(N) * DT
    tc = t - t.mean()
    x = np.stack([np.ones(N), tc], 1)
    m = np.eye(N) - x @ np.linalg.solve(x.T @ x, x.T)
    h = steps(N)
    mh = h @ m
    return tc, mh, (mh * h).sum(1), (h @ tc) / (tc @ tc)


def prior_model(tc, tau):
    """``(g, q)`` of a step at every read against a line of free intercept whose slope has
    a prior of spread ``tau``: generalised least squares with the noise RN**2 I + tau**2 tc
    tc'; a step's ``R_k = g_k' y`` (the reads less the prior's line), its variance ``q_k``."""
    N = tc.size
    r = tau ** 2 / RN ** 2
    cinv = (np.eye(N) - np.outer(tc, tc) * r / (1 + r * (tc @ tc))) / RN ** 2
    one = cinv.sum(0)
    m1 = cinv - np.outer(one, one) / one.sum()  # the intercept's GLS residual maker
    h = steps(N)
    g = h @ m1
    return g, (g * h).sum(1)


def prior_z2(y, tc, slope, model):
    """``z_k**2`` of a step at every read k (m, N - 1) of ramps ``y`` against the line of
    slope ``slope`` under ``model`` (`prior_model`)."""
    g, q = model
    return ((y - slope * tc[None, :]) @ g.T) ** 2 / q


def bulk_search(y, tc, slope, tau):
    """``z_k`` of a step at every read k (m, N - 1) against a line of free intercept whose
    slope has the prior N(``slope``, ``tau``**2) (the bulk's median and the spread of its
    true rates)."""
    g, q = prior_model(tc, tau)
    return ((y - slope * tc[None, :]) @ g.T) / np.sqrt(q)


def odds_of_step(y, tc, mh, q, c, ctx):
    """ln posterior odds of "a bulk ramp with a step" over "no step" (a bulk ramp, or one
    of the warm tail with its own slope), and the prior search's best read, for ramps
    ``y``; ``ctx`` the bulk (median, spread, the prior model) and the tail's density."""
    N = tc.size
    sig0 = RN / np.sqrt(tc @ tc)
    slope, tau, g, qb, density = ctx
    b0 = (y @ tc) / (tc @ tc)
    zb2 = prior_z2(y, tc, slope, (g, qb))
    vb = 1.0 / qb
    s2 = sig0 ** 2 + tau ** 2
    # each evidence over the free line's: a bulk ramp without a step, with one at k (the
    # amplitude a scale mixture), a warm one with its own slope
    clean = np.log(sig0 / np.sqrt(s2)) - (b0 - slope) ** 2 / (2 * s2)
    lk = logsumexp(np.stack([0.5 * np.log(vb / (vb + t ** 2)) + 0.5 * zb2 * t ** 2
                             / (t ** 2 + vb) for t in TAUS]), axis=0) - np.log(TAUS.size)
    step = np.log(JUMP_RATE / (N - 1)) + clean + logsumexp(lk, axis=1)
    warm = np.log(np.sqrt(2 * np.pi) * sig0 * density(b0))
    return step - np.logaddexp(np.log1p(-JUMP_RATE) + clean, warm), np.argmax(zb2, 1)


def warm_tail(y, tc, mh, q, c, slope, g, qb):
    """The density (per unit slope, a share of the ramps) of the exposure's ramps off its
    bulk: the excess of the upper side of their two-segment slopes at each one's best prior
    step over the mirrored lower side, in bins of 2 sigma0 up to 80 sigma0, floored."""
    sig0 = RN / np.sqrt(tc @ tc)
    parts = []
    for lo in range(0, y.shape[0], CHUNK):
        part = y[lo:lo + CHUNK]
        amp = (part @ mh.T) / q
        k = np.argmax(prior_z2(part, tc, slope, (g, qb)), 1)
        parts.append((part @ tc) / (tc @ tc) - c[k] * amp[np.arange(part.shape[0]), k])
    u = np.concatenate(parts) - slope
    width = 2 * sig0
    edges = np.arange(0.0, 80 * sig0 + width, width)
    upper, _ = np.histogram(u, edges)
    lower, _ = np.histogram(-u, edges)
    dens = np.maximum(upper - lower, 0) / (u.size * width)
    floor = 1e-4 / (80 * sig0)

    def density(b):
        i = np.clip(((b - slope) // width).astype(int), 0, dens.size - 1)
        return np.maximum(np.where(b >= slope, dens[i], 0.0), floor)

    return density, float(dens.sum() * width)


def estimates(y, p, tc, mh, q, c, mode, bulk=None, threshold=THRESHOLD):
    """(slope, error, flagged) of ramps ``y`` (m, N) for ``mode`` in detect / marginal /
    flagged / bulk (``bulk``: the bulk's median slope and true rates' spread; ``threshold``
    the bulk search's, sigma)."""
    N = tc.size
    s = tc @ tc
    sig0 = RN / np.sqrt(s)
    b0 = (y @ tc) / s
    amp = (y @ mh.T) / q
    v = RN ** 2 / q
    z2 = amp ** 2 / v
    m = y.shape[0]
    if mode == "odds":  # the bulk's step where its odds reach exp(threshold)
        odds, kb = odds_of_step(y, tc, mh, q, c, bulk)
        via = odds >= threshold
        flagged = via | (z2.max(1) >= THRESHOLD ** 2)
        kk = np.where(via, kb, np.argmax(z2, 1))
    elif mode == "bulk":  # the search against the bulk's slope
        slope, tau = bulk
        zb = bulk_search(y, tc, slope, tau) ** 2
        # a ramp whose two-segment slope at the prior search's best step is off the bulk
        # (a hot pixel, a source) keeps the search with its slope free (at the slope-free
        # search's best step instead, a 10-30 e step the slope-free search places at the
        # wrong read sent 8 % of the mid-ramp hits back to it)
        kf = np.argmax(zb, 1)
        own = (np.abs(b0 - c[kf] * amp[np.arange(m), kf] - slope)
               > OWN_SIGMA * np.sqrt(sig0 ** 2 + c[kf] ** 2 * v[kf] + tau ** 2))
        zb[own] = z2[own]
        flagged, kk = zb.max(1) >= threshold ** 2, np.argmax(zb, 1)
    else:
        flagged, kk = z2.max(1) >= THRESHOLD ** 2, np.argmax(z2, 1)
    rows = np.arange(m)
    seg = b0 - c[kk] * amp[rows, kk]
    seg_err = np.sqrt(sig0 ** 2 + c[kk] ** 2 * v[kk])
    if mode in ("detect", "bulk", "odds"):
        return np.where(flagged, seg, b0), np.where(flagged, seg_err, sig0), flagged
    lw, bs, vs = [np.full((m, 1), np.log1p(-p))], [b0[:, None]], [np.full((m, 1), sig0 ** 2)]
    for tau in TAUS:
        shrink = tau ** 2 / (tau ** 2 + v)
        lw.append(np.log(p / (N - 1) / TAUS.size) + 0.5 * np.log(v / (v + tau ** 2))
                  + 0.5 * z2 * shrink)
        bs.append(b0[:, None] - c * amp * shrink)
        vs.append(np.broadcast_to(sig0 ** 2 + c ** 2 * v * shrink, (m, N - 1)))
    lw, bs, vs = (np.concatenate(a, 1) for a in (lw, bs, vs))

    def posterior(logw):
        w = np.exp(logw - logw.max(1, keepdims=True))
        w /= w.sum(1, keepdims=True)
        mean = (w * bs).sum(1)
        return mean, np.sqrt((w * (vs + (bs - mean[:, None]) ** 2)).sum(1))

    mean, err = posterior(lw)
    if mode == "flagged":
        jump = lw.copy()
        jump[:, 0] = -np.inf
        jm, je = posterior(jump)
        mean, err = np.where(flagged, jm, mean), np.where(flagged, je, err)
    return mean, err, flagged


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--clean", type=int, default=300000)
    ap.add_argument("--hit", type=int, default=30000)
    ap.add_argument("--seed", type=int, default=2)
    ap.add_argument("--reads", type=int, default=READS, help="reads per ramp (at least 4)")
    ap.add_argument("--warm-share", type=float, default=0.01,
                    help="the warm ramps' share of the bulk's exposure (default 0.01)")
    ap.add_argument("--rate-spread", type=float, default=0.0,
                    help="true rates of the clean, hit and mid ramps spread by this many "
                    "sigma0 (Gaussian; 0: a flat dark)")
    a = ap.parse_args(argv)
    if a.reads < 4:
        ap.error("--reads must be at least 4")
    if not 0 <= a.warm_share <= a.hit / a.clean:
        ap.error(f"--warm-share must be in [0, {a.hit / a.clean:g}] (the warm ramps drawn: "
                 "as many as --hit)")
    N = a.reads
    rng = np.random.default_rng(a.seed)
    tc, mh, q, c = design(N)
    sig0 = RN / np.sqrt(tc @ tc)
    reads = np.arange(N)[None, :]
    clean = rng.normal(0, RN, (a.clean, N))
    amp = 10 ** rng.uniform(1, 4, a.hit)
    hit = rng.normal(0, RN, (a.hit, N)) + amp[:, None] * (
        reads >= rng.integers(1, N, a.hit)[:, None])
    amp = rng.uniform(10, 30, a.hit)
    mid = rng.normal(0, RN, (a.hit, N)) + amp[:, None] * (
        reads >= rng.integers(N // 3, 2 * N // 3, a.hit)[:, None])
    header = ("| estimator | clean rms (σ0) | clean pull rms | pull rms, falsely flagged "
              "| hit wrong | hit > 5 err | mid mean error (σ0) | mid > 5 err | hot flagged "
              "| warm flagged |\n|---|---|---|---|---|---|---|---|---|---|")
    def of(y, p, mode, threshold=THRESHOLD):  # in parts of CHUNK ramps: the models' arrays
        ctx = context if mode == "odds" else bulk
        parts = [estimates(y[lo:lo + CHUNK], p, tc, mh, q, c, mode, ctx, threshold)
                 for lo in range(0, y.shape[0], CHUNK)]  # are (ramps, 512)
        return (np.concatenate(a) for a in zip(*parts, strict=True))

    # rates spread about zero (a sky, or a dark whose current varies); errors are taken
    # about each ramp's own rate below
    truth = {}
    for name, y in (("clean", clean), ("hit", hit), ("mid", mid)):
        truth[name] = a.rate_spread * sig0 * rng.standard_normal(y.shape[0])
        y += truth[name][:, None] * tc[None, :]
    # hot pixels: clean ramps whose rate is 50 sigma0 above the others' (1 % of the array)
    hot = rng.normal(0, RN, (a.hit, N)) + 50 * sig0 * tc[None, :]
    warm = (rng.normal(0, RN, (a.hit, N))
            + rng.uniform(2, 8, a.hit)[:, None] * sig0 * tc[None, :])
    # the bulk: the median of the line slopes of an exposure of the clean ramps with 1 % of
    # them hit, 1 % hit at mid-ramp, 1 % hot and 1 % warm (the populations' first ramps), the
    # spread of the true rates, its MAD squared less the line's noise
    few = max(1, a.clean // 100)
    nwarm = min(warm.shape[0], round(a.warm_share * a.clean))
    exposure = np.concatenate([clean, hit[:few], mid[:few], hot[:few], warm[:nwarm]])
    slopes = exposure @ tc / (tc @ tc)
    med = float(np.median(slopes))
    mad = 1.482602218505602 * float(np.median(np.abs(slopes - med)))
    bulk = (med, float(np.sqrt(max(mad ** 2 - sig0 ** 2, 0.0))))
    # the odds' context: the bulk from the lower side of the slopes, the prior model at
    # its spread (floored at 0.1 sigma0), the warm tail's density
    low = med - slopes
    spread = np.sqrt(max((1.482602218505602 * np.median(low[low > 0])) ** 2 - sig0 ** 2,
                         0.0))
    tau_w = max(spread, 0.1 * sig0)
    g, qb = prior_model(tc, tau_w)
    density, share = warm_tail(exposure, tc, mh, q, c, med, g, qb)
    context = (med, tau_w, g, qb, density)
    del exposure, slopes, low
    _, _, fc_detect = of(clean, 0.0, "detect")
    # the threshold of the bulk's search whose false alarms on the clean ramps are detect's
    zc = np.concatenate([bulk_search(clean[lo:lo + CHUNK], tc, *bulk)
                         for lo in range(0, clean.shape[0], CHUNK)])
    matched = float(np.quantile(np.abs(zc).max(1), 1 - fc_detect.mean()))
    del zc
    print(f"bulk: median slope {med / sig0:+.4f} σ0, true rates' spread {bulk[1] / sig0:.4f} "
          f"σ0 (from their MAD), {spread / sig0:.4f} σ0 (below the median); warm tail "
          f"{share:.4f} of the ramps (warm share given "
          f"{nwarm / (a.clean + 3 * few + nwarm):.4f})\n")
    for mode, p, thr in (("detect", 0.0, THRESHOLD), ("marginal", 0.01, None),
                         ("marginal", 0.03, None), ("marginal", 0.1, None),
                         ("flagged", 0.03, None), ("flagged", 0.1, None),
                         ("bulk", 0.0, THRESHOLD), ("bulk", 0.0, matched),
                         ("odds", 0.0, 0.0), ("odds", 0.0, 2.0), ("odds", 0.0, 4.0)):
        thr = THRESHOLD if thr is None else thr
        bc, ec, fc = of(clean, p, mode, thr)
        bh, eh, _ = of(hit, p, mode, thr)
        bm, em, _ = of(mid, p, mode, thr)
        bc, bh, bm = bc - truth["clean"], bh - truth["hit"], bm - truth["mid"]
        _, _, fhot = of(hot, p, mode, thr)
        _, _, fwarm = of(warm, p, mode, thr)
        if header:
            print(header)
            header = None
        name = (mode if mode == "detect" else f"detect, bulk's slope, {thr:.2f}σ"
                if mode == "bulk" else f"bulk's slope, odds, ln K = {thr:g}"
                if mode == "odds" else f"{mode}, p = {p:g}")
        print(f"| {name} | {np.std(bc) / sig0:.3f} | {np.sqrt(np.mean((bc / ec) ** 2)):.3f} "
              f"| {np.sqrt(np.mean((bc[fc] / ec[fc]) ** 2)):.2f} ({fc.mean():.2%}) "
              f"| {np.mean(abs(bh) > 5 * sig0):.2%} | {np.mean(abs(bh) > 5 * eh):.2%} "
              f"| {np.mean(bm) / sig0:+.3f} | {np.mean(abs(bm) > 5 * em):.2%} "
              f"| {fhot.mean():.2%} | {fwarm.mean():.2%} |")


if __name__ == "__main__":
    main()
