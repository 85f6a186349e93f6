"""From the fits of each dark (or segment) to the components of a scene, with uncertainties.

Every number of the model is fitted to the spectra of all darks (or segments
of darks) pooled (`~spherex_reduce.analysis.characterize.spectra.fit_spectra`),
and its uncertainty is the delete-one jackknife over the darks: the scatter
of the numbers fitted with each dark left out in turn, which holds whatever
the noise's spectrum, its non-Gaussian scatter and the fit's weights.  The
components follow the simulator's (`~spherex_reduce.simulation.NoiseComponent`):
for each scope (``channel``, ``common``) a part seen by the light-sensitive
pixels only, one seen by the phantom reads only and one seen by both (the
paper's Table 2 split), with alternating column noise (ACN) when the darks show it.

Without phantom reads, ACN found is a component of its own, ``acn`` (channel scope,
``acn: true``): the even-odd difference holds ACN alone, so its correlated terms are
ACN's, and each channel's own part (``channel``, one stream for both parities: NGHXRG's
``u_pink``) is what the pixels' mean holds beyond the share of ACN it keeps.  With
phantom reads every channel component's correlated part is held as ACN.

With ACN an average of ``e`` even and ``o`` odd samples keeps ``(e² + o²)/n²``
of a component's correlated power (`Box.acn_factor`), and the cross-spectrum
of the pixels' and the phantom's averages keeps half of it; those factors
undo it.  White noise is independent from sample to sample, so whether it
is split by column parity, or seen by both, cannot be told: the white levels
sit in the pixels-only and phantom-only components.
"""

import dataclasses
import warnings

import numpy as np

from .spectra import NOT_REPORTED, band_power

__all__ = ["ACN_SIGMAS", "BAD_FIT_PROBABILITY", "Estimate", "combine", "goodness",
           "scene_values"]

PARAMS = ("alpha", "beta", "gamma")
#: ACN is found when the correlated power of the even-odd difference is above zero by more
#: than this many standard errors (one-sided; 0.13 % false alarms).  The error is the
#: jackknife's over the darks, floored at the fit's own (`_acn_test`).
ACN_SIGMAS = 3.0
#: A fit whose chi2 has a probability below this is visibly bad (see ``goodness``).
BAD_FIT_PROBABILITY = 1e-6
#: A channel-to-channel spread is reported as real when the channels' values scatter about
#: their mean with chi2 per degree of freedom beyond what this probability allows.
SPREAD_PROBABILITY = 1e-3


@dataclasses.dataclass
class Estimate:
    """One term's ``alpha, beta, gamma`` fitted to every dark, and their jackknife errors."""

    values: np.ndarray
    errors: np.ndarray
    #: the values fitted with each dark left out in turn, ``(darks, 3)``: the jackknife
    #: of any function of them (a band power) is theirs
    leave_one_out: np.ndarray = None

    @classmethod
    def of(cls, full, leave_one_out):
        """The value from all darks and the delete-one jackknife standard error,
        ``sqrt((K − 1)/K · Σ (θ₍ᵢ₎ − θ̄)²)`` over the ``K`` fits that leave out one dark.

        Examples
        --------
        The jackknife of a mean is the standard error of the mean:

        >>> import numpy as np
        >>> from spherex_reduce.analysis.characterize.model import Estimate
        >>> x = np.array([1.0, 2.0, 4.0, 7.0])
        >>> loo = [[np.delete(x, i).mean()] for i in range(4)]
        >>> e = Estimate.of([x.mean()], loo)
        >>> bool(np.isclose(e.errors[0], x.std(ddof=1) / 2))
        True
        """
        x = np.asarray(leave_one_out, dtype=np.float64)  # (darks, 3)
        k = x.shape[0]
        err = np.sqrt((k - 1) / k * np.sum((x - x.mean(axis=0)) ** 2, axis=0))
        return cls(np.asarray(full, dtype=np.float64), err, x)


def _theta(result):
    return np.array([result.values[p] for p in PARAMS])


def _fitted(result):
    """``alpha, beta, gamma`` of a fit, NaN for the terms it did not fit."""
    if result is None:
        return np.full(3, np.nan)
    return np.array([result.values[p] if p in result.fitted else np.nan for p in PARAMS])


