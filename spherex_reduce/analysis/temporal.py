"""Temporal noise spectra and the fit of ``p(f) = α + β/f + γ/f^exponent`` (paper eq. 1, Table 2).

The PSD is Welch's estimate (`scipy.signal.welch`, Hann window, one-sided
density: ``∫ p df`` is the variance, the convention of Table 2).  The fit is a
weighted linear least-squares fit of the three coefficients to the PSD averaged
in logarithmic frequency bins, iterated so that each bin's weight comes from
the model (its variance is ``model² · v``, with ``v`` the relative variance of
a Welch bin mean for locally white Gaussian noise, computed exactly from the
window, the segment overlap and the number of averaged segments, streams and
frequencies).  This is the Gaussian maximum-likelihood fit to first order, and
its covariance ``(Xᵀ W X)⁻¹`` gives the uncertainties.  The coefficients are
not forced to be positive: a component that is absent comes back as
``0 ± σ``.

Streams read out of a raw exposure are not sampled at the pixel rate: a
phantom value is the mean of ``c`` consecutive samples, taken once per row read
(every ``row_samples`` samples), and a reference-column value likewise the mean
of the ``ref_border`` border columns.  Their PSD is the pixel-rate PSD filtered
by the ``c``-sample box and aliased into the row rate;
`aliased_basis` gives the three model terms of such a stream, so the fit
returns the coefficients of the underlying 100 kHz process directly.
"""

import dataclasses
from typing import NamedTuple

import numpy as np
import scipy.signal
from astropy import units as u
from astropy.table import Table

from ..errors import SpherexReduceError

__all__ = [
    "NoiseModelFit",
    "Timestream",
    "aliased_basis",
    "fit_noise_model",
    "fit_raw_noise",
    "model_basis",
    "phantom_timestream",
    "reference_timestream",
    "temporal_psd",
]

PARAMS = ("alpha", "beta", "gamma")


# -- PSD ------------------------------------------------------------------------------
def temporal_psd(stream, sample_rate, nperseg=None, noverlap=None, detrend="constant"):
    """One-sided PSD of one or many timestreams with Welch's method.

    Parameters
    ----------
    stream : array-like or `~astropy.units.Quantity`
        Samples along the last axis; leading axes (channels, frames) are
        independent streams whose PSDs are averaged.
    sample_rate : float or `~astropy.units.Quantity`
        Sampling rate (Hz).
    nperseg : int, optional
        Segment length (default: the stream length, at most 4096).
    noverlap : int, optional
        Overlap of segments (default ``nperseg // 2``).
    detrend : str or False
        Per-segment detrending, as in `scipy.signal.welch`.

    Returns
    -------
    psd : `~astropy.table.Table`
        Columns ``frequency`` (Hz) and ``psd`` (unit²/Hz), without ``f = 0``
        and the Nyquist frequency (whose one-sided ordinate is not doubled);
        ``meta`` has ``nperseg``, ``noverlap``, ``nsegments`` (per stream),
        ``nstreams`` and ``sample_rate``, which `fit_noise_model` uses for the
        uncertainties.

    Examples
    --------
    White noise of variance σ² sampled at ``fs`` has ``p = 2σ²/fs``:

    >>> import numpy as np
    >>> from spherex_reduce.analysis import temporal_psd
    >>> x = np.random.default_rng(0).normal(0, 1, (4, 8192))
    >>> t = temporal_psd(x, 1000.0, nperseg=512)
    >>> round(float(np.mean(t["psd"])) / (2 / 1000.0), 2)
    1.0
    """
    unit = stream.unit if isinstance(stream, u.Quantity) else u.one
    x = np.asarray(getattr(stream, "value", stream), dtype=np.float64)
    if x.ndim == 0 or x.shape[-1] < 4:
        raise SpherexReduceError(f"a timestream needs at least 4 samples, got shape {x.shape}")
    fs = float(u.Quantity(sample_rate, u.Hz).value)
    n = x.shape[-1]
    nperseg = int(min(n, 4096) if nperseg is None else nperseg)
    if not 4 <= nperseg <= n:
        raise SpherexReduceError(f"nperseg must be in [4, {n}] (the stream length), got {nperseg}")
    noverlap = nperseg // 2 if noverlap is None else int(noverlap)
    if not 0 <= noverlap < nperseg:
        raise SpherexReduceError(f"noverlap must be in [0, nperseg), got {noverlap}")
    if not np.all(np.isfinite(x)):
        raise SpherexReduceError("the timestream has NaN or infinite samples; remove them first")
    window = scipy.signal.get_window("hann", nperseg)
    f, p = scipy.signal.welch(x.reshape(-1, n), fs=fs, window=window, nperseg=nperseg,
                              noverlap=noverlap, detrend=detrend, axis=-1)
    p = p.mean(axis=0)
    nseg = (n - noverlap) // (nperseg - noverlap)
    keep = f > 0
    if nperseg % 2 == 0:
        keep[-1] = False  # the Nyquist ordinate: scipy does not double it
    return Table({"frequency": f[keep] * u.Hz, "psd": p[keep] * unit**2 / u.Hz},
                 meta={"nperseg": nperseg, "noverlap": noverlap, "nsegments": int(nseg),
                       "nstreams": int(np.prod(x.shape[:-1], dtype=int)),
                       "sample_rate": fs, "window": "hann"})


