"""Base classes for what plugins register: steps, strategies, simulators."""

from collections.abc import Mapping
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import ClassVar

from .executor import MemorySource, execute

__all__ = ["Consumer", "FrameAccumulator", "Kernel", "Record", "Simulator", "Step", "Strategy"]


@dataclass
class Record:
    """What a kernel leaves besides corrected pixels (see `Kernel.record`).

    Attributes
    ----------
    tables : dict of `~astropy.table.Table`
        Tables for the output (e.g. ``REFOFFS``).
    cards : list of ``(keyword, value, comment)``
        Header cards for the output (e.g. ``NNOREF``).
    """

    tables: dict = field(default_factory=dict)
    cards: list = field(default_factory=list)


class Kernel:
    """How a step corrects any band of rows of every frame (the step's one implementation).

    A step whose correction works row by row, from coefficients that a few
    side values determine (reference reads, phantom values), returns a
    kernel from :meth:`Step.kernel`.  The executor then calls, in order:

    1. ``coefficients = kernel.prepare(side)``: from the side block (the
       reference reads of every frame, with their phantom values; see
       `~spherex_reduce.executor.side_block`), e.g. one offset per frame and
       channel;
    2. ``side = kernel.apply_side(coefficients, side)``: the side block as this
       step leaves it, for the next kernel's ``prepare``;
    3. ``kernel.apply(coefficients, block)`` on every band of rows, in any
       order and from several threads at once;
    4. ``kernel.record(coefficients)``: tables and header cards.

    Running the step on a whole exposure is the same with one band, so a
    streamed reduction and an in-memory one give the same numbers bit for bit.

    A kernel is configured when it is made (the step's parameters and the
    input's `~spherex_reduce.block.Context`) and keeps no state between
    calls of ``apply``.

    Attributes
    ----------
    context : `~spherex_reduce.block.Context`
        What its blocks are (set by the constructor).
    needs_exposure : bool
        True if `prepare` needs the whole exposure (``prepare(side,
        exposure)``), not only the side block: the step then runs on the
        exposure in memory (e.g. the ``median`` reference strategy).
    """

    context = None
    needs_exposure = False

    def __init__(self, context):
        self.context = context

    @property
    def output(self):
        """The context of the blocks `apply` returns (default: the input's)."""
        return self.context

    def prepare(self, side):
        """Coefficients from the side block (default: None, nothing to estimate)."""
        return None

    def apply(self, coefficients, block):
        """The corrected `~spherex_reduce.block.Block` (a new one, or ``block`` if owned)."""
        raise NotImplementedError

    def apply_side(self, coefficients, side):
        """The side block after this step (default: `apply` to it)."""
        return self.apply(coefficients, side)

    def extra_rows(self, coefficients):
        """A block of rows no band of the input holds (e.g. rows never read), or None."""
        return None

    def record(self, coefficients):
        """A `Record` of tables and header cards (default: empty)."""
        return Record()


class Consumer:
    """Turns bands of a ramp into the step's result (``fit_ramp``: slopes).

    `band` is called once for every band of rows, from several threads at
    once (bands never share rows); `finish` then returns the exposure.
    """

    def band(self, block):
        """Take one band (a `~spherex_reduce.block.Block`)."""
        raise NotImplementedError

    def finish(self, side, header, tables):
        """The result `~spherex_reduce.Exposure`.

        ``side`` is the side block as the kernels before this step leave it
        (the reference reads, reduced the same way when in readout order, or
        None); ``header`` and ``tables`` those of the input after those kernels.
        The consumer knows the schedule from the `~spherex_reduce.block.Context`
        it was made with.
        """
        raise NotImplementedError


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

    #: bands corrected at once when the step runs through the executor (None: its default)
    threads = None

    def kernel(self, context, **params):
        """The step's `Kernel` for blocks of ``context`` (a `~spherex_reduce.block.Context`),
        or None if it has none (then :meth:`run` works on whole exposures).

        Raises `~spherex_reduce.errors.StepSkipped` when there is nothing to do.
        """
        return None

    def consumer(self, context, **params):
        """The step's `Consumer` of bands of ``context``, or None (the default).

        A step that turns ramps into an image (``fit_ramp``) consumes the bands
        the kernels before it leave.
        """
        return None

    def run(self, exposure, **params):
        """Return a new exposure; never modify ``exposure``.

        The default runs the step's kernel or consumer on the whole exposure,
        through the executor (one implementation for both routes).
        """
        source = MemorySource(exposure)
        kernel = self.kernel(source.context, **params)
        consumer = self.consumer(source.context, **params)
        if kernel is None and consumer is None:
            raise NotImplementedError(f"step {self.name!r} has neither run, kernel nor consumer")
        return execute(source, [] if kernel is None else [kernel], consumer,
                       threads=self.threads)

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
