"""What a slope marginalised over "no jump" and "a jump at read k" would buy (issue 35).

A numpy study, not the pipeline: white read noise (10 e, 74 reads of 1.5 s, no dark),
three populations of ramps:

* clean ramps;
* *hit*: one jump of log-uniform amplitude 10-1e4 e at a random read;
* *mid*: one jump of 10-30 e in the middle third of the ramp (the issue's
  "jumps nobody can see").

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

Columns: clean rms of (slope - truth) / sigma0; pull rms (slope - truth) / error on
clean ramps, and on the clean ramps *detect* flags; wrong (> 5 sigma0) and > 5
errors among *hit*; mean error of *mid* (sigma0) and its > 5 errors.

Run: ``python benchmarks/bench_jump_marginal.py [--clean 300000] [--seed 2]`` (about a
minute; the ramps are weighed in parts of `CHUNK`, ~0.5 GB at the peak).
"""

import argparse

import numpy as np

N, DT, RN, THRESHOLD = 74, 1.5, 10.0, 4.0
TAUS = np.array([10, 30, 100, 300, 1000, 3000, 10000.0])
CHUNK = 10000  #: ramps whose models are weighed at once (~0.3 GB of float64 arrays)


def design():
    """Centred times, the line's residual maker applied to each step, and per read k:
    ``q_k`` (step variance / RN**2 inverse), ``c_k`` (slope change per unit step)."""
    t = np.arange(N) * DT
    tc = t - t.mean()
    x = np.stack([np.ones(N), tc], 1)
    m = np.eye(N) - x @ np.linalg.solve(x.T @ x, x.T)
    h = (np.arange(N)[None, :] >= np.arange(1, N)[:, None]).astype(float)
    mh = h @ m
    return tc, mh, (mh * h).sum(1), (h @ tc) / (tc @ tc)


def estimates(y, p, tc, mh, q, c, mode):
    """(slope, error, flagged) of ramps ``y`` (m, N) for ``mode`` in detect / marginal /
    flagged."""
    s = tc @ tc
    sig0 = RN / np.sqrt(s)
    b0 = (y @ tc) / s
    amp = (y @ mh.T) / q
    v = RN ** 2 / q
    z2 = amp ** 2 / v
    m = y.shape[0]
    flagged = z2.max(1) >= THRESHOLD ** 2
    kk = np.argmax(z2, 1)
    rows = np.arange(m)
    seg = b0 - c[kk] * amp[rows, kk]
    seg_err = np.sqrt(sig0 ** 2 + c[kk] ** 2 * v[kk])
    if mode == "detect":
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
    a = ap.parse_args(argv)
    rng = np.random.default_rng(a.seed)
    tc, mh, q, c = design()
    sig0 = RN / np.sqrt(tc @ tc)
    reads = np.arange(N)[None, :]
    clean = rng.normal(0, RN, (a.clean, N))
    amp = 10 ** rng.uniform(1, 4, a.hit)
    hit = rng.normal(0, RN, (a.hit, N)) + amp[:, None] * (
        reads >= rng.integers(1, N, a.hit)[:, None])
    amp = rng.uniform(10, 30, a.hit)
    mid = rng.normal(0, RN, (a.hit, N)) + amp[:, None] * (
        reads >= rng.integers(N // 3, 2 * N // 3, a.hit)[:, None])
    print("| estimator | clean rms (σ0) | clean pull rms | pull rms, falsely flagged "
          "| hit wrong | hit > 5 err | mid mean error (σ0) | mid > 5 err |")
    print("|---|---|---|---|---|---|---|---|")
    def of(y, p, mode):  # in parts of CHUNK ramps: the models' arrays are (ramps, 512)
        parts = [estimates(y[lo:lo + CHUNK], p, tc, mh, q, c, mode)
                 for lo in range(0, y.shape[0], CHUNK)]
        return (np.concatenate(a) for a in zip(*parts, strict=True))

    for mode, p in (("detect", 0.0), ("marginal", 0.01), ("marginal", 0.03),
                    ("marginal", 0.1), ("flagged", 0.03), ("flagged", 0.1)):
        bc, ec, fc = of(clean, p, mode)
        bh, eh, _ = of(hit, p, mode)
        bm, em, _ = of(mid, p, mode)
        name = mode if mode == "detect" else f"{mode}, p = {p:g}"
        print(f"| {name} | {np.std(bc) / sig0:.3f} | {np.sqrt(np.mean((bc / ec) ** 2)):.3f} "
              f"| {np.sqrt(np.mean((bc[fc] / ec[fc]) ** 2)):.2f} ({fc.mean():.2%}) "
              f"| {np.mean(abs(bh) > 5 * sig0):.2%} | {np.mean(abs(bh) > 5 * eh):.2%} "
              f"| {np.mean(bm) / sig0:+.3f} | {np.mean(abs(bm) > 5 * em):.2%} |")


if __name__ == "__main__":
    main()