def _relative_variance(nperseg, noverlap, nsegments, m):
    """``Var(bin mean) / S²`` of the mean of ``m`` adjacent Welch frequencies, white noise.

    Exact for Gaussian white noise (and locally white spectra): the
    periodogram ordinates at frequency offset ``q`` of segments offset by
    ``d`` samples have correlation ``|Σ w_n w_{n+d} e^{-2πi q n/N}|² / (Σ w²)²``.
    """
    w = scipy.signal.get_window("hann", nperseg)
    norm = np.sum(w**2) ** 2
    step = nperseg - noverlap
    m = np.asarray(m, dtype=int)
    mmax = int(m.max())
    total = np.zeros(m.shape, dtype=float)
    for d in range(-(nsegments - 1), nsegments):
        lag = abs(d) * step
        if lag >= nperseg:
            continue
        g = np.zeros(nperseg)
        g[: nperseg - lag] = w[: nperseg - lag] * w[lag:]
        rho = np.abs(np.fft.fft(g)) ** 2 / norm  # rho[q] for q = 0 .. nperseg-1
        q = np.arange(mmax)
        rq = rho[q]  # offsets 0 .. mmax-1 (rho is symmetric in q)
        for i, mi in enumerate(m.ravel()):
            qq = q[:mi]
            s = rq[0] * mi + 2 * np.sum((mi - qq[1:]) * rq[1:mi])
            total.ravel()[i] += (nsegments - abs(d)) * s
    return total / (m.astype(float) ** 2 * nsegments**2)


# -- model -----------------------------------------------------------------------------
def model_basis(frequency, exponent=1.3):
    """The three terms ``1, 1/f, 1/f^exponent`` at ``frequency`` (Hz), shape ``(n, 3)``.

    Examples
    --------
    >>> from spherex_reduce.analysis import model_basis
    >>> model_basis([1.0, 10.0], exponent=2).tolist()
    [[1.0, 1.0, 1.0], [1.0, 0.1, 0.01]]
    """
    f = np.asarray(u.Quantity(frequency, u.Hz).value, dtype=float)
    return np.stack([np.ones_like(f), 1 / f, f ** (-float(exponent))], axis=-1)


