"""Each dark's per-pixel sums, a band of rows at a time: what
`~spherex_reduce.analysis.pixel_terms.PixelSums` adds dark by dark and fits.

`new_sums` makes the empty sums of darks of one shape and read times; `add_dark` adds
one dark, whose bands of rows are read by the caller's function in the calling thread
and summed `PIXEL_THREADS` at a time in threads.  In float32 where the bulk allows (the
differences of reads; sums over reads are dot products), the few jumps taken out of the
all-read sums afterwards.
"""

import numpy as np

from ..reduce.options import default_threads, in_threads
from ..reduce.steps.reference.telegraph import MAD_TO_SIGMA
from .faint_telegraph import lag_design, lag_sums

__all__ = ["MIN_READS", "MIN_TELEGRAPH_INTERVALS", "PIXEL_THREADS", "SCALE_CAP", "add_dark",
           "new_sums"]

#: Fewest reads a dark needs (two differences after read 0 is kept aside, or with it).
MIN_READS = 3
#: Fewest differences per dark to tell a telegraph's jumps from a pixel's own noise.
MIN_TELEGRAPH_INTERVALS = 8
#: A pixel's robust scale of its differences, which its jumps are found above, is capped at
#: this times the band's typical one (with the pixel's shot noise): see `_band`.
SCALE_CAP = 1.25
#: Bands of a dark summed at once, in threads (each holds its reads and ~10 times their
#: size of work: two bands of 32 rows of a 2048² × 74 dark, ~0.2 GB), while the next
#: band is read (~19 MB)
PIXEL_THREADS = 2

_SUMS = ("wd", "wdt", "vr", "vs", "q", "kept", "jumps", "jsize", "jumps_a", "jsize_a", "offset",
         "s1", "s2")
_FLAGS = {"alternate": True, "bad": False}  # bool maps: and-ed, or-ed over darks


def _design(t, skip_first):
    """Weights and the exact constants of the differences' quadratic forms (all kept)."""
    ty = t[1:] if skip_first else t
    dt = np.diff(ty)
    m = dt.size
    k = np.arange(m)
    w = (k + 1.0) * (m - k)
    c_r = 2 * np.eye(m) - np.eye(m, k=1) - np.eye(m, k=-1)  # white reads, per unit variance
    c_s = np.diag(dt)  # shot noise, per unit current / gain
    p = np.eye(m) - np.outer(dt, w) / (w @ dt)
    mm = p.T @ p
    mr, ms = mm @ c_r, mm @ c_s
    return dict(dt=dt, w=w, m=m, t_mean=ty.mean(), level=(m - k) / (m + 1.0), mm=mm,
                ar=np.trace(mr), as_=np.trace(ms), trr=np.trace(mr @ mr),
                trs=np.trace(mr @ ms), tss=np.trace(ms @ ms), vr=w @ c_r @ w, vs=w ** 2 @ dt)


def new_sums(shape, t, jump_sigma, gain=1.0, labels=None):
    """Empty per-pixel sums of darks of ``shape`` ``(reads, ny, nx)`` read at times ``t``
    (s, float64), ``jump_sigma`` the jumps' threshold in robust standard deviations of a
    difference, ``gain`` e per unit of the darks, ``labels`` the pixels read together
    (integers ``(ny, nx)``, -1 on reference pixels, as
    `~spherex_reduce.analysis.pixel_terms.PixelSums` checks them; None: all together).

    Examples
    --------
    >>> import numpy as np
    >>> from spherex_reduce.analysis.pixel_sums import new_sums
    >>> acc = new_sums((10, 4, 6), np.arange(10) * 1.5, 5.0)
    >>> acc["wd"].shape, acc["skip_first"]
    ((4, 6), True)
    """
    n, ny, nx = shape
    skip_first = n > MIN_READS
    acc = {k: np.zeros((ny, nx)) for k in _SUMS}
    acc.update({key: np.full((ny, nx), value) for key, value in _FLAGS.items()})
    acc["design"], acc["skip_first"], acc["jump_sigma"] = (_design(t, skip_first), skip_first,
                                                           jump_sigma)
    acc["gain"], acc["drifts"] = gain, []
    acc["labels"] = np.zeros((ny, nx), np.int64) if labels is None else labels
    if acc["design"]["m"] >= MIN_TELEGRAPH_INTERVALS:  # the faint telegraph's statistics
        acc["lags"] = lag_design(t[1:] if skip_first else t)
        acc["lagq"] = np.zeros((acc["lags"]["lags"].size, ny, nx), np.float32)
        acc["csq"] = np.zeros((ny, nx))
    return acc


