"""Base classes for what plugins register: steps, strategies, simulators."""

from collections.abc import Mapping
from types import MappingProxyType
from typing import ClassVar

__all__ = ["FrameAccumulator", "Simulator", "Step", "Strategy"]


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
    per_frame : bool
        True if running the step on ramps gives the same as running it on
        each frame alone (as a one-frame exposure) and stacking the results.
        The pipeline then streams frames through it, one at a time, into a
        following step that has an :meth:`accumulator` (e.g. ``fit_ramp``),
        so memory stays near one frame.  Tables such a step records get a
        ``frame`` column.
    file_sections : dict
        The pipeline config's ``geometry:`` and ``readout:`` sections, set by
        the `~spherex_reduce.Pipeline` on the steps it runs: a step that reads
        another file (``pair_difference``) supplies them for keywords the file
        lacks, as the pipeline does for its input.

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
    per_frame: ClassVar[bool] = False
    file_sections: ClassVar[Mapping] = MappingProxyType({})

    def __init__(self, registry=None):
        self.registry = registry

    def run(self, exposure, **params):
        """Return a new exposure; never modify ``exposure``."""
        raise NotImplementedError

    def streams(self, params):
        """Whether the pipeline may stream frames through this step with ``params``.

        Defaults to :attr:`per_frame`; a step whose result depends on several
        frames only for some parameters (e.g. source masking on the
        difference of the last and first frames) says so here.
        """
        return self.per_frame

    def merge_frames(self, exposure, params):
        """Recompute header summaries after a streamed run (default: unchanged).

        A per-frame step's header keywords come from the last frame when the
        pipeline streams; the merged tables (with their ``frame`` column) are
        complete, so a step that writes summary keywords recomputes them here.
        """
        return exposure

    def accumulator(self, schedule, header, **params):
        """A `FrameAccumulator` that reduces ramps frame by frame, or None.

        Steps that turn frames into one image (``fit_ramp``) return one, so
        the pipeline can feed them frames as it reads them.  ``schedule`` is
        the whole exposure's; ``header`` the input's.  The default is None.
        """
        return None

    def strategy(self, name):
        """The registered strategy class ``name`` of this step's kind."""
        return self.registry.strategy(self.strategy_kind, name)


class FrameAccumulator:
    """Receives the frames of a ramp one at a time and returns the reduced exposure.

    The result must equal what the step's :meth:`Step.run` returns on the
    whole ramp.
    """

    def add(self, index, frame):
        """Take frame ``index`` (a one-frame `~spherex_reduce.Exposure`)."""
        raise NotImplementedError

    def finish(self):
        """The reduced `~spherex_reduce.Exposure`, after every frame was added."""
        raise NotImplementedError

    def close(self):
        """Release threads or memory when the run failed before `finish` (optional)."""


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