def aliased_basis(frequency, sample_rate, decimation, nbox=1, exponent=1.3, stride=1):
    """Model terms of a stream of ``nbox``-sample means taken every ``decimation`` samples.

    A process sampled at ``sample_rate`` with one-sided PSD ``p(f)`` on
    ``(0, sample_rate/2]``, averaged over ``nbox`` samples ``stride`` apart
    once every ``decimation`` samples (phantom reads: ``nbox = c``,
    ``decimation`` = samples per row read; one column parity of the border
    columns: ``stride = 2``), has at ``f < sample_rate / (2 · decimation)``
    the PSD ``Σ_m p(|f + m f_r|) |B(f + m f_r)|²`` (``f_r = sample_rate /
    decimation``, ``m = 0 … decimation−1``, frequencies folded into
    ``±sample_rate/2``, ``B`` the response of the average).  Returns the
    three terms of eq. 1 through that map, shape ``(n, 3)``; it is linear, so
    ``α, β, γ`` fit directly.

    Examples
    --------
    White noise ``α`` averaged over 4 samples every 72 reads ``α · 72 / 4``:

    >>> from spherex_reduce.analysis import aliased_basis
    >>> float(aliased_basis([100.0], 1e5, 72, 4)[0, 0])
    18.0
    """
    f = np.asarray(u.Quantity(frequency, u.Hz).value, dtype=float)
    fs = float(sample_rate)
    mdec, nbox, stride = int(decimation), int(nbox), int(stride)
    if nbox < 1 or stride < 1 or (nbox - 1) * stride >= mdec:
        raise SpherexReduceError(
            f"the averaged samples (nbox={nbox}, stride={stride}) must fit within one "
            f"decimation period ({mdec} samples)"
        )
    fr = fs / mdec
    alias = f[:, None] + np.arange(mdec)[None, :] * fr
    alias = (alias + fs / 2) % fs - fs / 2  # fold into [-fs/2, fs/2)
    af = np.abs(alias)
    x = np.pi * alias * stride / fs
    with np.errstate(invalid="ignore", divide="ignore"):
        b2 = np.where(np.abs(np.sin(x)) < 1e-12, 1.0,
                      (np.sin(nbox * x) / (nbox * np.sin(x))) ** 2)
        terms = [np.ones_like(af), 1 / af, af ** (-float(exponent))]
    return np.stack([np.sum(t * b2, axis=1) for t in terms], axis=-1)


@dataclasses.dataclass
class NoiseModelFit:
    """Result of `fit_noise_model`: coefficients, covariance and goodness of fit."""

    #: best-fit ``alpha`` (unit²/Hz), ``beta`` (unit²), ``gamma`` (unit²·Hz^(exponent−1))
    values: dict
    #: 1-σ uncertainties of the same
    errors: dict
    #: covariance matrix of the fitted parameters, in ``fitted`` order
    covariance: np.ndarray
    fitted: tuple
    exponent: float
    chi2: float
    dof: int
    frequency_range: tuple
    #: the binned spectrum and model: ``frequency psd psd_err model`` per bin and stream
    bins: Table = dataclasses.field(repr=False, default=None)
    #: 1-σ uncertainty of ``exponent`` when it was fitted (Δχ² = 1), else 0
    exponent_err: float = 0.0

    def model(self, frequency):
        """``α + β/f + γ/f^exponent`` at ``frequency`` (Hz)."""
        theta = np.array([self.values[p] for p in PARAMS])
        return model_basis(frequency, self.exponent) @ theta

    def to_row(self):
        """The fit as a dict of columns (``alpha alpha_err beta … chi2 dof``)."""
        row = {}
        for p in PARAMS:
            row[p] = self.values[p]
            row[f"{p}_err"] = self.errors[p]
        row.update(exponent=self.exponent, exponent_err=self.exponent_err, chi2=self.chi2,
                   dof=self.dof,
                   fmin=self.frequency_range[0], fmax=self.frequency_range[1])
        return row


def _log_bins(f, nbins):
    """Group indices of frequencies into ``nbins`` log-spaced bins (empty bins dropped)."""
    edges = np.geomspace(f.min(), f.max() * (1 + 1e-12), nbins + 1)
    idx = np.clip(np.searchsorted(edges, f, side="right") - 1, 0, nbins - 1)
    return [np.flatnonzero(idx == i) for i in range(nbins) if np.any(idx == i)]


