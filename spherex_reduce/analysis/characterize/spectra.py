"""The spectra of the darks' channel streams, pooled over darks, and their fits.

Every spectrum is a Welch estimate (`~spherex_reduce.analysis.temporal.temporal_psd`)
within frames, measured on each dark (or segment) alone (`dark_spectra`) and
averaged over darks (`pool`).  Cross-spectra come from auto-spectra of sums
of streams (the Welch estimate is bilinear: ``2 Re X(a, b) = P(a + b) − P(a)
− P(b)``), and the part common to all ``C`` channels from the spectrum of
the channel mean: the mean cross-spectrum over the ``C(C−1)`` pairs of
different channels is ``(C · P(mean) − mean P) / (C−1)``.  Each is fitted
(`fit_spectra`) with `~spherex_reduce.analysis.temporal.fit_noise_model`
through the exact map of its averaging and decimation
(`~spherex_reduce.analysis.temporal.aliased_basis`), the derived spectra
weighted by the fitted auto-spectra they come from (fixed weights: a fit is
then linear in its spectrum, so coefficients of differences of spectra are
differences of coefficients).
"""

import numpy as np
from astropy.table import Table

from ...reduce.options import default_threads, in_threads
from ..temporal import aliased_basis, fit_noise_model, temporal_psd, welch_terms

__all__ = ["LONG_BURST", "NOT_REPORTED", "SPECTRA", "SPECTRA_THREADS", "band_power",
           "dark_spectra", "fit_spectra", "pool"]

#: Spectra of one dark taken at once, in threads (each a Welch transform of one stream:
#: tens of MB at full size).
SPECTRA_THREADS = 2

#: Samples of one column parity in a reference-row burst from which its fit takes the
#: correlated terms too, not the white level alone (`_burst_terms`): 128 (channels of 256
#: columns or more).
LONG_BURST = 64

#: Entries of `fit_spectra`'s result that are not spectra of the report: the channels' own
#: fits, and a channel's own part of the phantom spectrum fitted with its parities'
#: averages (``phantom_acn``, which the model's components take where ACN is found).
NOT_REPORTED = ("channels", "phantom_acn")

#: The spectra `fit_spectra` fits, and what each holds.
SPECTRA = {
    "pixels": "light-sensitive pixels, channel mean of each channel's auto-spectrum",
    "pixels_common": "light-sensitive pixels, mean cross-spectrum of different channels",
    "acn": "half the even-odd column difference (alternating column noise only)",
    "phantom": "phantom reads, channel mean of the auto-spectra",
    "phantom_common": "phantom reads, mean cross-spectrum of different channels",
    "both": "pixels x phantom of one channel (what both see)",
    "both_common": "pixels x phantom of different channels",
    "reference": "reference pixels: white level (and 1/f of long bursts) of the reference-row "
                 "bursts",
    "reference_common": "reference pixels: mean cross-spectrum of different channels' "
                        "reference-row bursts (read at the same times): the white level "
                        "common to all channels",
}


def _nperseg(schedule, nperseg):
    n = schedule.n_reads
    return min(nperseg or 2 ** int(np.floor(np.log2(n))), n)


