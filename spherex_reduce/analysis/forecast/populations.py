"""The pixel populations' share of a forecast: white power, each pixel on its own.

A scene's pixel populations (``scene:`` terms, `~spherex_reduce.simulation.load_scene`)
make each light-sensitive pixel's slope depart from the others' independently of every
other pixel, so their expected ``|FFT|²`` is the same in every cell of the Fourier plane:
the variance over the pixels of what they add to a slope.  The forecast is the average
over realisations of ``simulate`` (with ``population_seed`` the populations are those of
one detector in every realisation: the forecast is then the average over detectors):

- **a spread of the dark current** ``σ_D`` (gamma-distributed about ``dark_current``):
  ``σ_D²``, a fixed pattern; its Poisson noise is that of the mean current, already in
  the ``poisson`` part;
- **hot pixels** (a fraction ``p`` of the active pixels, their excess current ``x``
  gamma-distributed about ``hot_pixel_current``): ``p E[x²] - (p E[x])²`` and their
  Poisson noise, ``p E[x]`` times the slope's Poisson factor.  A pipeline's
  ``sigma_clip`` masks, in the measurement, the pixels beyond its upper threshold
  (``sigma_upper`` or ``sigma`` times the standard deviation of the pixels it keeps,
  the forecast's with the hot pixels kept, to its fixed point): a pixel of excess ``x``
  is kept with the chance ``Φ((threshold - x) / σ)`` its noise ``σ`` (the forecast's
  pixel standard deviation without hot pixels) gives it, averaged over the gamma's
  quantiles, and the kept ones weighed as the unmasked pixels they are (the measured
  spectrum is divided by the unmasked fraction ``u``); the mask itself moves power
  between scales: on a field of spectrum ``P`` and pixel variance ``V`` a mask of
  pixels chosen independently of it measures ``u P(k) + (1 - u) V`` (the forecast's
  ``power_masked`` column, ``(1 - u) (V - P)``: a field with most of its variance in
  stripes gains it at every scale);
- **telegraph pixels** of ``rtn`` populations on the active pixels (``pixels: active`` or
  ``all``; a fraction ``f``, steps ``A`` and rates ``r`` per state, each
  gamma-distributed about its mean): a pixel switches, frame to frame, between two
  states with the autocovariance ``A²/4 exp(-2 r |j - k| T)`` at reads ``j`` and ``k``
  (``T`` the frame time; the simulator's chain,
  `~spherex_reduce.simulation.telegraph`), so its least-squares slope (weights ``w``)
  has the variance ``E[A²]/4 Σ_jk w_j w_k E[exp(-2 r |j - k| T)]``, the rates' average
  that of a gamma: ``(1 + 2 |j - k| T θ)^(-κ)`` (shape ``κ``, scale ``θ``); times
  ``f``.  Not clipped (a ``sigma_clip`` is forecast as no clipping);
- **telegraph reference pixels** (``pixels: reference`` or ``all``) are left out, with
  a warning: their steps reach the image only through the reference average, each at
  one over the number of reference pixels averaged.
"""

import warnings

import numpy as np
from astropy.utils.exceptions import AstropyUserWarning
from scipy.special import gammaincinv, ndtr  # (scipy.stats would load scipy.optimize)

from ...noise.variance import slope_frames

__all__ = ["POPULATIONS", "clipped_populations", "clipped_sigma", "population_variances",
           "shot_factor"]

#: the names of the populations' parts of a forecast (its ``power_<name>`` columns)
POPULATIONS = ("dark_spread", "hot_pixels", "telegraph")
#: quantiles of the hot pixels' gamma over which the clip's share is averaged
HOT_QUANTILES = 4096
#: telegraph slopes drawn (a fixed seed per population) for a clip's mixture
TELEGRAPH_CHAINS = 20000


