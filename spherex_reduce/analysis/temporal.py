"""Temporal noise spectra and the fit of ``p(f) = α + β/f + γ/f^exponent`` (paper eq. 1, Table 2).

The PSD is Welch's estimate (`scipy.signal.welch`, Hann window, one-sided
density: ``∫ p df`` is the variance, the convention of Table 2).  The fit is a
weighted linear least-squares fit of the three coefficients to the PSD averaged
in logarithmic frequency bins, iterated so that each bin's weight comes from
the model (its variance is ``model² · v``, with ``v`` the relative variance of
a Welch bin mean for locally white Gaussian noise, computed exactly from the
window, the segment overlap and the number of averaged segments, streams and
frequencies).  This is the Gaussian maximum-likelihood fit to first order, and
its covariance ``(Xᵀ W X)⁻¹`` gives the uncertainties.  The model a bin is fitted
with is what Welch's estimate expects (`welch_terms`): each term smoothed by the
window's spectral kernel, which at the lowest frequencies of a segment raises a
``1/f`` spectrum by 4 % (third frequency) and a ``1/f^1.3`` one by 6.5 %.  The coefficients are
not forced to be positive: a component that is absent comes back as
``0 ± σ``.
"""

import dataclasses
import functools

import numpy as np
import scipy.signal
from astropy import units as u
from astropy.table import Table

from ..core.errors import SpherexReduceError
from ..core.recently_used import RecentlyUsed

__all__ = [
    "NoiseModelFit",
    "aliased_basis",
    "fit_noise_model",
    "model_basis",
    "temporal_psd",
    "welch_terms",
]

PARAMS = ("alpha", "beta", "gamma")

