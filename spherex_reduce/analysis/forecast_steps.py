"""Which reductions the noise forecast propagates, and what a pipeline does to the noise.

`FORECAST_STEPS` is the one declaration of the steps (and parameter values)
`~spherex_reduce.analysis.forecast` knows to be linear; `reduction` reads a
pipeline into a `Reduction`, the few facts the forecast's engine
(`spherex_reduce.analysis.forecast_rows`) needs: whether each read's phantom
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
the spectrum by less than the Monte Carlo resolves (measured: see
docs/forecast.rst).
"""

from dataclasses import dataclass

from ..core.errors import ConfigError
from ..reduce.pipeline import as_pipeline

__all__ = ["FORECAST_STEPS", "Reduction", "linear_steps", "reduction"]

#: Steps the forecast propagates: for each, the parameters whose value it must check, with
#: the values it propagates (the first one is the step's default).  ``sigma_clip`` and the
#: clipping of ``correct_reference`` (``sigma``, ``maxiters``) are forecast as no clipping.
FORECAST_STEPS = {
    "unchop": {},
    "subtract_phantom": {},
    "correct_reference": {"strategy": ("mean", "acn")},
    "fit_ramp": {"weighting": ("uniform",)},
    "sigma_clip": {},
    "pair_difference": {},
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
        per channel; ``'acn'``: one per channel and column-offset parity), or
        None.
    reference_phantom : bool
        The reference pixels had their phantom values subtracted before they
        were averaged (``subtract_phantom`` ran first).
    side_columns : bool
        The reference offsets also average the side reference columns of the
        active rows.
    """

    steps: tuple = ()
    phantom: bool = False
    reference: str | None = None
    reference_phantom: bool = False
    side_columns: bool = False

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
    >>> from spherex_reduce.analysis.forecast_steps import reduction
    >>> r = reduction("spherex-default")
    >>> r.phantom, r.reference, r.reference_phantom
    (True, 'mean', True)
    """
    if pipeline is None:
        return Reduction()
    p = as_pipeline(pipeline)
    names, phantom, reference, reference_phantom, side = [], False, None, False, False
    for i, item in enumerate(p.config["steps"]):
        (name, params), = item.items()
        if name not in FORECAST_STEPS:
            raise ConfigError(f"forecast: steps[{i}].{name} ({p.source}) is not forecast so "
                              f"far; forecast steps: {', '.join(FORECAST_STEPS)}")
        for key, allowed in FORECAST_STEPS[name].items():
            value = params.get(key, allowed[0])
            if value not in allowed:
                raise ConfigError(f"forecast: steps[{i}].{name}.{key}: {value!r} is not "
                                  f"forecast (not linear, or not yet); only "
                                  f"{', '.join(map(repr, allowed))}")
        if name == "subtract_phantom":
            phantom = True
        elif name == "correct_reference":
            reference, reference_phantom = params.get("strategy", "mean"), phantom
            side = bool(params.get("side_columns", False))
        names.append(name)
    return Reduction(tuple(names), phantom, reference, reference_phantom, side)


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
    >>> from spherex_reduce.analysis.forecast_steps import linear_steps
    >>> linear_steps({"steps": [{"unchop": {}}, {"fit_ramp": {}}]})
    ['unchop', 'fit_ramp']
    """
    return list(reduction(pipeline).steps)