def clipped_sigma(weights, means, variance, sigma=5.0, tol=1e-10, maxiter=200):
    """Standard deviation, after iterative clipping at ``sigma``, of a Gaussian mixture.

    The large-sample limit of `astropy.stats.sigma_clipped_stats` (centre 0: the
    mixture is symmetric) for values drawn from ``Σ_i weights_i N(means_i, variance)``.

    Parameters
    ----------
    weights, means : array_like
        Weight and mean of each Gaussian (weights summing to 1).
    variance : float
        The Gaussians' common variance (> 0).
    sigma : float or None
        The clip; None: no clip.

    Returns
    -------
    float

    Examples
    --------
    One Gaussian clipped at 5 σ keeps almost all its width, ``σ (1 − 2 c φ(c))^½``
    for ``c = 5``:

    >>> from spherex_reduce.analysis.forecast.populations import clipped_sigma
    >>> round(clipped_sigma([1.0], [0.0], 4.0), 6)
    1.999985
    """
    wt = np.asarray(weights, dtype=np.float64)
    mu = np.asarray(means, dtype=np.float64)
    s = np.sqrt(float(variance))
    total = float(np.sum(wt * (mu * mu + variance)))
    if sigma is None:
        return float(np.sqrt(total))
    std = np.sqrt(total)
    for _ in range(maxiter):
        c = sigma * std
        a, b = (-c - mu) / s, (c - mu) / s
        pa, pb = np.exp(-a * a / 2), np.exp(-b * b / 2)
        pa, pb = pa / np.sqrt(2 * np.pi), pb / np.sqrt(2 * np.pi)
        kept = ndtr(b) - ndtr(a)
        m1 = mu * kept + s * (pa - pb)
        m2 = (mu * mu + variance) * kept + 2 * mu * s * (pa - pb) + variance * (a * pa - b * pb)
        frac = float(np.sum(wt * kept))
        mean = float(np.sum(wt * m1)) / frac
        new = np.sqrt(max(float(np.sum(wt * m2)) / frac - mean * mean, 0.0))
        if abs(new - std) <= tol * std:
            return float(new)
        std = new
    return float(std)


def clipped_populations(terms):
    """Whether a clip of the slope image acts on these scene terms' populations (hot
    pixels, telegraph light-sensitive pixels)."""
    return bool((terms.hot_pixel_fraction > 0 and terms.hot_pixel_current > 0)
                or any(r.on and r.pixels in ("active", "all") for r in terms.telegraphs))


def shot_factor(schedule):
    """The variance of a uniform least-squares slope per unit Poisson current: ``w' W w``,
    ``W[j, k] = min(t_j, t_k) - t_0`` (s⁻¹: (e/s)² per e/s).

    Examples
    --------
    >>> from spherex_reduce import DetectorGeometry, ReadoutSchedule
    >>> from spherex_reduce.analysis.forecast.populations import shot_factor
    >>> s = ReadoutSchedule(DetectorGeometry(8, 8, 1, ref_border=0), nframes=4,
    ...                     phantom_reads=0, ref_reads=0, skip=1, ref_mode="none",
    ...                     frame_time=1.0)
    >>> round(shot_factor(s), 4)   # 6 (n² + 1) / (5 n (n² - 1)) / T
    0.34
    """
    w, _, _ = slope_frames(schedule)
    t = schedule.frame_starts.to_value("s")
    return float(w @ (np.minimum.outer(t, t) - t[0]) @ w)


def _gamma_shape_scale(mean, spread):
    """``(shape, scale)`` of the gamma of that mean and standard deviation (None: fixed)."""
    if not spread > 0:
        return None
    return mean * mean / (spread * spread), spread * spread / mean


def _hot_excess(mean, spread):
    """The hot pixels' excess current on `HOT_QUANTILES` quantiles of its gamma (one value
    without a spread)."""
    gs = _gamma_shape_scale(mean, spread)
    if gs is None:
        return np.array([float(mean)])
    return gammainc_quantiles(gs[0], HOT_QUANTILES) * gs[1]


def gammainc_quantiles(shape, n):
    """``n`` mid-quantiles of the unit-scale gamma of ``shape``."""
    return gammaincinv(shape, (np.arange(n) + 0.5) / n)


