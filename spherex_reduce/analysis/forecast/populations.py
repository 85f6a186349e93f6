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
  gamma-distributed about ``hot_pixel_current``): ``p E[x²] - (p E[x])²`` (a fixed
  pattern) and their Poisson noise, ``p E[x]`` times the slope's Poisson factor;
- **telegraph pixels** of ``rtn`` populations on the active pixels (``pixels: active`` or
  ``all``; a fraction ``f``, steps ``A`` and rates ``r`` per state, each
  gamma-distributed about its mean): a pixel switches, frame to frame, between two
  states with the autocovariance ``A²/4 exp(-2 r |j - k| T)`` at reads ``j`` and ``k``
  (``T`` the frame time; the simulator's chain,
  `~spherex_reduce.simulation.telegraph`), so its least-squares slope (weights ``w``)
  has the variance ``E[A²]/4 Σ_jk w_j w_k E[exp(-2 r |j - k| T)]``, the rates' average
  that of a gamma: ``(1 + 2 |j - k| T θ)^(-κ)`` (shape ``κ``, scale ``θ``); times ``f``.

A **pair difference** (a step whose noise effect ``cancels_fixed``: two exposures of one
detector) cancels the fixed patterns: the dark-current spread and the hot pixels'
excess go, their Poisson noise stays, and a telegraph pixel's two exposures switch
independently (the same variance; ``(y₁ - y₂)/√2`` for the clip below).