def add_dark(acc, band, shape, t, band_rows):
    """Add one dark of ``shape`` ``(n, ny, nx)``, whose rows ``sl`` (a slice) of every read are
    ``band(sl)``, to the sums, a band of rows at a time (each pixel's sums take the darks in
    the order they are added).  Returns the dark's slope of every pixel ``(ny, nx)``
    (float32, NaN where a read is not finite) and its pixels with a jump (bool; read 0
    apart, also those whose read 0 is offset from their line unlike the band's pixels: a
    step between reads 0 and 1).

    ``band(sl)`` is called in the calling thread (a reader need not be thread-safe); up
    to `PIXEL_THREADS` bands are summed at once in threads, and each band's sums are added
    to ``acc`` in order, so the numbers do not depend on the threads.

    Examples
    --------
    >>> import numpy as np
    >>> from spherex_reduce.analysis.pixel_sums import add_dark, new_sums
    >>> t = np.arange(10) * 1.5
    >>> x = np.random.default_rng(1).normal(0, 4.0, (10, 4, 6)) + 2.0 * t[:, None, None]
    >>> acc = new_sums(x.shape, t, 5.0)
    >>> slopes, jumped = add_dark(acc, lambda sl: x[:, sl], x.shape, t, band_rows=2)
    >>> bool(abs(np.mean(slopes) - 2.0) < 0.5), int(jumped.sum())
    (True, 0)
    """
    _, ny, nx = shape
    slopes = np.empty((ny, nx), dtype=np.float32)
    jumped = np.zeros((ny, nx), dtype=bool)

    def one(sl, xb):
        return _band(xb, t, acc["design"], acc["jump_sigma"], acc["skip_first"],
                     acc["gain"], acc.get("lags"), acc["labels"][sl])

    cuts = [slice(r0, min(r0 + band_rows, ny)) for r0 in range(0, ny, band_rows)]
    # up to PIXEL_THREADS bands worked on at a time in threads (numpy's work releases the
    # GIL), the next band read here meanwhile (a reader need not be thread-safe); each
    # band's sums are added here, in order, to their own rows
    nthreads = max(1, min(PIXEL_THREADS, default_threads(), len(cuts)))
    for sl, part in zip(cuts, in_threads(cuts, one, nthreads, read=band,
                                         name="spherex-reduce-pixels"), strict=True):
        _add_band(acc, sl, part, slopes, jumped)
    return slopes, jumped