def fit_noise_model(spectra, exponent=1.3, fmin=None, fmax=None, nbins=40, fit=PARAMS,
                    basis=None, maxiter=30, exponent_range=(0.5, 3.0)):
    """Fit ``p(f) = α + β/f + γ/f^exponent`` to one or more Welch spectra.

    Parameters
    ----------
    spectra : `~astropy.table.Table` or list of them
        From `temporal_psd`.  Several spectra of the same process (e.g. a
        decimated stream and full-rate bursts) are fitted jointly; each needs
        its own ``basis`` then.
    exponent : float or None
        The exponent of the third term (1.3 in the paper).  ``None`` fits it
        too, by minimising χ² over ``exponent_range`` (the three coefficients
        are refitted at each trial value); its error is where χ² rises by 1,
        and the coefficients' errors are then conditional on the exponent.
    fmin, fmax : float or `~astropy.units.Quantity`, optional
        Frequency range (Hz).  By default from the third Welch frequency (the
        first two are shaped by per-segment detrending and window leakage) to
        the highest.
    nbins : int
        Logarithmic frequency bins per spectrum.
    fit : sequence of {'alpha', 'beta', 'gamma'}
        Terms to fit; the others are fixed at zero.
    basis : callable or list of callables, optional
        ``basis(frequency_Hz, exponent) -> (n, 3)`` model terms per spectrum;
        `model_basis` by default, `aliased_basis` for decimated streams.
    maxiter : int
        Re-weighting iterations.

    Returns
    -------
    `NoiseModelFit`

    Examples
    --------
    >>> import numpy as np
    >>> from spherex_reduce.analysis import fit_noise_model, temporal_psd
    >>> x = np.random.default_rng(3).normal(0, 1, (8, 16384))
    >>> r = fit_noise_model(temporal_psd(x, 1e5, nperseg=1024))
    >>> alpha = 2 / 1e5                        # white: p = 2 σ² / fs
    >>> bool(abs(r.values["alpha"] - alpha) < 4 * r.errors["alpha"])
    True
    """
    if isinstance(spectra, Table):
        spectra = [spectra]
    if basis is None:
        basis = [model_basis] * len(spectra)
    elif callable(basis):
        basis = [basis] * len(spectra)
    if len(basis) != len(spectra):
        raise SpherexReduceError("give one basis per spectrum")
    fit = tuple(fit)
    bad = set(fit) - set(PARAMS)
    if bad or not fit:
        raise SpherexReduceError(f"fit must name some of {PARAMS}, got {fit}")
    args = (fmin, fmax, nbins, fit, basis, maxiter)
    if exponent is not None:
        return _fit_fixed(spectra, float(exponent), *args)
    if "gamma" not in fit:
        raise SpherexReduceError("fitting the exponent needs 'gamma' among the fitted terms")
    return _fit_exponent(spectra, exponent_range, *args)


def _fit_exponent(spectra, bounds, *args):
    """Profile χ² over the exponent; error from Δχ² = 1 (NaN where not bracketed)."""
    from scipy.optimize import brentq, minimize_scalar

    lo, hi = (float(b) for b in bounds)

    def chi2(e):
        return _fit_fixed(spectra, e, *args).chi2

    grid = np.linspace(lo, hi, 12)  # steps of ~0.23: avoids landing on exponent 1
    values = [chi2(e) for e in grid]
    i = int(np.argmin(values))
    a, b = grid[max(i - 1, 0)], grid[min(i + 1, grid.size - 1)]
    best = minimize_scalar(chi2, bounds=(a, b), method="bounded",
                           options={"xatol": 1e-4}).x
    result = _fit_fixed(spectra, float(best), *args)
    target = result.chi2 + 1.0
    sides = []
    for edge in (lo, hi):
        if chi2(edge) > target:
            root = brentq(lambda e: chi2(e) - target, min(best, edge), max(best, edge),
                          xtol=1e-5)
            sides.append(abs(root - best))
    result.exponent_err = float(np.mean(sides)) if len(sides) == 2 else float("nan")
    return result