def dark_spectra(streams, schedule, nperseg=None):
    """The Welch spectra of one dark's streams that `fit_spectra` needs.

    Parameters
    ----------
    streams : `~spherex_reduce.analysis.characterize.streams.ChannelStreams`
    schedule : `~spherex_reduce.ReadoutSchedule`
    nperseg : int, optional
        Welch segment of the per-read streams (default: the largest power of two
        not above the reads per frame).

    Returns
    -------
    dict
        ``{key: Table}`` (``sum``, ``sum_mean``, ``diff``, ``phantom``,
        ``phantom_mean``, ``sum+phantom``, ``sum+phantom_mean``, ``sum[c]``,
        ``phantom[c]``, ``rows[c]``, ``rows``, ``rows_each`` and ``rows_mean`` (the
        bursts every channel keeps, each channel's and their mean over channels),
        ``sides[c]``: those the dark has).

    Examples
    --------
    >>> from spherex_reduce.io.examples import example_raw_exposure
    >>> from spherex_reduce.analysis.characterize.streams import channel_streams
    >>> from spherex_reduce.analysis.characterize.spectra import dark_spectra
    >>> e = example_raw_exposure()
    >>> sorted(dark_spectra(channel_streams(e), e.schedule))[:4]
    ['diff', 'phantom', 'phantom[0]', 'phantom[1]']
    """
    g = schedule.geometry
    fs = g.pixel_rate
    rate = fs / schedule.row_samples
    nper = _nperseg(schedule, nperseg)

    jobs = {}  # key: (values, rate, nperseg); values made when their spectrum is taken

    def psd(key, values, r=rate, n=nper):
        jobs[key] = (values, r, n)

    psd("sum", lambda: streams.sum)
    psd("sum_mean", lambda: streams.sum.mean(axis=0))
    for c in range(streams.sum.shape[0]):
        psd(f"sum[{c}]", lambda c=c: streams.sum[c])
    if streams.diff is not None:
        psd("diff", lambda: streams.diff)
    if streams.phantom is not None:
        psd("phantom", lambda: streams.phantom)
        psd("phantom_mean", lambda: streams.phantom.mean(axis=0))
        psd("sum+phantom", lambda: streams.sum + streams.phantom)
        psd("sum+phantom_mean", lambda: (streams.sum + streams.phantom).mean(axis=0))
        for c in range(streams.phantom.shape[0]):
            psd(f"phantom[{c}]", lambda c=c: streams.phantom[c])
    rows = streams.reference_rows
    if rows is not None:  # even and odd apart: each a stream at half the pixel rate
        kept = streams.reference_kept
        if kept is not None:  # the bursts kept, each a stream: (bursts, frames, width / 2)
            rows = np.moveaxis(rows, 3, 2)
            psd("rows", lambda: rows[kept], fs / 2, rows.shape[-1])
            for c in range(rows.shape[0]):
                psd(f"rows[{c}]", lambda c=c: rows[c][kept[c]], fs / 2, rows.shape[-1])
        else:
            psd("rows", lambda: rows, fs / 2, rows.shape[-1])
            for c in range(rows.shape[0]):
                psd(f"rows[{c}]", lambda c=c: rows[c], fs / 2, rows.shape[-1])
        every = None if kept is None else kept.all(axis=0)  # bursts every channel keeps
        if rows.shape[0] > 1 and rows.shape[-1] >= LONG_BURST and (every is None
                                                                   or every.any()):
            # the channels read their reference rows at the same times (bursts long enough
            # for `fit_spectra` to take their common white level from)
            both = (slice(None),) if every is None else (slice(None), every)
            psd("rows_each", lambda: rows[both], fs / 2, rows.shape[-1])
            psd("rows_mean", lambda: rows[both].mean(axis=0), fs / 2, rows.shape[-1])
    for c, v in streams.reference_sides.items():
        psd(f"sides[{c}]", lambda v=v: v)
    # each spectrum alone: SPECTRA_THREADS at a time (the transforms release the GIL)
    nthreads = max(1, min(SPECTRA_THREADS, default_threads()))
    done = in_threads(jobs.values(), lambda job: temporal_psd(job[0](), job[1], nperseg=job[2]),
                      nthreads, name="spherex-reduce-spectra")
    return dict(zip(jobs, done, strict=True))


def pool(spectra):
    """The spectra of several darks averaged (each key the darks share).

    The Welch metadata count every dark's streams, so the fits' formal
    errors are those of the pooled spectrum.

    Examples
    --------
    >>> import numpy as np
    >>> from spherex_reduce.analysis import temporal_psd
    >>> from spherex_reduce.analysis.characterize.spectra import pool
    >>> rng = np.random.default_rng(0)
    >>> a, b = ({"x": temporal_psd(rng.normal(size=(2, 256)), 1.0)} for _ in range(2))
    >>> p = pool([a, b])
    >>> bool(np.allclose(p["x"]["psd"], (a["x"]["psd"] + b["x"]["psd"]) / 2))
    True
    >>> p["x"].meta["nstreams"]
    4
    """
    out = {}
    for key in [k for k in spectra[0] if all(k in s for s in spectra)]:
        tabs = [s[key] for s in spectra]
        t = Table(tabs[0], copy=True)
        # summed as plain arrays: Column arithmetic per dark made the jackknife's pools
        # (one per dark left out) take minutes at a few hundred darks
        total = np.sum([np.asarray(x["psd"], dtype=np.float64) for x in tabs], axis=0)
        t["psd"] = total / len(tabs) * tabs[0]["psd"].unit
        t.meta["nstreams"] = int(sum(x.meta["nstreams"] for x in tabs))
        out[key] = t
    return out


def _model_psd(result, basis, spec):
    """The spectrum a fit's model gives at ``spec``'s frequencies, as Welch's estimate
    sees it (the window's smoothing)."""
    f = np.asarray(spec["frequency"].value)
    theta = np.array([result.values[p] for p in ("alpha", "beta", "gamma")])
    return welch_terms(basis, f, result.exponent, spec.meta) @ theta


