"""Which reductions the noise forecast propagates, and what a pipeline does to the noise.

Each step and reference strategy declares what it does to the noise on its
own class (``noise_effect``: a `~spherex_reduce.reduce.noise_effect.NoiseEffect`
or `~spherex_reduce.reduce.noise_effect.ReferenceEffect`, which parameter
values keep it linear and how it acts); `forecast_steps` reads them from a
plugin registry, so a plugin's step or strategy that declares itself is
forecast like the package's own.  `reduction` reads a pipeline into a
`Reduction`, the few facts the forecast's engine
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
step) is forecast as no clipping of Gaussian noise: on it it changes the
spectrum by less than the Monte Carlo resolves (measured at 3 σ for the
reference pixels and 5 σ for the slopes: see docs/forecast.rst), so a clip
below 3 σ is refused (`~spherex_reduce.reduce.noise_effect.MEASURED_SIGMA`), as
are ``fit_ramp``'s ``saturation`` (it drops reads: not linear), a pair
difference whose other exposure is not reduced the same way (``reduce_other:
false``) and a second reference correction.  The scene's pixel populations
(hot and telegraph pixels, a dark-current spread), which the ``sigma_clip``
step masks, are forecast through it (`Reduction.clip`,
`~spherex_reduce.analysis.forecast.populations`).
"""

from dataclasses import dataclass, field

from ...core.errors import ConfigError, PluginError
from ...reduce.noise_effect import AtLeast, declared_effect
from ...reduce.pipeline import as_pipeline
from ...reduce.plugins import default_registry

__all__ = ["Reduction", "forecast_steps", "forecast_strategies", "linear_steps", "reduction"]


def forecast_steps(registry=None):
    """The steps the forecast propagates: those of a registry that declare a noise effect.

    Parameters
    ----------
    registry : `~spherex_reduce.reduce.plugins.Registry`, optional
        Default: the built-in and installed plugins'
        (`~spherex_reduce.reduce.plugins.default_registry`).

    Returns
    -------
    dict
        ``{step name: NoiseEffect}`` in the registry's order.

    Examples
    --------
    >>> from spherex_reduce.analysis.forecast.steps import forecast_steps
    >>> effects = forecast_steps()
    >>> list(effects)
    ['unchop', 'subtract_phantom', 'correct_reference', 'fit_ramp', 'sigma_clip', 'pair_difference']
    >>> effects["fit_ramp"].linear["weighting"]
    ('uniform',)
    """
    registry = default_registry() if registry is None else registry
    return _declared(registry.steps)


def forecast_strategies(kind, registry=None):
    """The strategies of ``kind`` the forecast propagates: those that declare a noise effect.

    Parameters
    ----------
    kind : str
        The strategies' kind (a step's ``strategy_kind``, e.g. ``'reference'``).
    registry : `~spherex_reduce.reduce.plugins.Registry`, optional
        As `forecast_steps`.

    Returns
    -------
    dict
        ``{strategy name: ReferenceEffect}`` in the registry's order.

    Examples
    --------
    >>> from spherex_reduce.analysis.forecast.steps import forecast_strategies
    >>> {name: e.kind for name, e in forecast_strategies("reference").items()}
    {'mean': 'mean', 'acn': 'acn', 'wiener': 'wiener'}
    """
    registry = default_registry() if registry is None else registry
    return _declared(registry.strategies.get(kind, {}))


def _declared(registered):
    """``{name: effect}`` of the registered classes (``{name: Registered}``) that declare one."""
    effects = ((name, declared_effect(reg.obj)) for name, reg in registered.items())
    return {name: effect for name, effect in effects if effect is not None}


def _checked(effect, reg):
    """``effect`` (a class's declaration, or None), refused in one line if it names a
    parameter the class does not declare, or leaves out that parameter's default: a key
    misspelt would otherwise keep every value of the real parameter "linear"."""
    if effect is None:
        return None
    defaults = {p.name: p.default for p in getattr(reg.obj, "parameters", ())}
    for key, allowed in effect.linear.items():
        if key not in defaults:
            raise PluginError(f"{reg.obj.name} ({reg.plugin}): noise_effect.linear names "
                              f"{key!r}, which is not one of its parameters "
                              f"({', '.join(defaults) or 'none'})")
        if defaults[key] not in allowed:
            raise PluginError(f"{reg.obj.name} ({reg.plugin}): noise_effect.linear.{key} "
                              f"leaves out the parameter's default {defaults[key]!r}")
    return effect