def _fit_fixed(spectra, exponent, fmin, fmax, nbins, fit, basis, maxiter):
    cols = [PARAMS.index(p) for p in fit]
    ys, xs, rv, fb, which = [], [], [], [], []
    lo_all, hi_all = np.inf, 0.0
    for s, (spec, fun) in enumerate(zip(spectra, basis, strict=True)):
        for key in ("nperseg", "noverlap", "nsegments", "nstreams"):
            if key not in spec.meta:
                raise SpherexReduceError(f"spectrum meta lacks {key!r}; use temporal_psd")
        f = np.asarray(u.Quantity(spec["frequency"], u.Hz).value)
        p = np.asarray(u.Quantity(spec["psd"]).value)
        lo = f[min(2, f.size - 1)] if fmin is None else u.Quantity(fmin, u.Hz).value
        hi = f.max() if fmax is None else u.Quantity(fmax, u.Hz).value
        sel = (f >= lo) & (f <= hi)
        if sel.sum() < 2:
            continue
        f, p = f[sel], p[sel]
        lo_all, hi_all = min(lo_all, f.min()), max(hi_all, f.max())
        groups = _log_bins(f, nbins)
        m = np.array([g.size for g in groups])
        meta = spec.meta
        rel = _relative_variance(meta["nperseg"], meta["noverlap"], meta["nsegments"], m)
        rel = rel / meta["nstreams"]
        terms = fun(f, exponent)[:, cols]
        for g, r in zip(groups, rel, strict=True):
            ys.append(p[g].mean())
            xs.append(terms[g].mean(axis=0))
            rv.append(r)
            fb.append(np.exp(np.log(f[g]).mean()))
            which.append(s)
    if len(ys) <= len(fit):
        raise SpherexReduceError(
            f"only {len(ys)} frequency bins in range for {len(fit)} parameters; widen "
            "fmin/fmax or use longer streams"
        )
    y, x, rv = np.array(ys), np.array(xs), np.array(rv)
    if not (np.all(np.isfinite(y)) and np.max(np.abs(y)) > 0):
        raise SpherexReduceError(
            "the power spectrum is not finite, or zero at every frequency: no noise to fit "
            "(is the stream constant, e.g. all zero, or not a number?)")
    var = np.maximum(y, np.max(np.abs(y)) * 1e-12) ** 2 * rv
    theta = np.zeros(len(fit))
    for _ in range(maxiter):
        wsq = 1 / np.sqrt(var)
        theta_new, *_ = np.linalg.lstsq(x * wsq[:, None], y * wsq, rcond=None)
        model = x @ theta_new
        floor = np.max(np.abs(y)) * 1e-6
        var = np.maximum(model, floor) ** 2 * rv
        done = np.allclose(theta_new, theta, rtol=1e-10, atol=0)
        theta = theta_new
        if done:
            break
    xw = x / np.sqrt(var)[:, None]
    # pinv: with beta and gamma both fitted, exponent -> 1 makes the two terms identical
    cov = np.linalg.pinv(xw.T @ xw)
    err = np.sqrt(np.diag(cov))
    model = x @ theta
    chi2 = float(np.sum((y - model) ** 2 / var))
    values = dict.fromkeys(PARAMS, 0.0)
    errors = dict.fromkeys(PARAMS, 0.0)
    for i, p in enumerate(fit):
        values[p] = float(theta[i])
        errors[p] = float(err[i])
    bins = Table({"spectrum": np.array(which), "frequency": np.array(fb) * u.Hz,
                  "psd": y, "psd_err": np.sqrt(var), "model": model})
    return NoiseModelFit(values, errors, cov, fit, float(exponent), chi2, int(y.size - len(fit)),
                         (float(lo_all), float(hi_all)), bins)