#: Points per Welch frequency at which `welch_terms` takes a model to smooth it by the
#: window (the expectation of a 1/f^1.3 spectrum is then within 1.5e-4 of its limit at
#: the third frequency, 1e-3 at the second, 1.2e-2 at the first, which the fits leave out)
WINDOW_OVERSAMPLE = 4


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
        ``nstreams``, ``sample_rate``, ``window`` and ``detrend``, which
        `fit_noise_model` uses for the uncertainties and the model's expectation.

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
                       "sample_rate": fs, "window": "hann",
                       # a callable cannot be written with the table: its name stands for it
                       "detrend": detrend if isinstance(detrend, str) or not callable(detrend)
                       else "callable"})


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
def welch_terms(basis, frequency, exponent, meta):
    """Model terms as Welch's estimate expects them: each smoothed by the window.

    The periodogram of a Hann-windowed segment of ``nperseg`` samples at rate
    ``fs`` expects at frequency ``f`` the spectrum weighted by the window's
    kernel, ``∫ p(ν) |W(f − ν)|² dν / ∫ |W|² dν``; where ``p`` curves on the
    scale of a few frequencies (``1/f`` at the lowest ones of a segment) that
    is not ``p(f)``: at the third Welch frequency it is 4.2 % above a ``1/f``
    spectrum and 6.5 % above a ``1/f^1.3`` one, 0.5 % and 0.8 % at the eighth.
    A fit with the bare terms reads that excess as a steeper spectrum (``γ``
    high, ``β`` low: a bias of 1-2 standard errors on thousands of segments).
    The integral is a circular convolution over ``[-fs/2, fs/2)`` on a grid
    `WINDOW_OVERSAMPLE` times finer than the Welch frequencies.  A periodic Hann
    window's transform vanishes two or more Welch frequencies away from its
    centre, so there the segment's mean (``detrend="constant"``, removed or not)
    does not reach; at the first Welch frequency it does, and the kernel there
    is that of the window less the mean's removal, exactly.

    Parameters
    ----------
    basis : callable
        ``basis(frequency_Hz, exponent) -> (n, k)`` terms of the spectrum on
        ``(0, fs/2]`` (`model_basis`, `aliased_basis`).
    frequency : array_like
        Frequencies (Hz) in ``(0, fs/2]``, shape ``(n,)``.
    exponent : float
        The exponent of the third term.
    meta : dict
        The spectrum's metadata from `temporal_psd`: ``nperseg``,
        ``sample_rate`` (Hz), ``window`` (``"hann"``) and ``detrend``
        (``"constant"`` or False; absent: ``"constant"``, `temporal_psd`'s
        default).

    Returns
    -------
    `numpy.ndarray`
        The smoothed terms at ``frequency``, shape ``(n, k)``.

    Raises
    ------
    `~spherex_reduce.core.errors.SpherexReduceError`
        Another window or detrending (``"linear"`` reaches every frequency), a
        frequency outside ``(0, fs/2]``, or the first Welch frequency of a
        spectrum that was not detrended (it holds the power at ``f = 0``).

    Examples
    --------
    White noise is not changed; ``1/f`` is raised where it curves:

    >>> from spherex_reduce.analysis import model_basis, welch_terms
    >>> meta = {"nperseg": 256, "sample_rate": 1.0, "window": "hann"}
    >>> t = welch_terms(model_basis, [3 / 256, 100 / 256], 1.3, meta)
    >>> (t / model_basis([3 / 256, 100 / 256], 1.3)).round(3).tolist()
    [[1.0, 1.042, 1.065], [1.0, 1.0, 1.0]]
    """
    if meta.get("window") != "hann":
        raise SpherexReduceError(f"the spectrum's window is {meta.get('window')!r}: the fit "
                                 "knows the Hann window of temporal_psd only")
    detrend = meta.get("detrend", "constant")
    undetrended = not isinstance(detrend, str) and detrend is not None and not detrend
    if detrend != "constant" and not undetrended:
        raise SpherexReduceError(f"the spectrum's detrend is {detrend!r}: the fit knows "
                                 "temporal_psd's 'constant' (or none) only")
    f = np.asarray(u.Quantity(frequency, u.Hz).value, dtype=float)
    n, fs = int(meta["nperseg"]), float(meta["sample_rate"])
    m = n * WINDOW_OVERSAMPLE
    grid = np.arange(1, m // 2 + 1) * (fs / m)  # (0, fs/2]
    if f.size and not (f.min() > 0 and f.max() <= grid[-1] * (1 + 1e-12)):
        raise SpherexReduceError(f"welch_terms takes frequencies in (0, {fs / 2:g}] Hz, "
                                 f"got {f.min():g} to {f.max():g}")
    terms = np.asarray(basis(grid, exponent), dtype=float)
    two_sided = np.zeros((m, terms.shape[1]))  # on nu_j = j fs / m, j mod m; f = 0 left out
    two_sided[1: m // 2 + 1] = terms
    two_sided[m // 2 + 1:] = terms[: m - m // 2 - 1][::-1]  # p(-f) = p(f)
    kernel = _window_kernel(n, m)
    smooth = np.fft.irfft(np.fft.rfft(two_sided, axis=0) * kernel[:, None],
                          n=m, axis=0)[1: m // 2 + 1]
    out = np.stack([np.interp(f, grid, smooth[:, j]) for j in range(terms.shape[1])],
                   axis=-1)
    first = np.flatnonzero(f < 1.5 * fs / n)  # the first Welch frequency: the mean reaches it
    if first.size and undetrended:
        raise SpherexReduceError(
            "the first Welch frequency of a spectrum that was not detrended holds the power "
            "at f = 0, which no model term gives: leave it out (fmin)")
    t = np.arange(n)
    w = _hann(n)
    for i in first:  # x_n less its mean, windowed: sum_n g_n x_n, g_n = w_n e^(-i w n) - W / n
        g = w * np.exp(-2j * np.pi * f[i] * t / fs)
        g -= g.sum() / n
        # |sum_n g_n e^(+2 pi i nu n / fs)|^2 on the grid (0 at nu = 0: the mean is gone)
        gain = np.abs(np.fft.fft(np.conj(g), m)) ** 2
        out[i] = gain @ two_sided / (m * np.sum(w * w))
    return out


@functools.lru_cache(maxsize=16)
def _hann(n):
    """`temporal_psd`'s window of ``n`` samples (read only: cached)."""
    w = scipy.signal.get_window("hann", n)
    w.setflags(write=False)
    return w


@functools.lru_cache(maxsize=16)
def _window_kernel(n, m):
    """The Hann window's ``|W|²`` on ``m`` frequencies, normalised to sum 1, transformed
    (real: the kernel is even)."""
    k = np.abs(np.fft.fft(_hann(n), m)) ** 2
    return np.fft.rfft(k / k.sum()).real


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


def aliased_basis(frequency, sample_rate, decimation, nbox=1, exponent=1.3, stride=1,
                  cross=None):
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

    With ``cross = (nbox2, stride2, lag)`` the terms are those of the real
    part of the cross-spectrum between this average and a second one of
    ``nbox2`` samples ``stride2`` apart whose centre is ``lag`` samples
    later: ``Σ_m p(|g|) B(g) B₂(g) cos(2π g lag / sample_rate)`` (``B``
    real, the responses about each average's centre).

    Examples
    --------
    White noise ``α`` averaged over 4 samples every 72 reads ``α · 72 / 4``:

    >>> from spherex_reduce.analysis import aliased_basis
    >>> float(aliased_basis([100.0], 1e5, 72, 4)[0, 0])
    18.0

    The cross-spectrum of two averages of different samples has no white term:

    >>> white = aliased_basis([100.0], 1e5, 72, 4, cross=(64, 1, 34))[0, 0]
    >>> bool(abs(white) < 1e-12)
    True
    """
    f = np.asarray(u.Quantity(frequency, u.Hz).value, dtype=float)
    fs = float(sample_rate)
    mdec = int(decimation)
    boxes = [(int(nbox), int(stride))]
    if cross is not None:
        boxes.append((int(cross[0]), int(cross[1])))
    for n, st in boxes:
        if n < 1 or st < 1 or (n - 1) * st >= mdec:
            raise SpherexReduceError(
                f"the averaged samples (nbox={n}, stride={st}) must fit within one "
                f"decimation period ({mdec} samples)"
            )
    key = (f.tobytes(), f.shape, fs, mdec, boxes[0], float(exponent),
           None if cross is None else (boxes[1], float(cross[2])))
    # the fit over all darks and each of its jackknife fits ask for the same terms
    return _BASES.get(key, lambda: _aliased_terms(f, fs, mdec, boxes, exponent, cross)).copy()


#: Bytes of model terms kept (`aliased_basis`): a full-size dark's spectra ask for ~100
#: sets of terms of ~24 kB each (more while an exponent is fitted).
BASES_BYTES = 16 * 2**20
_BASES = RecentlyUsed(BASES_BYTES, size=lambda terms: terms.nbytes)


def _aliased_terms(f, fs, mdec, boxes, exponent, cross):
    """`aliased_basis` itself (its arguments checked)."""
    fr = fs / mdec
    alias = f[:, None] + np.arange(mdec)[None, :] * fr
    alias = (alias + fs / 2) % fs - fs / 2  # fold into [-fs/2, fs/2)
    af = np.abs(alias)

    def response(n, st):  # real: the box's response about its centre
        x = np.pi * alias * st / fs
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.where(np.abs(np.sin(x)) < 1e-12, np.cos(n * x) / np.cos(x),
                            np.sin(n * x) / (n * np.sin(x)))

    b = response(*boxes[0])
    if cross is None:
        b2 = b**2
    else:
        b2 = b * response(*boxes[1]) * np.cos(2 * np.pi * alias * float(cross[2]) / fs)
    with np.errstate(invalid="ignore", divide="ignore"):
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
        its own ``basis`` then.  A spectrum with a ``weight`` column (same unit
        as ``psd``, > 0) is weighted by it rather than by the model: each bin's
        variance is ``weight² · v``, fixed, so the fit is linear in the
        spectrum (a cross-spectrum, or a difference of spectra, whose scatter
        follows the auto-spectra and not its own mean).
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
    ys, xs, rv, fb, which, levels = [], [], [], [], [], []
    lo_all, hi_all = np.inf, 0.0
    for s, (spec, fun) in enumerate(zip(spectra, basis, strict=True)):
        for key in ("nperseg", "noverlap", "nsegments", "nstreams", "sample_rate",
                    "window"):
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
        terms = welch_terms(fun, f, exponent, meta)[:, cols]
        level = (np.asarray(spec["weight"])[sel] if "weight" in spec.colnames else None)
        for g, r in zip(groups, rel, strict=True):
            ys.append(p[g].mean())
            levels.append(np.nan if level is None else level[g].mean())
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
    fixed = np.isfinite(levels := np.array(levels))
    if fixed.any():  # a given scatter (a cross-spectrum's follows its auto-spectra)
        if not (fixed.all() and np.all(levels > 0)):
            raise SpherexReduceError("a spectrum's weight column must be positive wherever "
                                     "it is given, and given for every spectrum of a fit")
        var = levels**2 * rv
    theta = np.zeros(len(fit))
    for _ in range(maxiter if not fixed.any() else 1):
        wsq = 1 / np.sqrt(var)
        theta_new, *_ = np.linalg.lstsq(x * wsq[:, None], y * wsq, rcond=None)
        model = x @ theta_new
        floor = np.max(np.abs(y)) * 1e-6
        if not fixed.any():
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