def _telegraph_slopes(schedule, population, n, seed):
    """``n`` draws of a telegraph pixel's least-squares slope (e/s): the simulator's chain
    (a flip from one frame to the next with the chance ``(1 - exp(-2 r T)) / 2``, the
    first state either), its step and rate from their gammas, scaled so that their mean
    square is the exact variance (`_telegraph_variance`)."""
    rng = np.random.default_rng(seed)
    w, _, _ = slope_frames(schedule)
    frame = schedule.frame_samples / schedule.geometry.pixel_rate
    amp = _draw(rng, population.amplitude, population.amplitude_spread, n)
    rate = _draw(rng, population.rate, population.rate_spread, n)
    flips = rng.random((n, w.size - 1)) < (-np.expm1(-2.0 * rate * frame) / 2.0)[:, None]
    start = rng.random((n, 1)) < 0.5
    states = np.concatenate([start, start ^ np.logical_xor.accumulate(flips, axis=1)], axis=1)
    y = amp * (states @ w)
    ms = float(np.mean(y * y))
    return y * np.sqrt(_telegraph_variance(schedule, population) / ms) if ms > 0 else y


def _draw(rng, mean, spread, n):
    """``n`` values of the gamma of that mean and spread (``mean`` without a spread)."""
    gs = _gamma_shape_scale(mean, spread)
    return np.full(n, float(mean)) if gs is None else rng.gamma(gs[0], gs[1], n)


def _telegraph_variance(schedule, population):
    """The variance of a telegraph pixel's least-squares slope ((e/s)²)."""
    w, _, _ = slope_frames(schedule)
    n = w.size
    frame = schedule.frame_samples / schedule.geometry.pixel_rate  # s: the chain's step
    lag = np.abs(np.subtract.outer(np.arange(n), np.arange(n))) * frame
    gs = _gamma_shape_scale(population.rate, population.rate_spread)
    if gs is None:
        cov = np.exp(-2.0 * population.rate * lag)
    else:
        k, theta = gs
        cov = (1.0 + 2.0 * lag * theta) ** (-k)
    step2 = population.amplitude ** 2 + population.amplitude_spread ** 2
    return float(step2 / 4.0 * (w @ cov @ w))