# -- streams of a raw exposure ----------------------------------------------------------
class Timestream(NamedTuple):
    """Values of a stream with the sample index of each value (in pixel-rate samples)."""

    #: ``(..., nframes, n)``: streams first (channels), then frames, then time within a frame
    values: np.ndarray
    #: ``(nframes, n)``: sample index from the start of the exposure (the value's first sample)
    samples: np.ndarray
    #: samples averaged into each value (``c`` for phantoms)
    nbox: int
    #: the pixel rate (Hz)
    sample_rate: float
    #: spacing (samples) of the averaged samples, or of the values of a burst
    stride: int = 1


def _raw(exposure):
    if not exposure.is_ramp or exposure.order != "readout":
        raise SpherexReduceError(
            "noise streams come from a raw exposure: ramps (frames × reads × columns) in "
            f"readout order; got {'ramps' if exposure.is_ramp else 'an image'} in "
            f"{exposure.order} order"
        )
    if exposure.schedule.nframes < 3:
        raise SpherexReduceError("noise streams need at least 3 frames (a line is removed "
                                 "from every position across frames)")


def _detrend_frames(values):
    """Remove a straight line across frames (axis -2) at every position; float64 copy.

    Returns the residual scaled by ``sqrt(N / (N - 2))`` so that noise that is
    independent from frame to frame keeps its variance.
    """
    v = np.asarray(values, dtype=np.float64)
    n = v.shape[-2]
    t = np.arange(n, dtype=float) - (n - 1) / 2
    mean = v.mean(axis=-2, keepdims=True)
    slope = np.tensordot(t, v, axes=([0], [v.ndim - 2])) / np.sum(t**2)
    res = v - mean - t[:, None] * slope[..., None, :]
    return res * np.sqrt(n / (n - 2))


def _frame_samples(schedule, within):
    within = np.asarray(within, dtype=np.int64)
    frames = np.arange(schedule.nframes, dtype=np.int64) * schedule.frame_samples
    return frames.reshape((-1,) + (1,) * within.ndim) + within[None, ...]


def phantom_timestream(exposure):
    """Phantom values of every channel in time order, detrended across frames.

    Parameters
    ----------
    exposure : `~spherex_reduce.Exposure`
        Raw ramps in readout order with a ``phantom`` array.

    Returns
    -------
    `Timestream`
        ``values`` ``(nchannels, nframes, n_reads)``; ``samples`` the first of
        the ``c`` phantom samples of each read.  A straight line across frames
        is removed at every read position (the Video8 leakage drift and any
        offset) and the residual rescaled by ``sqrt(N/(N−2))``.
    """
    _raw(exposure)
    s = exposure.schedule
    if exposure.phantom is None or s.phantom_reads == 0:
        raise SpherexReduceError("the exposure has no phantom reads (c = 0 or no PHANTOM)")
    vals = np.moveaxis(np.asarray(exposure.phantom), -1, 0)  # channels, frames, reads
    return Timestream(_detrend_frames(vals), _frame_samples(s, s.phantom_samples()[:, 0]),
                      s.phantom_reads, s.geometry.pixel_rate)