def _acn_power(fits, exponent, band):
    acn = fits["acn"]
    return band_power(acn.values["beta"], acn.values["gamma"], exponent, band)


def _formal_band_error(fit, band):
    """The error of a fit's β, γ band power over ``band`` from the fit's covariance."""
    grad = {"alpha": 0.0, "beta": band_power(1.0, 0.0, fit.exponent, band),
            "gamma": band_power(0.0, 1.0, fit.exponent, band)}
    g = np.array([grad[p] for p in fit.fitted])
    return float(np.sqrt(max(g @ fit.covariance @ g, 0.0)))


def _acn_test(full, jack, exponent):
    """The ACN test: the correlated power (β, γ terms) of the even-odd difference in its
    fitted band, its error, and its z.

    The error is the jackknife's over the darks, but not below the fit's own (the
    scatter the Welch spectrum of Gaussian noise has): the difference's β and γ are
    nearly opposite in shape, and the jackknife of a few darks can miss their scatter
    (on 4 of NGHXRG's full-size darks without ACN it gave 6.5 times less than the fit,
    and ACN at 9.6 standard errors)."""
    if "acn" not in full:
        return None
    band = full["acn"].frequency_range
    power = _acn_power(full, exponent, band)
    err = float(Estimate.of([power], [[_acn_power(j, j["pixels"].exponent, band)]
                                      for j in jack]).errors[0])
    err = max(err, _formal_band_error(full["acn"], band))
    z = power / err if err > 0 else float(np.copysign(np.inf, power))
    return {"band": band, "power": float(power), "error": err, "z": float(z),
            "found": bool(z > ACN_SIGMAS)}


def _classes(g, acn, boxes, nch, reference=True):
    """The six components' ``alpha, beta, gamma`` of one dark's fits ``g`` (missing: None).

    The common white level is the reference-row bursts' cross-spectrum's where the darks
    have one (``reference_common``: read at the pixel rate, where white noise dominates),
    not the light-sensitive streams' (row means, where a strong common 1/f leaves it loose:
    on NGHXRG's ``c_pink`` darks ± 1.5e-4 about a white level of 5.4e-4); ``reference``
    False: the streams' (every fit of a jackknife takes it from one source)."""
    out = _split(g, acn, boxes, nch)
    ref = g.get("reference_common") if reference else None
    if ref is not None and nch > 1 and "common" in out:
        out["common"] = np.array([ref.values["alpha"], *out["common"][1:]])
    return out


def _split(g, acn, boxes, nch):
    """`_classes` from the light-sensitive and phantom streams alone."""
    zero = np.zeros(3)
    t = {k: _theta(v) for k, v in g.items() if k != "channels" and v is not None}
    common = t.get("pixels_common", zero) if nch > 1 else zero
    k_s = boxes["sum"].acn_factor if acn else 1.0
    corr = np.array([0.0, 1.0, 1.0])  # the correlated terms, which ACN splits
    out = {}
    chan_s = t["pixels"] - common
    if "phantom" not in t:
        if acn:  # the even-odd difference holds ACN alone: the rest of each channel is not
            out["channel"] = chan_s - k_s * t["acn"] * corr
            out["acn"] = t["acn"] * corr
        else:
            out["channel"] = chan_s
        out["common"] = common
        return out
    k_p = boxes["phantom"].acn_factor if acn else 1.0
    k_x = 0.5 if acn else 1.0
    common_p = t.get("phantom_common", zero) if nch > 1 else zero
    common_x = t.get("both_common", zero) if nch > 1 else zero
    chan_x = (t["both"] - common_x) / k_x
    if acn and "phantom_acn" in t:
        # each channel's own part of the phantom values fitted with each parity's own
        # average (`_parity_basis`): its correlated terms are a parity stream's
        chan_p, k_p = t["phantom_acn"], 1.0
    else:
        chan_p = t["phantom"] - common_p
    out["channel"] = np.where(corr > 0, chan_s / k_s - chan_x, chan_s)
    out["channel_both"] = chan_x * corr
    out["channel_phantom"] = np.where(corr > 0, chan_p / k_p - chan_x, chan_p)
    out["common"] = np.where(corr > 0, common - common_x, common)
    out["common_both"] = common_x * corr
    out["common_phantom"] = np.where(corr > 0, common_p - common_x, common_p)
    return out