A **clip of the slope image** (a step whose noise effect ``clips_slopes``: the
``sigma_clip`` step, as `astropy.stats.sigma_clip` with the median as centre and the
standard deviation as spread) masks, in the measurement, the pixels whose slope left its
thresholds.  The pixels are a mixture: a Gaussian part (variance ``V``, every other term)
and each population's pixels, that part plus an offset (the hot pixels' excess on
`HOT_QUANTILES` quantiles of its gamma, `TELEGRAPH_CHAINS` telegraph slopes drawn from
the chain with a fixed seed).  The clip's thresholds (``sigma_lower`` and
``sigma_upper`` times the standard deviation of the pixels it keeps) are followed pass
by pass to the fixed point (or ``maxiters`` passes), a pixel of offset ``y`` and variance
``V`` kept with the chance ``Φ((hi - y) / √V) - Φ((lo - y) / √V)`` (each kind of pixel its
own ``V``: a hot pixel's holds its Poisson noise; the dark-current spread is offsets on
its gamma's quantiles, its tail masked too); what the populations add to the kept
pixels' variance, beyond the Gaussian part's own, is split between them exactly as
their kept second moments with the kept mean taken out.  It is the large-image limit:
on a small image the clip's standard deviation follows that image's own outliers (16 ×
16 pixels, one pass: 1570 forecast against 2050-2160 measured; numpy draws of the same
mixture give 1620 at 25 600 pixels and 1575 at 409 600).  The kept ones are weighed as the
unmasked pixels they are (the measured spectrum is divided by the unmasked fraction
``u``); the mask itself moves power between scales: on a field of spectrum ``P`` and
pixel variance ``V`` a mask of pixels chosen independently of it measures ``u P(k) + (1
- u) V`` (the forecast's ``power_masked`` column, ``(1 - u) (V - P)``).  Refused in one
line: a clip with another centre or spread (``cenfunc``, ``stdfunc``), two clips, a
clip before a pair difference, populations whose fractions add up to more than 1.

**Telegraph reference pixels** (``pixels: reference`` or ``all``) are left out, with a
warning where a reference correction averages them: their steps reach the image only
through that average, each at one over the number of reference pixels averaged.
"""

import warnings

import numpy as np
from astropy.utils.exceptions import AstropyUserWarning
from scipy.special import gammaincinv, ndtr  # (scipy.stats would load scipy.optimize)

from ...core.errors import ConfigError
from ...core.limits import check_size
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
    if sigma is None:
        wt, mu = np.asarray(weights, np.float64), np.asarray(means, np.float64)
        return float(np.sqrt(np.sum(wt * (mu * mu + variance))))
    return _clip_passes(weights, means, variance, sigma, sigma, maxiter, tol)[0]


def _clip_passes(weights, means, variance, lower, upper, passes, tol=1e-10):
    """The clip of a Gaussian mixture (`clipped_sigma`) pass by pass, thresholds ``lower``
    and ``upper`` standard deviations below and above 0, at most ``passes`` passes (or
    until the standard deviation settles); ``variance`` one for all the Gaussians or one
    each.  Returns the standard deviation of the kept values, the last pass's thresholds
    ``(lo, hi)`` and, for each Gaussian at them, the chance it is kept and its kept first
    and second moments (``E[x; kept]``, ``E[x²; kept]``)."""
    wt = np.asarray(weights, dtype=np.float64)
    mu = np.asarray(means, dtype=np.float64)
    variance = np.asarray(variance, dtype=np.float64)
    s = np.sqrt(variance)
    std = np.sqrt(float(np.sum(wt * (mu * mu + variance))))
    lo = hi = kept = m1 = m2 = None
    for _ in range(passes):
        lo, hi = -lower * std, upper * std
        a, b = (lo - mu) / s, (hi - mu) / s
        pa, pb = np.exp(-a * a / 2), np.exp(-b * b / 2)
        pa, pb = pa / np.sqrt(2 * np.pi), pb / np.sqrt(2 * np.pi)
        kept = ndtr(b) - ndtr(a)
        m1 = mu * kept + s * (pa - pb)
        m2 = (mu * mu + variance) * kept + 2 * mu * s * (pa - pb) + variance * (a * pa - b * pb)
        frac = float(np.sum(wt * kept))
        mean = float(np.sum(wt * m1)) / frac
        new = np.sqrt(max(float(np.sum(wt * m2)) / frac - mean * mean, 0.0))
        if abs(new - std) <= tol * std:
            return float(new), (lo, hi), kept, m1, m2
        std = new
    return float(std), (lo, hi), kept, m1, m2


def clipped_populations(terms):
    """Whether a clip of the slope image acts on these scene terms' populations (hot
    pixels, a dark-current spread, telegraph light-sensitive pixels)."""
    return bool((terms.hot_pixel_fraction > 0 and terms.hot_pixel_current > 0)
                or terms.dark_current_spread > 0
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


def _gamma_quantiles(mean, spread):
    """The gamma of that mean and spread on `HOT_QUANTILES` mid-quantiles (the mean alone
    without a spread)."""
    gs = _gamma_shape_scale(mean, spread)
    if gs is None:
        return np.array([float(mean)])
    return gammaincinv(gs[0], (np.arange(HOT_QUANTILES) + 0.5) / HOT_QUANTILES) * gs[1]


def _chain(schedule):
    """The least-squares weights of the frames and the telegraph chain's step, the frame
    time (s): what both of a telegraph pixel's slope functions need."""
    w, _, _ = slope_frames(schedule)
    return w, schedule.frame_samples / schedule.geometry.pixel_rate


def _telegraph_slopes(schedule, population, n, seed, differenced=False):
    """``n`` draws of a telegraph pixel's least-squares slope (e/s): the simulator's chain
    (a flip from one frame to the next with the chance ``(1 - exp(-2 r T)) / 2``, the
    first state either), its step and rate from their gammas, scaled so that their mean
    square is the exact variance (`_telegraph_variance`); ``differenced``: of two
    exposures' chains of the same pixel, ``(y₁ - y₂)/√2``."""
    w, frame = _chain(schedule)
    check_size(2.0 * n * w.size * 9, "forecast: the telegraph chains of a clip")
    rng = np.random.default_rng(seed)
    amp = _draw(rng, population.amplitude, population.amplitude_spread, n)
    flip = -np.expm1(-2.0 * _draw(rng, population.rate, population.rate_spread, n)
                     * frame) / 2.0

    def chain():
        flips = rng.random((n, w.size - 1)) < flip[:, None]
        start = rng.random((n, 1)) < 0.5
        return np.concatenate([start, start ^ np.logical_xor.accumulate(flips, axis=1)],
                              axis=1) @ w

    y = amp * ((chain() - chain()) / np.sqrt(2.0) if differenced else chain())
    ms = float(np.mean(y * y))
    return y * np.sqrt(_telegraph_variance(schedule, population) / ms) if ms > 0 else y


def _draw(rng, mean, spread, n):
    """``n`` values of the gamma of that mean and spread (``mean`` without a spread)."""
    gs = _gamma_shape_scale(mean, spread)
    return np.full(n, float(mean)) if gs is None else rng.gamma(gs[0], gs[1], n)


def _telegraph_variance(schedule, population):
    """The variance of a telegraph pixel's least-squares slope ((e/s)²)."""
    w, frame = _chain(schedule)
    n = w.size
    lag = np.abs(np.subtract.outer(np.arange(n), np.arange(n))) * frame
    gs = _gamma_shape_scale(population.rate, population.rate_spread)
    if gs is None:
        cov = np.exp(-2.0 * population.rate * lag)
    else:
        k, theta = gs
        cov = (1.0 + 2.0 * lag * theta) ** (-k)
    step2 = population.amplitude ** 2 + population.amplitude_spread ** 2
    return float(step2 / 4.0 * (w @ cov @ w))


def population_variances(scene, reduction=None, others=0.0):
    """The white variance each pixel population adds to a reduced slope image ((e/s)²).

    Parameters
    ----------
    scene : `~spherex_reduce.simulation.Scene`
        In electrons (`~spherex_reduce.simulation.Scene.in_electrons`), slopes mode.
    reduction : `~spherex_reduce.analysis.forecast.steps.Reduction`, optional
        The pipeline: its clip of the slope image, its pair difference and its reference
        correction (None: none of them).
    others : float
        The pixel variance of every other term ((e/s)²): the clip's Gaussian part.

    Returns
    -------
    variances : dict
        ``{"dark_spread", "hot_pixels", "telegraph"}``: the variance of each population
        the scene has (see the module).
    unmasked : float
        The fraction of the pixels the clip keeps (1 without a clip).

    Raises
    ------
    ConfigError
        A clip of the populations the forecast cannot follow (see the module).

    Warns
    -----
    AstropyUserWarning
        Telegraph reference pixels under a reference correction: left out.

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
    differenced = reduction is not None and reduction.differenced
    clip = None if reduction is None else reduction.clip
    if clip is not None and clipped_populations(t):
        _check_clip(clip, reduction, t)
    else:
        clip = None
    shot = shot_factor(s) if t.poisson else 0.0
    telegraphs = [(i, r) for i, r in enumerate(t.telegraphs)
                  if r.on and r.pixels in ("active", "all")]
    hot = t.hot_pixel_fraction > 0 and t.hot_pixel_current > 0
    spread = 0.0 if differenced else float(t.dark_current_spread)  # (a fixed pattern)
    if clip is not None:
        out, unmasked = _clipped(s, t, telegraphs, spread, differenced, others, clip, shot)
    else:
        out, unmasked = {}, 1.0
        if spread:
            out["dark_spread"] = spread ** 2
        if telegraphs:
            out["telegraph"] = sum(r.fraction * _telegraph_variance(s, r) for _, r in telegraphs)
        if hot:
            p, m1 = float(t.hot_pixel_fraction), float(t.hot_pixel_current)
            m2 = 0.0 if differenced else m1 * m1 + float(t.hot_pixel_current_spread) ** 2
            fixed = 0.0 if differenced else (p * m1) ** 2  # (the excess cancels in a pair)
            out["hot_pixels"] = p * m2 - fixed + p * m1 * shot
    if (reduction is not None and reduction.reference is not None
            and any(r.on and r.pixels in ("reference", "all") for r in t.telegraphs)):
        warnings.warn("forecast: the telegraph noise of reference pixels (scene.rtn with "
                      "pixels: reference or all) is left out: it reaches the image through "
                      "the reference average only, at 1 / (reference pixels averaged) of "
                      "a telegraph pixel's own", AstropyUserWarning, stacklevel=3)
    return out, unmasked


def _check_clip(clip, reduction, terms):
    """Refuse, in one line, a clip of the populations the forecast cannot follow."""
    what = "forecast: scene populations (hot or telegraph pixels) under sigma_clip"
    if clip.get("cenfunc", "median") != "median" or clip.get("stdfunc", "std") != "std":
        raise ConfigError(f"{what} with cenfunc {clip.get('cenfunc')!r} and stdfunc "
                          f"{clip.get('stdfunc')!r} are not forecast; only median and std")
    if not isinstance(clip.get("sigma"), (int, float)):
        raise ConfigError(f"{what}: the clip's step has no sigma (its NoiseEffect declares "
                          "clips_slopes: sigma, sigma_lower, sigma_upper and maxiters as "
                          "astropy.stats.sigma_clip takes them)")
    if reduction.clips > 1:
        raise ConfigError(f"{what}: {reduction.clips} clips of the slope image are not "
                          "forecast; only one")
    if reduction.clip_before_difference:
        raise ConfigError(f"{what} before pair_difference are not forecast; clip after it")
    total = terms.hot_pixel_fraction + sum(r.fraction for r in terms.telegraphs
                                           if r.on and r.pixels in ("active", "all"))
    if total > 1:
        raise ConfigError(f"{what}: their fractions add up to {total:g} > 1 (the forecast "
                          "takes them as distinct pixels)")


def _clipped(s, t, telegraphs, spread, differenced, others, clip, shot):
    """Each population's share of the variance of the pixels a clip keeps ((e/s)²), and
    the fraction of the pixels it keeps.

    The pixels are a mixture of Gaussians, each a kind of pixel with its offset and its
    variance: the pixels of no population (their dark current's offset on `HOT_QUANTILES`
    quantiles of its gamma, variance ``others``), hot pixels (their excess on quantiles,
    ``others`` + the dark spread's + their own Poisson noise; in a pair difference no
    excess), telegraph pixels (`TELEGRAPH_CHAINS` slopes from the chain, ``others`` + the
    dark spread's).  The clip (``clip``: the step's parameters) is followed pass by pass
    (`_clip_passes`); what the populations add to the kept pixels' variance, beyond
    ``others`` clipped alone, is split between them exactly: each kind's kept second
    moment less ``others`` times its kept share, less its kept mean times the kept mean.
    """
    sigma = float(clip["sigma"])
    lower = float(clip.get("sigma_lower") or sigma)
    upper = float(clip.get("sigma_upper") or sigma)
    passes = int(clip.get("maxiters") or 200)  # (null: until it settles)
    kinds = []  # (name, weights, offsets, variances)
    p = float(t.hot_pixel_fraction) if t.hot_pixel_fraction > 0 and t.hot_pixel_current > 0 \
        else 0.0
    tel = sum(r.fraction for _, r in telegraphs)
    if spread:
        dark = _gamma_quantiles(float(t.dark_current), spread) - float(t.dark_current)
        kinds.append(("dark_spread", np.full(dark.size, (1.0 - p - tel) / dark.size), dark,
                      np.full(dark.size, others)))
    else:
        kinds.append(("", np.array([1.0 - p - tel]), np.zeros(1), np.full(1, others)))
    if p:
        x = _gamma_quantiles(t.hot_pixel_current, t.hot_pixel_current_spread)
        kinds.append(("hot_pixels", np.full(x.size, p / x.size),
                      np.zeros(x.size) if differenced else x,
                      others + spread ** 2 + x * shot))
    if telegraphs:
        y = [_telegraph_slopes(s, r, TELEGRAPH_CHAINS, i, differenced) for i, r in telegraphs]
        kinds.append(("telegraph", np.concatenate([np.full(v.size, r.fraction / v.size)
                                                   for (_, r), v in zip(telegraphs, y,
                                                                        strict=True)]),
                      np.concatenate(y), np.full(sum(v.size for v in y), others + spread ** 2)))
    weights, means, variances = (np.concatenate([k[i] for k in kinds]) for i in (1, 2, 3))
    _, _, kept, m1, m2 = _clip_passes(weights, means, variances, lower, upper, passes)
    own, (olo, ohi), _, _, _ = _clip_passes([1.0], [0.0], others, lower, upper, passes)
    frac = float(np.sum(weights * kept))
    mean = float(np.sum(weights * m1)) / frac
    out, at = {}, 0
    for name, w, _, _ in kinds:
        part = slice(at, at + w.size)
        at += w.size
        if name:
            wk = weights[part] / frac
            out[name] = (float(np.sum(wk * (m2[part] - own ** 2 * kept[part])))
                         - float(np.sum(wk * m1[part])) * mean)
    sd = np.sqrt(others)
    unmasked = frac / float(ndtr(ohi / sd) - ndtr(olo / sd))  # (others' own clip: none)
    return out, min(unmasked, 1.0)
