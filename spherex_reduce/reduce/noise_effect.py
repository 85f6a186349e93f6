"""What a step or a strategy does to the noise, declared on its class for the noise forecast.

The noise forecast (`~spherex_reduce.analysis.forecast`) propagates a
pipeline's steps without random numbers, so it must know how each step acts on
the noise.  A `~spherex_reduce.Step` says so in its class attribute
``noise_effect``, a `NoiseEffect`; a reference strategy
(`~spherex_reduce.Strategy` of kind ``reference``) in its own, a
`ReferenceEffect`.  A class that declares nothing (``noise_effect = None``, the
base classes' default) is not forecast: a pipeline holding it is refused in
one line.  The declaration is read from the class itself, never inherited: a
subclass may compute something else, so it declares its own.

Both say, as data, which parameter values keep the step linear (``linear``:
for each parameter to check, the values allowed, or an `AtLeast` bound), and
how it acts:

``identity``
    The slope image's noise is unchanged: a permutation of the rows
    (``unchop``), a clip the forecast neglects (``sigma_clip``), a pair
    difference of two exposures reduced alike (``pair_difference``).
``subtract_phantom``
    Each read minus its phantom value (the mean of its phantom samples),
    unless a reference strategy consumed them first.
``reference``
    A reference correction; the step's strategy (a `ReferenceEffect`)
    decides: ``mean`` (one mean of the reference pixels per channel), ``acn``
    (one per channel and column-offset parity) or ``wiener`` (a drift
    estimate at every read, with that strategy's weights).
``slope_fit``
    Least-squares slopes with uniform weights, which commute with every
    frame-wise linear step.

Examples
--------
>>> from spherex_reduce.reduce.noise_effect import MEASURED_SIGMA, NoiseEffect
>>> clip = NoiseEffect("identity", linear={"sigma": MEASURED_SIGMA})
>>> clip.outside({"sigma": 5.0}), clip.outside({"sigma": 2.5})
(None, ('sigma', a number >= 3))
"""

from collections.abc import Callable
from dataclasses import dataclass, field

__all__ = ["ACTIONS", "KINDS", "MEASURED_SIGMA", "AtLeast", "NoiseEffect", "ReferenceEffect",
           "declared_effect"]

#: How a step may act on the noise (see the module notes).
ACTIONS = ("identity", "subtract_phantom", "reference", "slope_fit")

#: How a reference strategy may act on the noise (see the module notes).
KINDS = ("mean", "acn", "wiener")


@dataclass(frozen=True)
class AtLeast:
    """The values a clipping threshold may take: a number from ``minimum`` up, or None (a
    threshold that defaults to the step's ``sigma``).

    Examples
    --------
    >>> from spherex_reduce.reduce.noise_effect import MEASURED_SIGMA
    >>> 5.0 in MEASURED_SIGMA, 2.5 in MEASURED_SIGMA, MEASURED_SIGMA
    (True, False, a number >= 3)
    """

    minimum: float

    def __contains__(self, value):
        number = isinstance(value, (int, float)) and not isinstance(value, bool)
        return value is None or (number and value >= self.minimum)

    def __repr__(self):
        return f"a number >= {self.minimum:g}"


#: The clipping thresholds (σ) the forecast may neglect: its effect was measured there
#: (see the forecast page of the documentation).
MEASURED_SIGMA = AtLeast(3.0)


def _allowed(linear):
    """``linear`` with every list of values as a tuple; refuses a value that is neither."""
    out = {}
    for key, allowed in dict(linear).items():
        if isinstance(allowed, AtLeast):
            out[key] = allowed
        elif isinstance(allowed, (tuple, list, set, frozenset)):
            out[key] = tuple(allowed)
        else:
            raise TypeError(f"linear[{key!r}]: expected a tuple of values or an AtLeast, "
                            f"got {allowed!r}")
    return out


def _outside(linear, params):
    for key, allowed in linear.items():
        if key in params and params[key] not in allowed:
            return key, allowed
    return None