#: scope and visibility of each component `combine` gives
LAYOUT = {"channel": ("channel", "pixels"), "acn": ("channel", "pixels"),
          "channel_both": ("channel", "both"),
          "channel_phantom": ("channel", "phantom"), "common": ("common", "pixels"),
          "common_both": ("common", "both"), "common_phantom": ("common", "phantom")}


#: the components of each visibility, channel scope and common scope: their sum, term by
#: term, is the spectrum that visibility's streams show (``channel + common``: each pixel's)
PAIRS = (("channel", "common"), ("channel_both", "common_both"),
         ("channel_phantom", "common_phantom"))


def scene_values(components, exponent, bands):
    """The coefficients a scene can hold (none below zero), keeping what the darks constrain.

    A fitted term below zero (within its error of zero, where a term is poorly constrained
    alone but well in a sum) cannot be simulated; set to 0 alone it would raise the sum it
    belongs to.  So, in turn:

    1. **Within a component**: a negative ``beta`` (1/f) or ``gamma`` (1/f^exponent)
       beside a positive other (nearly the same shape over the fitted frequencies) is 0
       and the other holds the component's band power over ``bands[name]``
       (`~spherex_reduce.analysis.characterize.spectra.band_power`), where that band
       power is not below zero.
    2. **Across scopes** (`PAIRS`), term by term: a negative term of one scope beside a
       positive same term of the other scope, of the same visibility, moves into it, which
       then holds their sum: ``channel.alpha + common.alpha`` (each pixel's white level)
       and every other sum the visibility's auto-spectrum fits are kept.
    3. Within a component again, as 1: where the band power is below zero both are 0.
    4. Whatever is still below zero is 0.

    Parameters
    ----------
    components : dict
        ``{name: alpha, beta, gamma}`` (unit²/Hz, unit², unit²·Hz^(exponent−1)), as fitted.
    exponent : float
        The exponent of the ``gamma`` terms.
    bands : dict
        ``{name: (fmin, fmax)}`` (Hz): the frequencies each component was fitted over; a
        component missing here has steps 1 and 3 left out.

    Returns
    -------
    values : dict
        ``{name: ndarray (3,)}``, the coefficients for the scene.
    notes : dict
        ``{(name, term): str}``: what was done with each term fitted below zero or
        holding another's, and its value in the scene.

    Examples
    --------
    >>> from spherex_reduce.analysis.characterize.model import scene_values
    >>> v, notes = scene_values({"channel": [5e-4, 0.0, 0.0], "common": [-1e-4, 0.0, 0.0]},
    ...                         1.3, {})
    >>> [float(x) for x in v["channel"]], [float(x) for x in v["common"]]
    ([0.0004, 0.0, 0.0], [0.0, 0.0, 0.0])
    >>> notes[("common", "alpha")]
    'moved into channel.alpha (channel.alpha + common.alpha = 0.0004 kept); 0 in the scene'
    """
    vals = {n: np.array(v, dtype=np.float64) for n, v in components.items()}
    said = {}

    def say(name, p, text):
        said.setdefault((name, p), []).append(text)

    def within(name, v, band, last):
        factor = {1: band_power(1.0, 0.0, exponent, band), 2: band_power(0.0, 1.0, exponent, band)}
        power = band_power(v[1], v[2], exponent, band)
        if power < 0 and not last:
            return
        neg, pos = (1, 2) if v[1] < 0 else (2, 1)
        new = max(power, 0.0) / factor[pos]
        say(name, PARAMS[neg], f"{name}'s band power over {band[0]:.3g}-{band[1]:.3g} Hz "
                               f"({power:.3g}) " + ("is below zero, so" if power < 0 else
                                                    "kept by") +
            f" {name}.{PARAMS[pos]}: {v[pos]:.3g} -> {new:.3g}")
        v[pos], v[neg] = new, 0.0

    def within_all(last):
        for name, v in vals.items():
            if name in bands and min(v[1], v[2]) < 0 < max(v[1], v[2]):
                within(name, v, bands[name], last)

    within_all(last=False)
    for pair in PAIRS:
        if not all(n in vals for n in pair):
            continue
        for i, p in enumerate(PARAMS):
            a, b = (vals[n][i] for n in pair)
            if min(a, b) >= 0 or max(a, b) <= 0:
                continue
            neg, pos = pair if a < 0 else pair[::-1]
            vals[neg][i], vals[pos][i] = 0.0, a + b
            say(neg, p, f"moved into {pos}.{p} ({pair[0]}.{p} + {pair[1]}.{p} = {a + b:.3g} "
                        "kept)")
            if a + b < 0:
                say(pos, p, f"holds {pair[0]}.{p} + {pair[1]}.{p} = {a + b:.3g}, below zero")
    within_all(last=True)
    for name, v in vals.items():
        for i, p in enumerate(PARAMS):
            if v[i] < 0:
                v[i] = 0.0
                said.setdefault((name, p), [])
    notes = {(n, p): "; ".join([*texts, f"{vals[n][PARAMS.index(p)]:.3g} in the scene"])
             for (n, p), texts in said.items()}
    return vals, notes