def population_variances(scene, clip=None, others=0.0):
    """The white variance each pixel population adds to a slope image ((e/s)²).

    Parameters
    ----------
    scene : `~spherex_reduce.simulation.Scene`
        In electrons (`~spherex_reduce.simulation.Scene.in_electrons`), slopes mode.
    clip : float, optional
        The pipeline's ``sigma_clip`` upper threshold (standard deviations); None: no
        clip.
    others : float
        The pixel variance of everything else ((e/s)²): the clip's standard deviation.

    Returns
    -------
    variances : dict
        ``{"dark_spread", "hot_pixels", "telegraph"}``: the variance of each population
        the scene has (see the module).
    unmasked : float
        The fraction of the pixels the clip keeps (1 without a clip).

    Warns
    -----
    AstropyUserWarning
        Telegraph reference pixels, left out.

    Examples
    --------
    >>> from spherex_reduce.simulation import load_scene
    >>> from spherex_reduce.analysis.forecast.populations import population_variances
    >>> sc = load_scene({"geometry": {"nrows": 16, "ncols": 16, "nchannels": 1},
    ...                  "readout": {"nframes": 8, "phantom_reads": 0},
    ...                  "scene": {"dark_current": 1.0, "dark_current_spread": 0.3,
    ...                            "poisson": False}})
    >>> population_variances(sc)
    ({'dark_spread': 0.09}, 1.0)
    """
    t = scene.terms
    s = scene.schedule
    out = {}
    if t.dark_current_spread > 0:
        out["dark_spread"] = float(t.dark_current_spread) ** 2
    core = others + out.get("dark_spread", 0.0)  # the Gaussian part of every pixel
    offsets = {}  # population -> (weights, offsets): each pixel's slope less its core
    telegraphs, reference = [], False
    for i, r in enumerate(t.telegraphs):
        if not r.on:
            continue
        if r.pixels in ("active", "all"):
            telegraphs.append((i, r))
        reference |= r.pixels in ("reference", "all")
    if telegraphs:
        if clip is None:
            out["telegraph"] = sum(r.fraction * _telegraph_variance(s, r) for _, r in telegraphs)
        else:
            y = [_telegraph_slopes(s, r, TELEGRAPH_CHAINS, i) for i, r in telegraphs]
            offsets["telegraph"] = (np.concatenate([np.full(v.size, r.fraction / v.size)
                                                    for (_, r), v in zip(telegraphs, y,
                                                                         strict=True)]),
                                    np.concatenate(y))
    hot = t.hot_pixel_fraction > 0 and t.hot_pixel_current > 0
    if hot:
        p = float(t.hot_pixel_fraction)
        x = _hot_excess(t.hot_pixel_current, t.hot_pixel_current_spread)
        shot = shot_factor(s) if t.poisson else 0.0
        if clip is None:
            m1, m2 = float(t.hot_pixel_current), float(t.hot_pixel_current ** 2
                                                       + t.hot_pixel_current_spread ** 2)
            out["hot_pixels"] = p * m2 - (p * m1) ** 2 + p * m1 * shot
        else:
            offsets["hot_pixels"] = (np.full(x.size, p / x.size), x)
    unmasked = 1.0
    if offsets:  # the clip keeps the pixels within its threshold: the mixture's fixed point
        kept, unmasked = _clipped(offsets, core, clip, shot if hot else 0.0)
        out.update(kept)
    if reference:
        warnings.warn("forecast: the telegraph noise of reference pixels (scene.rtn with "
                      "pixels: reference or all) is left out: it reaches the image through "
                      "the reference average only, at 1 / (reference pixels averaged) of "
                      "a telegraph pixel's own", AstropyUserWarning, stacklevel=3)
    return out, unmasked


def _clipped(offsets, core, clip, shot):
    """Each population's share of the variance of the pixels a clip keeps ((e/s)²).

    The pixels are a mixture: the core alone (Gaussian of variance ``core``) and each
    population's pixels, the core plus an offset (``offsets``: name -> (weights,
    offsets)).  The clip keeps a pixel of offset ``y`` with the chance ``Φ((c - y) / s) -
    Φ((-c - y) / s)`` (``s² = core``, ``c`` the threshold times the standard deviation of
    the kept pixels, the mixture's fixed point: `clipped_sigma`); what the populations add
    to the kept pixels' variance, beyond the core's own, is split between them as their
    kept offsets' second moments; hot pixels add their kept ones' shot noise
    (``shot`` per unit current, e/s)."""
    weights = np.concatenate([[1.0 - sum(float(w.sum()) for w, _ in offsets.values())],
                              *(w for w, _ in offsets.values())])
    means = np.concatenate([[0.0], *(y for _, y in offsets.values())])
    sigma = clipped_sigma(weights, means, core, clip)
    excess = max(sigma ** 2 - clipped_sigma([1.0], [0.0], core, clip) ** 2, 0.0)
    c, sd = clip * sigma, np.sqrt(core)
    frac = float(np.sum(weights * (ndtr((c - means) / sd) - ndtr((-c - means) / sd))))
    unmasked = frac / float(ndtr(c / sd) - ndtr(-c / sd))  # (the core's own clip: none)
    moments, out = {}, {}
    for name, (w, y) in offsets.items():
        kept = w * (ndtr((c - y) / sd) - ndtr((-c - y) / sd))
        moments[name] = float(np.sum(kept * y * y))
        out[name] = float(np.sum(kept * y)) / frac * shot if name == "hot_pixels" else 0.0
    total = sum(moments.values())
    for name, m in moments.items():
        out[name] += excess * m / total if total > 0 else 0.0
    return out, min(unmasked, 1.0)