def _add_band(acc, sl, part, slopes, jumped):
    """Add the sums ``part`` of the band of rows ``sl`` of one dark to ``acc``; its slopes
    and pixels with a jump into ``slopes`` and ``jumped`` (`add_dark`'s)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        slopes[sl] = np.where(part["bad"], np.nan, part["wd"] / part["wdt"])
    jumped[sl] = part["jumps"] > 0
    if acc["skip_first"]:  # a step between reads 0 and 1: an offset unlike the band's
        r = np.where(part["bad"], 0.0, part["offset"] - np.median(part["offset"]))
        jumped[sl] |= np.abs(r) > acc["jump_sigma"] * MAD_TO_SIGMA * np.median(np.abs(r))
    for key, value in part.items():
        if key == "alternate":
            acc[key][sl] &= value
        elif key == "bad":
            acc[key][sl] |= value
        elif key == "lagq":
            acc[key][:, sl] += value
        else:
            acc[key][sl] += value


def _median_of_reads(a):
    """``numpy.median(a, axis=0)`` of finite float32 or float64 ``a`` ``(n, rows, nx)``
    (`_band`'s rates and absolute residuals), the same numbers, ~4 times faster: each
    pixel's ``n`` values made contiguous, then partitioned at one kth."""
    n = a.shape[0]
    y = a.reshape(n, -1).T.copy()  # C order; ``a`` is never reordered
    k = n // 2
    y.partition(k, axis=1)  # one kth: numpy's partition at two is several times slower
    mid = y[:, k]
    if n % 2 == 0:  # the mean of the two middle values, as numpy takes it
        mid = (y[:, :k].max(axis=1) + mid) / y.dtype.type(2)
    return mid.reshape(a.shape[1:])


def _band(x, t, des, jump_sigma, skip_first, gain=1.0, lags=None, labels=None):
    """One band of one dark ``x (n, rows, nx)``: its per-pixel sums.

    The bulk is float32 (the differences of reads; sums over reads are dot products), and
    the few jumps are taken out of the all-read sums afterwards.
    """
    f32 = np.float32
    y = np.asarray(x[1:] if skip_first else x, dtype=f32)  # integers never differenced as such
    shape = y.shape[1:]
    d = np.diff(y, axis=0)
    total = d.sum(axis=0, dtype=np.float64)  # not finite where any read is not
    bad = ~np.isfinite(total)
    if skip_first:
        bad |= ~np.isfinite(x[0])
    if bad.any():
        y = np.where(bad, f32(0), y)  # a copy: the input is never changed
        d = np.diff(y, axis=0)
        total = d.sum(axis=0, dtype=np.float64)
    dt64 = des["dt"]
    dt = dt64.astype(f32)[:, None, None]
    mean = (total / dt64.sum()).astype(f32)
    e = d - mean * dt
    a = np.abs(e)
    scale = MAD_TO_SIGMA * _median_of_reads(a)
    shot = np.maximum(mean, 0) * f32(np.mean(dt64) / gain)  # a difference's, unit^2

    def clipped(scale):
        # a pixel's robust scale from a few tens of differences scatters by ~20 %: floored at
        # the band's typical one, so that a quiet pixel's noise does not pass for jumps; and
        # capped at that plus the pixel's own shot noise (a quarter over), so that a
        # telegraph pixel's jumps, a third of a dark of ten differences when it switches
        # fast, do not raise its scale above them (its rate came out 17 standard errors low
        # from 4 darks of 10 reads)
        floor = np.median(scale)
        return np.clip(scale, floor, f32(SCALE_CAP) * np.sqrt(floor * floor + shot))

    if d.shape[0] >= MIN_TELEGRAPH_INTERVALS:
        # where a telegraph is sought, its jumps are sought about the pixel's median rate
        # (of fewer differences the median is a poor centre: one of three residuals is 0):
        # jumps that do not cancel over the dark (a telegraph ending it in the other state)
        # move the mean rate by their net size over the intervals, which made one sign of
        # jump smaller, raised the scale and missed 4 % of the flips of 125 e steps in 10 e
        # noise (the pixels whose flips measured high kept: their step 1.4 e high).  But a
        # pixel with jumps at half of its intervals or more about its mean rate keeps that:
        # its median sits near a flip (4 full-size SIDECAR darks lost 142 of 83 275
        # telegraph pixels so, 27 now)
        a_med = np.abs(d - _median_of_reads(d / dt) * dt)
        busy = np.count_nonzero(a > jump_sigma * clipped(scale), axis=0) * 2 >= d.shape[0]
        a = np.where(busy, a, a_med)
        scale = np.where(busy, scale, MAD_TO_SIGMA * _median_of_reads(a_med))
        del a_med
    scale = clipped(scale)
    kk, ii, jj = np.nonzero(a > jump_sigma * scale)
    del a
    pix = ii * shape[1] + jj
    size = shape[0] * shape[1]

    def per_pixel(weights=None):
        return np.bincount(pix, weights, minlength=size).reshape(shape)

    w = des["w"]
    wd = np.tensordot(w.astype(f32), d, 1).astype(np.float64) - per_pixel(
        w[kk] * d[kk, ii, jj])
    wdt = w @ dt64 - per_pixel(w[kk] * dt64[kk])
    slope = np.divide(wd, wdt, out=np.zeros_like(wd), where=wdt > 0)
    delta = slope - mean  # residuals d - slope dt = e - delta dt
    ee = np.einsum("kij,kij->ij", e, e, dtype=np.float64)
    edt = np.tensordot(dt64.astype(f32), e, 1).astype(np.float64)
    res = e[kk, ii, jj] - delta[ii, jj] * dt64[kk]
    q = ee - 2 * delta * edt + delta ** 2 * (dt64 @ dt64) - per_pixel(res ** 2)
    jumps = per_pixel()
    order = np.argsort(pix, kind="stable")  # each pixel's jumps in time order
    p_o, s_o = pix[order], np.sign(res[order])
    # the slope's variance without the jumps' differences: w C w less their terms (the
    # white reads' C = tridiag(-1, 2, -1): a pair of adjacent jumps shares one)
    wpad = np.concatenate([[0.0], w, [0.0]])
    wj = w[kk]
    k_o = kk[order]
    pair = (p_o[1:] == p_o[:-1]) & (k_o[1:] == k_o[:-1] + 1)
    vr = des["vr"] - per_pixel(2 * wj ** 2 - 2 * wj * (wpad[kk] + wpad[kk + 2]))
    vr -= np.bincount(p_o[1:][pair], 2 * w[k_o[1:][pair]] * w[k_o[:-1][pair]],
                      minlength=size).reshape(shape)
    same = (p_o[1:] == p_o[:-1]) & (s_o[1:] == s_o[:-1])
    alternate = np.ones(size, bool)
    alternate[p_o[1:][same]] = False
    size_j = np.abs(res)
    first_half = kk < d.shape[0] // 2  # the jumps of the first half of the intervals apart:
    # a telegraph pixel's step is measured on one half where the other clears the threshold
    out = {"wd": wd, "wdt": wdt, "vr": vr, "vs": des["vs"] - per_pixel(wj ** 2 * dt64[kk]),
           "q": q, "kept": 1 - jumps / des["m"], "jumps": jumps, "jsize": per_pixel(size_j),
           "jumps_a": per_pixel(first_half.astype(np.float64)),
           "jsize_a": per_pixel(np.where(first_half, size_j, 0.0)),
           "alternate": alternate.reshape(shape), "bad": bad}
    if lags is not None:  # the faint telegraph's structure functions (jumps kept)
        out["lagq"] = lag_sums(e, labels, (jumps > 0) | bad, lags["lags"])
        a = lags["a"]  # the dark's contrast, squared: its scatter between darks
        out["csq"] = (out["lagq"][-1] / a[-1] - out["lagq"][0] / a[0]) ** 2
    if skip_first:
        level = y[0] + np.tensordot(des["level"].astype(f32), d, 1)  # mean of the later reads
        out["offset"] = (np.where(bad, 0.0, np.asarray(x[0], dtype=np.float64)) - level
                         - slope * (t[0] - des["t_mean"]))
    return out