def _expected(result, basis, spec):
    """`_model_psd` floored above zero: the weights of the spectra derived from the one it
    fits."""
    model = _model_psd(result, basis, spec)
    return np.maximum(model, np.max(np.abs(model)) * 1e-6)


def _with(spec, psd, weight):
    out = Table(spec, copy=True)
    out["psd"] = np.asarray(psd) * spec["psd"].unit
    out["weight"] = np.asarray(weight) * spec["psd"].unit
    return out


def _pairs(mean_spec, per_channel, nch):
    """The mean cross-spectrum over the ``C(C−1)`` pairs of different channels, from the
    spectrum of the channel mean and the mean over channels of each one's:
    ``Σ_ij X_ij = C² P(mean)`` and ``Σ_i X_ii = C · mean P``, so the mean over ``i ≠ j``
    is ``(C · P(mean) − mean P) / (C − 1)``.

    Examples
    --------
    Noise common to all channels: every pair's cross-spectrum is its spectrum.

    >>> from spherex_reduce.analysis.characterize.spectra import _pairs
    >>> float(_pairs(2.0, 2.0, 32))
    2.0
    """
    return (nch * np.asarray(mean_spec) - np.asarray(per_channel)) / (nch - 1)


def _cross(sp, a, b, key):
    """``Re X(a, b)`` from ``P(a + b)``, ``P(a)`` and ``P(b)``."""
    return 0.5 * (np.asarray(sp[key]["psd"]) - np.asarray(sp[a]["psd"])
                  - np.asarray(sp[b]["psd"]))


