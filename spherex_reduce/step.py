"""Base classes for what plugins register: steps, strategies, simulators."""

from typing import ClassVar

__all__ = ["Simulator", "Step", "Strategy"]


class Step:
    """A pipeline step: a thin wrapper around a plain function on `Exposure`.

    Subclasses set the class attributes and implement :meth:`run`.  A step that
    has nothing to do raises `~spherex_reduce.errors.StepSkipped` with a reason.

    Attributes
    ----------
    name : str
        Name used in the YAML file (``steps: [{name: {...}}]``).
    keyword : str
        FITS status keyword (at most 8 characters), e.g. ``S_UNCHOP``; set to
        ``COMPLETE`` or ``SKIPPED`` after every run.
    parameters : tuple of `~spherex_reduce.parameters.Parameter`
        What the YAML mapping may contain.
    strategy_kind : str or None
        If set, the step takes a ``strategy`` parameter naming a registered
        `Strategy` of this kind, whose own parameters are accepted beside the
        step's.
    default_strategy : str or None
        Strategy used when the YAML file names none.

    Examples
    --------
    >>> from spherex_reduce import Step
    >>> from spherex_reduce.parameters import Parameter
    >>> class Scale(Step):
    ...     name, keyword = "scale", "S_SCALE"
    ...     parameters = (Parameter("factor", 1.0, (float,), "multiply by this"),)
    ...     def run(self, exposure, factor):
    ...         return exposure.replace(data=exposure.data.data * factor)
    """

    name: ClassVar[str] = ""
    keyword: ClassVar[str] = ""
    parameters: ClassVar[tuple] = ()
    strategy_kind: ClassVar[str | None] = None
    default_strategy: ClassVar[str | None] = None

    def __init__(self, registry=None):
        self.registry = registry

    def run(self, exposure, **params):
        """Return a new exposure; never modify ``exposure``."""
        raise NotImplementedError

    def strategy(self, name):
        """The registered strategy class ``name`` of this step's kind."""
        return self.registry.strategy(self.strategy_kind, name)


class Strategy:
    """A variant of a step (e.g. the ``mean`` reference correction).

    Attributes
    ----------
    kind : str
        The step family it belongs to (``'reference'`` for ``correct_reference``).
    name : str
        Value of the step's ``strategy`` parameter that selects it.
    parameters : tuple of `~spherex_reduce.parameters.Parameter`
        Its own parameters, accepted in the step's YAML mapping.
    """

    kind: ClassVar[str] = ""
    name: ClassVar[str] = ""
    parameters: ClassVar[tuple] = ()

    def __call__(self, exposure, **params):
        raise NotImplementedError


class Simulator:
    """A noise simulator: turns a scene into an `Exposure`.

    Attributes
    ----------
    name : str
        Name a scene selects it by.
    """

    name: ClassVar[str] = ""

    def simulate(self, scene, *, mode=None, seed=None):
        raise NotImplementedError