def _spread(full, jack, view):
    """Per channel: the values and their jackknife errors, the channels' standard
    deviation, and whether it exceeds what the errors explain (chi2 of the channels
    about their mean)."""
    from scipy.stats import chi2

    with warnings.catch_warnings():  # a term no channel fitted is NaN: no warning for it
        warnings.simplefilter("ignore", RuntimeWarning)
        mean = np.array([_fitted(r) for r in full["channels"][view]])  # ch, 3
        per = np.array([[_fitted(r) for r in j["channels"][view]] for j in jack])  # K, ch, 3
        k, nch = per.shape[:2]
        err = np.sqrt((k - 1) / k * np.sum((per - per.mean(axis=0)) ** 2, axis=0))
        spread = np.nanstd(mean, axis=0, ddof=1) if nch > 1 else np.zeros(3)
        c2 = np.nansum(((mean - np.nanmean(mean, axis=0)) / err) ** 2, axis=0)
        dof = np.sum(np.isfinite(mean), axis=0) - 1
        real = (dof > 0) & (chi2.sf(c2, np.maximum(dof, 1)) < SPREAD_PROBABILITY)
    return {"channels": mean, "errors": err, "spread": spread, "real": real}


def combine(full, jack, boxes, nch):
    """The model's numbers: fitted to every dark, with jackknife errors.

    Parameters
    ----------
    full : dict
        `~spherex_reduce.analysis.characterize.spectra.fit_spectra` of the spectra of
        every dark pooled.
    jack : list of dict
        The same of the spectra pooled without each dark in turn (at least 2).
    boxes : dict
        The streams' averages (`~spherex_reduce.analysis.characterize.streams.Box`).
    nch : int
        Channels.

    Returns
    -------
    dict
        ``components`` ``{name: Estimate}``, ``spectra`` ``{name: Estimate}`` (the
        fit of each spectrum), ``acn`` (the test, or None where it cannot be made),
        ``acn_on``, ``spreads`` ``{view: ...}`` (`_spread`), ``exponent`` (an
        `Estimate` of one value).
    """
    exponent = full["pixels"].exponent
    acn = _acn_test(full, jack, exponent)
    found = bool(acn and acn["found"])
    reference = "reference_common" in full  # (then every dark had it, and every pool)
    whole = _classes(full, found, boxes, nch, reference)
    parts = [_classes(j, found, boxes, nch, reference) for j in jack]
    components = {n: Estimate.of(whole[n], [p[n] for p in parts]) for n in whole}
    names = [k for k in full if k not in NOT_REPORTED and full[k] is not None]
    spectra = {k: Estimate.of(_theta(full[k]), [_theta(j[k]) for j in jack]) for k in names}
    spreads = {view: _spread(full, jack, view) for view in full["channels"]}
    return {"components": components, "spectra": spectra, "acn": acn, "spreads": spreads,
            "acn_on": found,
            "exponent": Estimate.of([exponent], [[j["pixels"].exponent] for j in jack])}