def reference_timestream(exposure, source="columns", parity=None):
    """Reference-pixel values in time order, detrended across frames.

    Parameters
    ----------
    exposure : `~spherex_reduce.Exposure`
        Raw ramps in readout order.
    source : {'columns', 'rows'}
        ``'columns'``: the side border columns (left of the first channel,
        right of the last), averaged per read: one value per row read,
        ``values`` ``(2, nframes, n_reads)``.  ``'rows'``: every reference-row
        read of every channel at the pixel rate, in each channel's scan order,
        ``values`` ``(nchannels, nframes, n_ref_reads, width)``.
    parity : {None, 'even', 'odd'}
        Keep only the pixels sampled at even or odd offsets of a channel's
        row read (the column parities that alternating column noise, ACN,
        gives independent realisations); ``stride`` becomes 2.

    Returns
    -------
    `Timestream`
        ``samples`` has the sample index of each value (the first averaged
        sample for ``'columns'``).
    """
    _raw(exposure)
    s, g = exposure.schedule, exposure.geometry
    if parity not in (None, "even", "odd"):
        raise SpherexReduceError(f"parity must be None, 'even' or 'odd', got {parity!r}")
    first_off = {None: 0, "even": 0, "odd": 1}[parity]
    stride = 1 if parity is None else 2
    data = np.asarray(exposure.data.data)
    offs = g.column_offsets()
    if source == "columns":
        b = g.ref_border
        if b == 0:
            raise SpherexReduceError("the array has no reference border (ref_border = 0)")
        sides = [np.arange(b), np.arange(g.ncols - b, g.ncols)]
        if parity is not None:
            sides = [c[offs[c] % 2 == first_off] for c in sides]
            if any(c.size == 0 for c in sides):
                raise SpherexReduceError("the border has no columns of that parity")
        nbox = sides[0].size
        vals = np.stack([data[:, :, c].mean(axis=-1) for c in sides])
        first = s.starts + offs[sides[0]].min()
        return Timestream(_detrend_frames(vals), _frame_samples(s, first), nbox,
                          g.pixel_rate, stride)
    if source == "rows":
        reads = s.reference_read_indices
        if reads.size == 0:
            raise SpherexReduceError("the schedule has no reference-row reads")
        w = g.channel_width
        order = np.argsort(offs.reshape(g.nchannels, w), axis=1)
        cols = order + (np.arange(g.nchannels) * w)[:, None]  # (nchannels, w) in scan order
        cols = cols[:, first_off::stride]
        vals = data[:, reads][:, :, cols]  # frames, nref, nchannels, w'
        vals = np.moveaxis(vals, 2, 0)  # channels, frames, nref, w'
        flat = _detrend_frames(vals.reshape(g.nchannels, s.nframes, -1))
        samples = s.starts[reads][:, None] + np.arange(first_off, w, stride)[None, :]
        return Timestream(flat.reshape(vals.shape), _frame_samples(s, samples), 1, g.pixel_rate,
                          stride)
    raise SpherexReduceError(f"source must be 'columns' or 'rows', got {source!r}")


def _burst_length(g, split):
    """Samples per reference-row burst of one channel (one parity if ``split``)."""
    return g.channel_width // 2 if split else g.channel_width


def _parity_psd(exposure, source, rate, nperseg, acn):
    """Welch PSD of a reference stream, split by column parity when ``acn``.

    The even and odd PSDs are averaged but the uncertainty counts the streams
    of one parity only: right when the parities are correlated (no ACN),
    conservative by up to √2 when they are independent.
    """
    if not acn:
        ts = reference_timestream(exposure, source)
        return temporal_psd(ts.values, rate, nperseg=nperseg), ts
    even = reference_timestream(exposure, source, "even")
    odd = reference_timestream(exposure, source, "odd")
    pe = temporal_psd(even.values, rate, nperseg=nperseg)
    po = temporal_psd(odd.values, rate, nperseg=nperseg)
    pe["psd"] = (pe["psd"] + po["psd"]) / 2
    return pe, even