@dataclass(frozen=True)
class NoiseEffect:
    """What a step does to the noise: a step's ``noise_effect`` class attribute.

    Parameters
    ----------
    action : str
        One of `ACTIONS`: ``'identity'``, ``'subtract_phantom'``,
        ``'reference'`` (the step's strategy declares the rest: the step must
        set ``strategy_kind``) or ``'slope_fit'``.
    linear : dict
        For each parameter whose value decides whether the step is linear, the
        values that keep it so (a tuple, which must hold the parameter's
        default) or an `AtLeast` bound.  Parameters not named may take any
        value.
    clips_slopes : bool
        The step masks the slope image's outlying pixels as
        `astropy.stats.sigma_clip` does, with its parameters (``sigma``,
        ``sigma_lower``, ``sigma_upper``, ``maxiters``, ``cenfunc``, ``stdfunc``):
        the forecast takes the pixel populations it masks through them
        (`~spherex_reduce.analysis.forecast.populations`).
    cancels_fixed : bool
        The step takes the difference of two exposures of one detector: a fixed
        pattern (a spread of the dark current, hot pixels' excess) cancels.

    Examples
    --------
    >>> from spherex_reduce.reduce.noise_effect import NoiseEffect
    >>> fit = NoiseEffect("slope_fit", linear={"weighting": ("uniform",)})
    >>> fit.outside({"weighting": "uniform"}), fit.outside({"weighting": "optimal"})
    (None, ('weighting', ('uniform',)))
    """

    action: str
    linear: dict = field(default_factory=dict)
    clips_slopes: bool = False
    cancels_fixed: bool = False

    def __post_init__(self):
        if self.action not in ACTIONS:
            raise ValueError(f"NoiseEffect: unknown action {self.action!r}; valid: "
                             f"{', '.join(ACTIONS)}")
        object.__setattr__(self, "linear", _allowed(self.linear))

    def outside(self, params):
        """The first parameter of ``params`` (a dict) whose value the declaration does not
        keep linear, as ``(name, allowed)``, or None if every value is allowed."""
        return _outside(self.linear, params)


def _never(params, phantom_subtracted):
    """A strategy that never estimates from the phantom values."""
    return False


@dataclass(frozen=True)
class ReferenceEffect:
    """What a reference strategy does to the noise: a strategy's ``noise_effect`` attribute.

    Parameters
    ----------
    kind : str
        One of `KINDS`: the correction computes what the built-in strategy of
        that name computes with the same parameters (``'mean'``, ``'acn'`` or
        ``'wiener'``).
    linear : dict
        As for `NoiseEffect`, for the strategy's own parameters.
    consumes_phantom : callable
        ``consumes_phantom(params, phantom_subtracted)``: whether the strategy,
        given the step's parameters (a dict) and whether ``subtract_phantom``
        ran before it, estimates from the phantom values of every read and so
        consumes them (a later ``subtract_phantom`` is then skipped, as
        `~spherex_reduce.Strategy.uses_phantom` says for a run).  Default:
        never.

    Examples
    --------
    >>> from spherex_reduce.reduce.noise_effect import MEASURED_SIGMA, ReferenceEffect
    >>> mean = ReferenceEffect("mean", linear={"sigma": MEASURED_SIGMA})
    >>> mean.outside({"sigma": 2.0}), mean.consumes_phantom({}, False)
    (('sigma', a number >= 3), False)
    """

    kind: str
    linear: dict = field(default_factory=dict)
    consumes_phantom: Callable = _never

    def __post_init__(self):
        if self.kind not in KINDS:
            raise ValueError(f"ReferenceEffect: unknown kind {self.kind!r}; valid: "
                             f"{', '.join(KINDS)}")
        object.__setattr__(self, "linear", _allowed(self.linear))

    def outside(self, params):
        """As `NoiseEffect.outside`."""
        return _outside(self.linear, params)


def declared_effect(cls):
    """The ``noise_effect`` a step or strategy class declares itself, or None.

    Read from the class's own attributes: a subclass that declares nothing is
    not forecast, whatever its base class declares.

    Parameters
    ----------
    cls : type
        A `~spherex_reduce.Step` or `~spherex_reduce.Strategy` subclass.

    Returns
    -------
    `NoiseEffect`, `ReferenceEffect` or None

    Examples
    --------
    >>> from spherex_reduce.reduce.noise_effect import declared_effect
    >>> from spherex_reduce.reduce.steps.reference.strategies import AcnReference, MeanReference
    >>> declared_effect(MeanReference).kind, declared_effect(AcnReference).kind
    ('mean', 'acn')
    >>> class Mine(MeanReference):
    ...     name = "mine"
    >>> declared_effect(Mine) is None
    True
    """
    return vars(cls).get("noise_effect")
