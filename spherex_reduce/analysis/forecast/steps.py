"""Which reductions the noise forecast propagates, and what a pipeline does to the noise.

`FORECAST_STEPS` is the one declaration of the steps (and parameter values)
`~spherex_reduce.analysis.forecast` knows to be linear; `reduction` reads a
pipeline into a `Reduction`, the few facts the forecast's engine
(`spherex_reduce.analysis.forecast.rows`) needs: whether each read's phantom
value is subtracted, which reference correction follows and whether the
reference pixels it averages had their phantom values subtracted first.

Un-chopping is a permutation (the forecast is of the image in physical row
order), least-squares slopes with uniform weights commute with every
frame-wise linear correction (a slope of ``x - c`` is the slope of ``x``
minus that of ``c``), so the order of ``fit_ramp`` among the other steps does
not matter; the order of phantom subtraction and reference correction does.
A pair difference ``(a - b) / sqrt(2)`` of two exposures taken and reduced the
same way has, for noise independent between the two exposures, the expected
spectrum of one exposure (``(E|A|² + E|B|²) / 2``; the dark current and any
fixed pattern cancel, the Poisson noise of both adds up to one's): it is
forecast as the identity.
σ-clipping (the clipped mean of the reference pixels, the ``sigma_clip``
step's hot pixels) is forecast as no clipping: on Gaussian noise it changes
the spectrum by less than the Monte Carlo resolves (measured at 3 σ for the
reference pixels and 5 σ for the slopes: see docs/forecast.rst), so a clip
below 3 σ is refused, as are ``fit_ramp``'s ``saturation`` (it drops reads:
not linear), a pair difference whose other exposure is not reduced the same
way (``reduce_other: false``) and a second reference correction.
"""

from dataclasses import dataclass, field

from ...core.errors import ConfigError
from ...reduce.pipeline import as_pipeline

__all__ = ["FORECAST_STEPS", "MEASURED_SIGMA", "AtLeast", "Reduction", "linear_steps", "reduction"]


@dataclass(frozen=True)
class AtLeast:
    """The values a clipping threshold may take: a number from ``minimum`` up, or None (a
    threshold that defaults to the step's ``sigma``).

    Examples
    --------
    >>> from spherex_reduce.analysis.forecast.steps import MEASURED_SIGMA
    >>> 5.0 in MEASURED_SIGMA, 2.5 in MEASURED_SIGMA, MEASURED_SIGMA
    (True, False, a number >= 3)
    """

    minimum: float

    def __contains__(self, value):
        number = isinstance(value, (int, float)) and not isinstance(value, bool)
        return value is None or (number and value >= self.minimum)

    def __repr__(self):
        return f"a number >= {self.minimum:g}"


#: The clipping thresholds (σ) the forecast may neglect: its effect was measured there.
MEASURED_SIGMA = AtLeast(3.0)

#: Steps the forecast propagates: for each, the parameters whose value it must check, with
#: the values it propagates (every step's default is one of them; a parameter not given
#: takes it).  ``sigma_clip`` and the clipping of ``correct_reference`` (``sigma``,
#: ``maxiters``) are forecast as no clipping, so only from `MEASURED_SIGMA` up.
FORECAST_STEPS = {
    "unchop": {},
    "subtract_phantom": {},
    "correct_reference": {"strategy": ("mean", "acn", "wiener"), "sigma": MEASURED_SIGMA},
    "fit_ramp": {"weighting": ("uniform",), "saturation": (None,)},
    "sigma_clip": {"sigma": MEASURED_SIGMA, "sigma_lower": MEASURED_SIGMA,
                   "sigma_upper": MEASURED_SIGMA},
    "pair_difference": {"reduce_other": (True,)},
}