def fit_spectra(sp, boxes, schedule, exponent, nbins=30, shot=0.0):
    """Fit every spectrum of `SPECTRA` the (pooled) spectra ``sp`` hold.

    Parameters
    ----------
    sp : dict
        `dark_spectra` of one dark, or `pool` of several.
    boxes : dict
        The streams' averages (`~spherex_reduce.analysis.characterize.streams.Box`).
    schedule : `~spherex_reduce.ReadoutSchedule`
    exponent : float or None
        The exponent of the third term; None fits it on the ``pixels`` spectrum,
        and every other fit takes the value found.
    nbins : int
        Logarithmic bins per spectrum.
    shot : float
        The white level (of one sample, as ``alpha``) that the light-sensitive
        pixels' dark current adds to their streams
        (`~spherex_reduce.analysis.characterize.streams.shot_white`), taken out of
        the ``pixels`` and ``acn`` spectra before they are fitted: the per-pixel
        terms hold it.

    Returns
    -------
    dict
        ``{name: NoiseModelFit}`` for the spectra of `SPECTRA` that ``sp`` holds
        (and ``phantom_acn``: each channel's own part of the phantom spectrum, less
        the common part's model, fitted with its parities' own averages,
        `_parity_basis`, which the model takes where ACN is found), and
        ``{"channels": {view: [NoiseModelFit or None per channel]}}`` for ``pixels``,
        ``phantom`` and ``reference``.

    Examples
    --------
    >>> from spherex_reduce.io.examples import example_raw_exposure
    >>> from spherex_reduce.analysis.characterize.streams import channel_streams
    >>> from spherex_reduce.analysis.characterize.spectra import dark_spectra, fit_spectra
    >>> e = example_raw_exposure()
    >>> st = channel_streams(e)
    >>> fits = fit_spectra(dark_spectra(st, e.schedule), st.boxes, e.schedule, 1.3)
    >>> sorted(k for k in fits if k != "channels")
    ['acn', 'both', 'both_common', 'phantom', 'phantom_acn', 'phantom_common', 'pixels',
     'pixels_common']
    """
    g = schedule.geometry
    fs, m = g.pixel_rate, schedule.row_samples
    nch = g.nchannels

    def basis(box, half=False, channel=None):
        # the white level of the average: that of n samples times the box's factor (pixels
        # left out), so that alpha stays the white level of one sample
        white = box.white if channel is None or not box.whites else box.whites[channel]
        scale = (0.5 if half else 1.0) * np.array([white, 1.0, 1.0])
        return lambda f, e: scale * aliased_basis(f, fs, m, box.n, e, box.stride)

    def less_shot(spec, terms):  # the dark current's shot noise: the per-pixel terms'
        if not shot:
            return spec
        out = Table(spec, copy=True)
        white = terms(np.asarray(spec["frequency"].value), 1.3)[:, 0] * shot
        out["psd"] = (np.asarray(spec["psd"]) - white) * spec["psd"].unit
        return out

    b_sum = basis(boxes["sum"])
    out, per = {}, {}
    out["pixels"] = fit_noise_model(less_shot(sp["sum"], b_sum), basis=b_sum,
                                    exponent=exponent, nbins=nbins)
    fit = {"exponent": out["pixels"].exponent, "nbins": nbins}
    s_w = _expected(out["pixels"], b_sum, sp["sum"])
    per["pixels"] = []
    for c in range(nch):
        b_c = basis(boxes["sum"], channel=c)
        per["pixels"].append(fit_noise_model(less_shot(sp[f"sum[{c}]"], b_c), basis=b_c,
                                             **fit))
    if nch > 1:
        out["pixels_common"] = fit_noise_model(
            _with(sp["sum"], _pairs(sp["sum_mean"]["psd"], sp["sum"]["psd"], nch), s_w),
            basis=b_sum, **fit)
    if "diff" in sp:
        b_d = basis(boxes["diff"], half=True)
        out["acn"] = fit_noise_model(less_shot(sp["diff"], b_d), basis=b_d, **fit)
    if "phantom" in sp and np.any(np.asarray(sp["phantom"]["psd"]) > 0):  # not constant
        b_ph = basis(boxes["phantom"])
        out["phantom"] = fit_noise_model(sp["phantom"], basis=b_ph, **fit)
        p_w = _expected(out["phantom"], b_ph, sp["phantom"])
        per["phantom"] = [fit_noise_model(sp[f"phantom[{c}]"], basis=b_ph, **fit)
                          for c in range(nch)]
        b_x = _cross_basis(boxes, fs, m)
        w_x = np.sqrt(s_w * p_w)
        cross_fit = {**fit, "fit": ("beta", "gamma")}  # no white: other samples
        both = _cross(sp, "sum", "phantom", "sum+phantom")
        out["both"] = fit_noise_model(_with(sp["sum"], both, w_x), basis=b_x, **cross_fit)
        if nch > 1:
            out["phantom_common"] = fit_noise_model(
                _with(sp["phantom"], _pairs(sp["phantom_mean"]["psd"], sp["phantom"]["psd"],
                                            nch), p_w), basis=b_ph, **fit)
            both_mean = _cross(sp, "sum_mean", "phantom_mean", "sum+phantom_mean")
            out["both_common"] = fit_noise_model(
                _with(sp["sum"], _pairs(both_mean, both, nch), w_x), basis=b_x, **cross_fit)
        if 0 < boxes["phantom"].even < boxes["phantom"].n:  # taken where ACN is found
            # each channel's own part (the phantom spectrum less the common part's model,
            # which is not ACN: the whole box's shape) with its parities' averages
            own = np.asarray(sp["phantom"]["psd"])
            if "phantom_common" in out:
                own = own - _model_psd(out["phantom_common"], b_ph, sp["phantom"])
            out["phantom_acn"] = fit_noise_model(
                _with(sp["phantom"], own, p_w),
                basis=_parity_basis(boxes["phantom"], fs, m), **fit)
    ref = _reference(sp, boxes, nch, fs, m, fit)
    if ref:
        per["reference"] = ref
    if "rows" in sp:
        out["reference"] = fit_noise_model(sp["rows"], basis=_burst_basis(fs), **fit,
                                           **_burst_terms(sp["rows"]))
    each = sp.get("rows_each")
    if each is not None and nch > 1 and each.meta["nperseg"] >= LONG_BURST:
        # the common white level where white noise dominates, from bursts long enough that
        # their fit takes the common 1/f apart (short ones would take it for white)
        r_w = _expected(fit_noise_model(each, basis=_burst_basis(fs), **fit,
                                        **_burst_terms(each)), _burst_basis(fs), each)
        out["reference_common"] = fit_noise_model(
            _with(each, _pairs(sp["rows_mean"]["psd"], each["psd"], nch), r_w),
            basis=_burst_basis(fs), **fit, **_burst_terms(each))
    out["channels"] = per
    return out