def _common_mode(rho, nch):
    """``(κ_mean, κ_pairs)``: the variance of the channels' mean auto-spectrum and of their
    mean cross-spectrum, relative to that of independent channels, when each pair of the
    ``C`` channels is correlated by ``ρ`` (the common part's share of a channel's power).

    For Gaussian streams ``Cov(X_ij, X_kl) ∝ (S_ik S_lj + S_il S_kj)/2``: the mean of the
    ``C`` auto-spectra has ``κ = 1 + (C − 1) ρ²``, and the mean over the ``C(C − 1)``
    pairs ``κ = T / (C (C − 1)²)``, ``T = A² − 2 Σ r_i² + tr a²`` for ``a = ρ J + (1 − ρ) I``
    (``A`` its sum, ``r_i`` its row sums): ``C`` at ``ρ = 1``, ``1/(C − 1)`` at ``ρ = 0``.

    Examples
    --------
    >>> from spherex_reduce.analysis.characterize.model import _common_mode
    >>> [float(k) for k in _common_mode(1.0, 4)], [float(k) for k in _common_mode(0.0, 4)]
    ([4.0, 4.0], [1.0, 0.3333333333333333])
    """
    rho = np.clip(np.asarray(rho, dtype=np.float64), 0.0, 1.0)
    c = nch
    k_mean = 1 + (c - 1) * rho**2
    row = 1 + (c - 1) * rho  # every row sum of a
    t = (c * row) ** 2 - 2 * c * row**2 + c * (1 + (c - 1) * rho**2)
    return k_mean, t / (c * (c - 1) ** 2)


def goodness(bins, nch):
    """χ², degrees of freedom and probability of each pooled spectrum's fit.

    Every fit weights its bins as if the ``C`` channels were independent; noise common to
    them (NGHXRG's ``c_pink``) makes their spectra move together, so the errors of the
    channels' mean auto-spectrum (``pixels``) and mean cross-spectrum (``pixels_common``)
    are scaled by ``_common_mode`` at the share the fits give the common part; other
    spectra are taken as weighted.

    Parameters
    ----------
    bins : dict
        ``{name: Table}`` of binned spectra and models (``psd``, ``psd_err``,
        ``model``), as ``Characterization.bins`` holds them.
    nch : int
        Channels.

    Returns
    -------
    dict
        ``{name: (chi2, dof, probability)}``.

    Examples
    --------
    >>> import numpy as np
    >>> from astropy.table import Table
    >>> from spherex_reduce.analysis.characterize.model import goodness
    >>> b = Table({"psd": [1.0, 2.0, 1.0, 2.0, 1.0], "psd_err": [1.0] * 5, "model": [1.5] * 5})
    >>> chi2, dof, p = goodness({"x": b}, 4)["x"]
    >>> chi2, dof
    (1.25, 2)
    """
    from scipy.stats import chi2 as chi2_dist

    kappa = {}
    pix, common = bins.get("pixels"), bins.get("pixels_common")
    if nch > 1 and pix is not None and common is not None and len(pix) == len(common):
        rho = np.asarray(common["model"]) / np.maximum(np.asarray(pix["model"]), 1e-300)
        kappa["pixels"], kappa["pixels_common"] = _common_mode(rho, nch)
    ref, ref_common = bins.get("reference"), bins.get("reference_common")
    if nch > 1 and ref is not None and ref_common is not None and len(ref) == len(ref_common):
        rho = np.asarray(ref_common["model"]) / np.maximum(np.asarray(ref["model"]), 1e-300)
        kappa["reference_common"] = _common_mode(rho, nch)[1]
    out = {}
    for name, b in bins.items():
        r2 = ((np.asarray(b["psd"]) - np.asarray(b["model"])) / np.asarray(b["psd_err"])) ** 2
        c2 = float(np.sum(r2 / kappa.get(name, 1.0)))
        dof = max(int(r2.size) - len(PARAMS), 1)
        out[name] = (c2, dof, float(chi2_dist.sf(c2, dof)))
    return out