@dataclass(frozen=True)
class Reduction:
    """What a linear pipeline does to the noise of a slope image.

    Attributes
    ----------
    steps : tuple of str
        The pipeline's step names, in order.
    phantom : bool
        Every read has its phantom value (the mean of its ``c`` phantom samples)
        subtracted.
    reference : str or None
        The reference correction (``'mean'``: one mean of the reference pixels
        per channel; ``'acn'``: one per channel and column-offset parity;
        ``'wiener'``: a drift estimate at every read), or None.
    reference_phantom : bool
        The reference pixels had their phantom values subtracted before they
        were averaged (``subtract_phantom`` ran first).
    side_columns : bool
        The reference offsets also average the side reference columns of the
        active rows.
    reference_params : dict
        The reference step's parameters (the ``wiener`` strategy's weights
        depend on them).
    reference_ramps : bool
        The reference step works on ramps (``fit_ramp`` comes after it).
    """

    steps: tuple = ()
    phantom: bool = False
    reference: str | None = None
    reference_phantom: bool = False
    side_columns: bool = False
    reference_params: dict = field(default_factory=dict)
    reference_ramps: bool = True

    def describe(self):
        """The pipeline's steps as ``'a > b'`` (``'none'`` without steps)."""
        return " > ".join(self.steps) if self.steps else "none"


def reduction(pipeline):
    """The `Reduction` of a pipeline, refusing in one line a step the forecast does not know.

    Parameters
    ----------
    pipeline : `~spherex_reduce.Pipeline`, shipped name, path, dict or None

    Returns
    -------
    `Reduction`

    Raises
    ------
    ConfigError
        A step not in `FORECAST_STEPS`, or one with a parameter value the
        forecast does not propagate (the message names the step and value).

    Examples
    --------
    >>> from spherex_reduce.analysis.forecast.steps import reduction
    >>> r = reduction("spherex-default")
    >>> r.phantom, r.reference, r.reference_phantom
    (True, 'mean', True)
    """
    if pipeline is None:
        return Reduction()
    p = as_pipeline(pipeline)
    names, phantom, fitted, ref = [], False, False, {}
    for i, item in enumerate(p.config["steps"]):
        (name, params), = item.items()
        if name not in FORECAST_STEPS:
            raise ConfigError(f"forecast: steps[{i}].{name} ({p.source}) is not forecast so "
                              f"far; forecast steps: {', '.join(FORECAST_STEPS)}")
        for key, allowed in FORECAST_STEPS[name].items():
            if key in params and params[key] not in allowed:
                only = repr(allowed) if isinstance(allowed, AtLeast) else ", ".join(
                    map(repr, allowed))
                raise ConfigError(f"forecast: steps[{i}].{name}.{key}: {params[key]!r} is "
                                  f"not forecast (not linear, or not yet); only {only}")
        if name == "correct_reference" and ref:
            raise ConfigError(f"forecast: steps[{i}].correct_reference: a second reference "
                              "correction is not forecast; only one")
        if name == "subtract_phantom" and not ref.get("consumed"):
            phantom = True  # (skipped when a wiener estimate consumed the phantom values)
        elif name == "fit_ramp":
            fitted = True
        elif name == "correct_reference":
            strategy = params.get("strategy", "mean")
            rest = {k: v for k, v in params.items() if k != "strategy"}
            ref = {"reference": strategy, "reference_phantom": phantom,
                   "side_columns": bool(params.get("side_columns", False)),
                   "reference_params": rest, "reference_ramps": not fitted,
                   "consumed": strategy == "wiener" and not phantom
                   and params.get("phantom", "auto") == "auto"}
        names.append(name)
    ref.pop("consumed", None)
    return Reduction(tuple(names), phantom, **ref)


def linear_steps(pipeline):
    """The names of a pipeline's steps, refused in one line if the forecast does not know one.

    Parameters
    ----------
    pipeline : `~spherex_reduce.Pipeline`, shipped name, path, dict or None

    Returns
    -------
    list of str

    Raises
    ------
    ConfigError
        As `reduction`.

    Examples
    --------
    >>> from spherex_reduce.analysis.forecast.steps import linear_steps
    >>> linear_steps({"steps": [{"unchop": {}}, {"fit_ramp": {}}]})
    ['unchop', 'fit_ramp']
    """
    return list(reduction(pipeline).steps)