def _refusal(i, name, key, value, allowed):
    """The error of a parameter value outside the values that keep step ``i`` linear."""
    only = repr(allowed) if isinstance(allowed, AtLeast) else ", ".join(map(repr, allowed))
    return ConfigError(f"forecast: steps[{i}].{name}.{key}: {value!r} is "
                      f"not forecast (not linear, or not yet); only {only}")


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
        The reference correction, as its strategy declares it (the ``kind`` of
        its `~spherex_reduce.reduce.noise_effect.ReferenceEffect`: ``'mean'``,
        one mean of the reference pixels per channel; ``'acn'``, one per
        channel and column-offset parity; ``'wiener'``, a drift estimate at
        every read), or None.
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
    clip : dict or None
        The parameters (defaults filled in) of the step that masks the slope image's
        outlying pixels (``sigma_clip``: its ``NoiseEffect`` declares ``clips_slopes``;
        the last of them), or None.
    clips : int
        How many such steps the pipeline has (a second is forecast as no clipping of
        Gaussian noise, as the first; with pixel populations, refused).
    differenced : bool
        A step takes the difference of two exposures of one detector
        (``pair_difference``: ``cancels_fixed``).
    clip_before_difference : bool
        The clip masks each exposure before their difference.
    """

    steps: tuple = ()
    phantom: bool = False
    reference: str | None = None
    reference_phantom: bool = False
    side_columns: bool = False
    reference_params: dict = field(default_factory=dict)
    reference_ramps: bool = True
    clip: dict | None = None
    clips: int = 0
    differenced: bool = False
    clip_before_difference: bool = False

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
        A step (or reference strategy) that declares no noise effect
        (`forecast_steps`), or one with a parameter value its declaration does
        not keep linear (the message names the step and value).

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
    table = forecast_steps(p.registry)
    names, phantom, fitted, ref = [], False, False, {}
    clip, clips, differenced, clip_first = None, 0, False, False
    for i, item in enumerate(p.config["steps"]):
        (name, params), = item.items()
        effect = table.get(name)
        if effect is not None:
            _checked(effect, p.registry.steps[name])
        if effect is None:
            raise ConfigError(f"forecast: steps[{i}].{name} ({p.source}) is not forecast so "
                              f"far; forecast steps: {', '.join(table)}")
        if (bad := effect.outside(params)) is not None:
            raise _refusal(i, name, bad[0], params[bad[0]], bad[1])
        strategy = None
        if effect.action == "reference":
            kind = p.registry.step(name).strategy_kind
            strategies = forecast_strategies(kind, p.registry)
            strategy = strategies.get(params.get("strategy"))
            if strategy is None:
                raise _refusal(i, name, "strategy", params.get("strategy"), tuple(strategies))
            _checked(strategy, p.registry.strategies[kind][params["strategy"]])
            if (bad := strategy.outside(params)) is not None:
                raise _refusal(i, name, bad[0], params[bad[0]], bad[1])
            if ref:
                raise ConfigError(f"forecast: steps[{i}].{name}: a second reference "
                                  "correction is not forecast; only one")
        if effect.action == "subtract_phantom" and not ref.get("consumed"):
            phantom = True  # (skipped when a reference estimate consumed the phantom values)
        elif effect.action == "slope_fit":
            fitted = True
        elif strategy is not None:
            rest = {k: v for k, v in params.items() if k != "strategy"}
            ref = {"reference": strategy.kind, "reference_phantom": phantom,
                   "side_columns": bool(params.get("side_columns", False)),
                   "reference_params": rest, "reference_ramps": not fitted,
                   "consumed": strategy.consumes_phantom(params, phantom)}
        if effect.clips_slopes:
            clips += 1
            clip = {q.name: q.default for q in p.registry.step(name).parameters} | params
        if effect.cancels_fixed:
            differenced, clip_first = True, clip is not None
        names.append(name)
    ref.pop("consumed", None)
    return Reduction(tuple(names), phantom, clip=clip, clips=clips, differenced=differenced,
                     clip_before_difference=clip_first, **ref)


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