def _parity_basis(box, fs, m):
    """The terms of an average ``box`` (stride 1) whose correlated noise is alternating
    column noise: its even and its odd samples see streams of their own, so the
    correlated terms are those of two averages of every other sample, ``(e/n)**2`` and
    ``(o/n)**2`` of them (`~spherex_reduce.analysis.characterize.streams.Box.acn_factor`
    at low frequencies).  An average of every other sample passes the pixel rate's
    Nyquist frequency whole where the whole box nulls it, and the phantom reads' white
    level (Video8's, 3.71e-5 e²/Hz) sits near the 1/f of 8.4e-3 e² aliased from there:
    fitted with the whole box's terms it came back ~0.5 % high from ACN phantom values
    (one pull of `characterize`'s error at full size).

    Examples
    --------
    At low frequencies the correlated terms are half the whole box's (2 even, 2 odd):

    >>> from spherex_reduce.analysis.characterize.streams import Box
    >>> from spherex_reduce.analysis.temporal import aliased_basis
    >>> t = _parity_basis(Box(4, 1, 1.5, even=2), 1e5, 72)([1.0], 1.3)
    >>> w = aliased_basis([1.0], 1e5, 72, 4, 1.3)
    >>> [round(float(x), 3) for x in (t / w)[0]]
    [1.0, 0.5, 0.5]
    """
    parts = [(k, k / box.n) for k in (box.even, box.n - box.even) if k]

    def terms(f, e):
        whole = aliased_basis(f, fs, m, box.n, e, box.stride)
        split = sum(w * w * aliased_basis(f, fs, m, k, e, 2 * box.stride) for k, w in parts)
        return np.concatenate([box.white * whole[:, :1], split[:, 1:]], axis=1)
    return terms


def _cross_basis(boxes, fs, m):
    """The terms of the pixels x phantom cross-spectrum, the mean over the channels'
    lags between the centres of their pixels' and their phantom's averages."""
    sums, ph = boxes["sum"], boxes["phantom"]
    lags, counts = np.unique(np.array(sums.centres) - ph.centre, return_counts=True)
    weights = counts / counts.sum()

    def terms(f, e):
        return sum(w * aliased_basis(f, fs, m, sums.n, e, sums.stride, cross=(ph.n, 1, lag))
                   for lag, w in zip(lags, weights, strict=True))
    return terms


def _burst_basis(fs):
    """Reference-row bursts of one column parity: samples 2 apart at the pixel rate."""
    return lambda f, e: aliased_basis(f, fs, 2, 1, e)


def _burst_terms(spec):
    """The terms a fit of reference-row bursts takes: the white level alone from short
    bursts, where white noise dominates their frequencies (above ``fs / width``); the
    white level and a 1/f term from bursts of `LONG_BURST` samples or more, which reach
    down to where correlated noise is as strong as the white (NGHXRG's 1/f at ~1 kHz)
    and would otherwise be taken for white.  One correlated term, not two: over the one
    to two decades a burst spans, 1/f and 1/f^1.3 are nearly the same shape, and a fit of
    both leaves the white level loose."""
    return {"fit": ("alpha", "beta") if spec.meta["nperseg"] >= LONG_BURST else ("alpha",)}


def _reference(sp, boxes, nch, fs, m, fit):
    """Per channel: the fit of its reference pixels.  Reference-row bursts give the white
    level (`_burst_terms`); the side columns' mean per read, where a channel has side
    columns, give the correlated terms too."""
    out = []
    for c in range(nch):
        spectra, bases = [], []
        if f"rows[{c}]" in sp:
            spectra.append(sp[f"rows[{c}]"])
            bases.append(_burst_basis(fs))
        side = f"sides[{c}]" in sp
        if side:
            box = boxes["sides"]
            spectra.append(sp[f"sides[{c}]"])
            white = np.array([box.whites[c] if box.whites else 1.0, 1.0, 1.0])
            bases.append(lambda f, e, b=box, w=white: w * aliased_basis(f, fs, m, b.n, e,
                                                                        b.stride))
        terms = {} if side or not spectra else _burst_terms(spectra[0])
        out.append(fit_noise_model(spectra, basis=bases, **fit, **terms) if spectra else None)
    return out if any(r is not None for r in out) else []


def band_power(beta, gamma, exponent, band):
    """``∫ β/f + γ/f^exponent df`` over ``band = (fmin, fmax)`` (Hz): the correlated power.

    Examples
    --------
    >>> from spherex_reduce.analysis.characterize.spectra import band_power
    >>> round(band_power(1.0, 0.0, 1.3, (1.0, 10.0)), 4)   # ln 10
    2.3026
    """
    lo, hi = band
    e = float(exponent)
    steep = np.log(hi / lo) if abs(1 - e) < 1e-9 else (hi ** (1 - e) - lo ** (1 - e)) / (1 - e)
    return float(beta * np.log(hi / lo) + gamma * steep)