def fit_raw_noise(exposure, exponent=1.3, nperseg=None, nbins=30, fit=PARAMS, acn=True):
    """Fit eq. 1 to the reference-pixel and phantom streams of a raw exposure.

    Welch spectra are computed within frames (segments never span the
    frame overhead).  Reference columns and phantom values are modelled as
    box-averaged, decimated streams (`aliased_basis`); reference rows are
    bursts at the pixel rate.  The reference fit joins columns and rows.

    Parameters
    ----------
    exposure : `~spherex_reduce.Exposure`
        Raw ramps in readout order.
    exponent : float or None
        Exponent of the third term; ``None`` fits it per stream.
    nperseg : int, optional
        Welch segment length of the per-read streams (default: the largest
        power of two not above the reads per frame).
    nbins : int
        Logarithmic bins per spectrum.
    fit : sequence of str
        Terms to fit.
    acn : bool
        Treat even and odd columns (offsets within a channel's row read) as
        separate streams, as alternating column noise makes them (paper §3.2;
        the simulator's default for Video8 and ROIC).  Averaging across
        parities would halve the low-frequency power of ACN terms.  The
        result is right with or without ACN; the uncertainties count one
        parity's streams, so they are conservative (by up to √2) when the
        parities are independent.  ``False`` uses every column as one stream.

    Returns
    -------
    `~astropy.table.Table`
        One row per stream (``reference``, ``phantom`` where the exposure has
        phantom reads): ``stream alpha alpha_err beta beta_err gamma gamma_err
        exponent chi2 dof fmin fmax`` (coefficients in the exposure's unit²
        per Hz etc., for the pixel-rate process).  ``meta['fits']`` holds the
        `NoiseModelFit` objects (not written to files).
    """
    _raw(exposure)
    s, g = exposure.schedule, exposure.geometry
    fs, m = g.pixel_rate, s.row_samples
    nreads = s.n_reads
    nper = nperseg or 2 ** int(np.floor(np.log2(nreads)))
    nper = min(nper, nreads)
    rows, fits_ = [], {}
    frate = fs / m
    spectra, bases, names = [], [], []
    if g.ref_border:
        split = acn and g.ref_border >= 2
        spec, ts = _parity_psd(exposure, "columns", frate, nper, split)
        spectra.append(spec)
        names.append("border columns")
        bases.append(lambda f, e, b=ts.nbox, st=ts.stride: aliased_basis(f, fs, m, b, e,
                                                                         stride=st))
    if s.reference_read_indices.size:
        split = acn and g.channel_width >= 8
        rate = fs / 2 if split else fs
        spec, tr = _parity_psd(exposure, "rows", rate, _burst_length(g, split), split)
        spectra.append(spec)
        names.append("re-read rows")
        bases.append(lambda f, e, d=tr.stride: aliased_basis(f, fs, d, 1, e))
    unit = exposure.unit or u.one
    if spectra:
        fits_["reference"] = fit_noise_model(spectra, exponent, nbins=nbins, fit=fit,
                                             basis=bases)
    if exposure.phantom is not None and s.phantom_reads:
        tp = phantom_timestream(exposure)
        spec = temporal_psd(tp.values, frate, nperseg=nper)
        fits_["phantom"] = fit_noise_model(
            spec, exponent, nbins=nbins, fit=fit,
            basis=lambda f, e: aliased_basis(f, fs, m, s.phantom_reads, e))
    if not fits_:
        raise SpherexReduceError("the exposure has neither reference pixels nor phantom reads")
    for name, fit_ in fits_.items():  # for plots: what each spectrum is, and the PSD's unit
        fit_.bins.meta.update({"spectra": names if name == "reference" else [name],
                               "psd_unit": unit**2 / u.Hz})
    for name, r in fits_.items():
        rows.append({"stream": name, **r.to_row()})
    t = Table(rows=rows)
    units = {"alpha": unit**2 / u.Hz, "beta": unit**2}
    if exponent is not None:
        units["gamma"] = unit**2 * u.Hz ** (exponent - 1)
    for p, unit_p in units.items():
        t[p].unit = unit_p
        t[f"{p}_err"].unit = unit_p
    t["fmin"].unit = t["fmax"].unit = u.Hz
    t.meta["fits"] = fits_
    label = "exponent" if exponent is None else exponent
    t.meta["comments"] = [f"p(f) = alpha + beta/f + gamma/f^{label}, one-sided, "
                          f"pixel rate {fs:g} Hz; {s.summary()}"]
    return t
