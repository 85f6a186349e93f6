"""Base classes for what plugins register: steps, strategies, simulators."""

import os
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import ClassVar

from ..core.errors import StepSkipped, UnknownNameError
from ..core.parameters import Parameter, validate_parameters
from ..io import read
from ..io.header_text import header_text
from ..io.sources import MemorySource
from .noise_effect import NoiseEffect, ReferenceEffect
from .options import RunOptions
from .passes import PlannedStep, Whole, plan_pass, run_pass
from .provenance import record_step

__all__ = ["Consumer", "Kernel", "Record", "Simulator", "Step", "Strategy"]


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
       `~spherex_reduce.io.sources.side_block`), e.g. one offset per frame and
       channel;
    2. ``side = kernel.apply_side(coefficients, side)``: the side block as this
       step leaves it, for the next kernel's ``prepare``;
    3. ``kernel.apply(coefficients, block)`` on every band of rows, in any
       order and from several threads at once;
    4. ``kernel.record(coefficients)``: tables and header cards.

    A step run alone goes through the same executor (on the exposure in
    memory), and each pixel's arithmetic does not depend on which band holds
    it, so a streamed reduction and the steps called one by one give the same
    numbers bit for bit.

    A kernel is configured when it is made (the step's parameters and the
    input's `~spherex_reduce.core.block.Context`) and keeps no state between
    calls of ``apply``.

    Attributes
    ----------
    context : `~spherex_reduce.core.block.Context`
        What its blocks are (set by the constructor).
    needs_exposure : bool
        True if `prepare` needs the whole exposure (``prepare(side,
        exposure)``), not only the side block (e.g. the ``median`` reference
        strategy): after other kernels of a pass, the executor first makes
        their output into an exposure for it (which it then corrects in place:
        keep no view of it past `prepare`).
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
        """The corrected `~spherex_reduce.core.block.Block` (a new one, or ``block`` if owned)."""
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
        """Take one band (a `~spherex_reduce.core.block.Block`)."""
        raise NotImplementedError

    def finish(self, reference, header, tables):
        """The result `~spherex_reduce.Exposure`.

        ``reference`` is the `~spherex_reduce.ReferenceReads` kept aside after
        the kernels before this step (corrected like the pixels), or None;
        ``header`` and ``tables`` those of the input after those kernels.  The
        consumer knows the schedule from the `~spherex_reduce.core.block.Context` it
        was made with.
        """
        raise NotImplementedError


class Step:
    """A pipeline step: one correction, run alone or by a `~spherex_reduce.Pipeline`.

    Subclasses set the class attributes and either return a `Kernel` from
    :meth:`kernel` (a correction that works on any band of rows: it then
    streams through the executor), a `Consumer` from :meth:`consumer`
    (``fit_ramp``), or implement :meth:`run` (a step that needs the whole
    exposure).  Calling the step (``step(exposure, **params)``) validates the
    parameters, runs it and records its provenance.  A step that has nothing
    to do raises `~spherex_reduce.core.errors.StepSkipped` with a reason.

    Attributes
    ----------
    name : str
        Name used in the YAML file (``steps: [{name: {...}}]``).
    keyword : str
        FITS status keyword (at most 8 characters), e.g. ``S_UNCHOP``; set to
        ``COMPLETE`` or ``SKIPPED`` after every run.
    parameters : tuple of `~spherex_reduce.core.parameters.Parameter`
        What the YAML mapping may contain.
    strategy_kind : str or None
        If set, the step takes a ``strategy`` parameter naming a registered
        `Strategy` of this kind, whose own parameters are accepted beside the
        step's.
    default_strategy : str or None
        Strategy used when the YAML file names none.
    inputs : tuple of str
        Parameters naming another exposure's FITS file (see :meth:`apply_to`).

    Parameters
    ----------
    registry : `~spherex_reduce.reduce.plugins.Registry`, optional
        Where strategies are looked up and whose hooks the step calls.
    threads : int, optional
        Bands corrected at once when the step runs through the executor.
    strategies : `~spherex_reduce.reduce.plugins.Registry`, optional
        Where strategies are looked up when there is no ``registry`` (its hooks
        are not called).  ``correct_reference`` made without either uses the
        built-in and installed plugins' (`~spherex_reduce.reduce.plugins.default_registry`).

    Examples
    --------
    >>> from spherex_reduce import Step
    >>> from spherex_reduce.core.parameters import Parameter
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

    #: parameters that name another exposure's FITS file (``pair_difference``'s
    #: ``other``, ``subtract_dark``'s ``dark``): read before :meth:`run`, which
    #: receives the `~spherex_reduce.Exposure`
    inputs: ClassVar[tuple] = ()

    #: what the step does to the noise, for the noise forecast: a
    #: `~spherex_reduce.reduce.noise_effect.NoiseEffect` declared on the step's own class
    #: (not inherited); None, the default: the forecast refuses the step
    noise_effect: ClassVar[NoiseEffect | None] = None

    def __init__(self, registry=None, threads=None, strategies=None):
        #: the `~spherex_reduce.reduce.plugins.Registry` whose ``before_step`` and
        #: ``after_step`` hooks run around the step, and where it looks up its
        #: strategies; None: no hooks
        self.registry = registry
        #: how the step runs through the executor when run alone (a
        #: `~spherex_reduce.reduce.options.RunOptions`; its ``threads`` from the argument)
        self.options = RunOptions(threads=threads)
        #: where strategies are looked up when the step has no :attr:`registry` (a
        #: `~spherex_reduce.reduce.plugins.Registry` whose hooks are not called)
        self.strategies = strategies

    def __call__(self, exposure, **params):
        """Run the step: validate ``params``, call the plugins' hooks, run, record provenance.

        This is what a pipeline does for each step it runs whole, and what the
        package's functions (`~spherex_reduce.unchop`, `~spherex_reduce.fit_ramp`
        ...) do: the result carries the step's status keyword, its parameters
        and a row of the ``PROVENANCE`` table however the step was run.

        Parameters
        ----------
        exposure : `~spherex_reduce.Exposure`
            Not modified.
        **params
            The step's parameters (defaults filled in; unknown names and wrong
            types raise `~spherex_reduce.core.errors.ConfigError`).  Parameters in
            :attr:`inputs` name FITS files, read before the step runs.

        Returns
        -------
        `~spherex_reduce.Exposure`
        """
        return self.apply_to(exposure, params)

    def apply_to(self, exposure, params, inputs=None):
        """`__call__` with the second inputs given as exposures (``{name: Exposure}``)
        instead of files: how a pipeline passes an input it reduced itself."""
        params = self.validate(params)
        given, labels, paths = dict(inputs or {}), {}, {}
        for name in self.inputs:
            path = params.get(name)
            if isinstance(path, (str, os.PathLike)):
                labels[name] = paths[name] = str(path)
                if given.get(name) is None:
                    given[name] = self.read_input(name, path)
            elif given.get(name) is not None:
                labels[name] = "exposure given in memory"
        self.started(exposure, params)
        t0 = time.perf_counter()
        try:
            result = self.run(exposure, **{**params, **given})
            status, reason = "COMPLETE", None
        except StepSkipped as skip:
            result, status, reason = exposure, "SKIPPED", skip.reason
        if status == "COMPLETE":
            result = self._input_cards(result, paths)
        return self.record(exposure, result, params, status, reason,
                           time.perf_counter() - t0, route="whole exposure",
                           inputs=labels)

    def read_input(self, name, path, supplied=None):
        """Read the FITS file a parameter of :attr:`inputs` names, with ``supplied``
        geometry/readout values for keywords it lacks (a pipeline gives its config's
        ``geometry:`` and ``readout:`` sections; a step run alone reads the file as it is)."""
        if not Path(path).is_file():
            raise FileNotFoundError(f"{self.name}.{name}: no such file: {path}")
        return read(path, **(supplied or {}))

    def input_card(self, name, label):
        """A header card ``(keyword, value, comment)`` naming the file of input ``name``,
        or None (the default).  ``label`` is the file's path as a card can hold it
        (`~spherex_reduce.io.header_text.header_text`)."""
        return None

    def streams(self):
        """Whether the step may run in a pass of the executor: it has a kernel or a
        consumer (its class overrides :meth:`kernel` or :meth:`consumer`) and no
        :attr:`inputs` of its own."""
        cls = type(self)
        return not self.inputs and (cls.kernel is not Step.kernel
                                    or cls.consumer is not Step.consumer)

    def reduces_input(self, name, params):
        """Whether a `~spherex_reduce.Pipeline` first brings the exposure of input ``name``
        (one of :attr:`inputs`) to this step's stage, running on it the steps it has
        completed so far; ``params`` are the step's validated parameters.

        The default, False, has the step read that file as it is.
        """
        return False

    def _input_cards(self, result, labels):
        cards = [c for name, label in labels.items()  # the name as a card can hold it
                 if label and (c := self.input_card(name, header_text(label))) is not None]
        if not cards:
            return result
        header = result.header.copy()
        for key, value, comment in cards:
            header[key] = (value, comment)
        return result.replace(header=header)

    def started(self, exposure, params):
        """Call the plugins' ``before_step`` hooks: the step is about to run on ``exposure``
        (None when it runs inside a streamed pass over a file)."""
        if self.registry is not None:
            self.registry.pm.hook.before_step(step=self, exposure=exposure, params=params)

    def record(self, before, result, params, status, reason, elapsed, route, inputs=None):
        """``result`` with this step's provenance: status keyword, parameters, HISTORY, the
        cards the plugins' ``after_step`` hooks return, and a ``PROVENANCE`` row.

        ``before`` is the step's input exposure (None when it ran inside a
        streamed pass over a file); ``route`` says how it ran; ``inputs``
        names other files it used (e.g. ``{'other': 'b.fits'}``).
        """
        replies = []
        if self.registry is not None:
            replies = self.registry.pm.hook.after_step(
                step=self, exposure=before, result=result, params=params, status=status,
                reason=reason, elapsed=elapsed)
        return record_step(self, result, params, status, reason, elapsed, route,
                           inputs=inputs, extra_cards=[c for r in replies for c in (r or ())])

    # -- parameters ------------------------------------------------------------
    def strategy_registry(self):
        """The `~spherex_reduce.reduce.plugins.Registry` this step looks its strategies up
        in: its :attr:`registry`, else its :attr:`strategies` (None if it has neither)."""
        return self.registry if self.registry is not None else self.strategies

    def strategy_names(self):
        """Names of the strategies this step may use."""
        found = self.strategy_registry()
        return [] if found is None else sorted(found.strategies.get(self.strategy_kind, {}))

    def strategy(self, name):
        """The strategy class ``name`` of this step's kind.

        Raises `~spherex_reduce.core.errors.UnknownNameError` (a `KeyError`) listing
        the valid names.
        """
        found = self.strategy_registry()
        if found is None:
            raise UnknownNameError(
                f"unknown {self.strategy_kind} strategy {name!r}: the step was made without "
                "a registry (give registry=spherex_reduce.reduce.plugins.Registry())")
        return found.strategy(self.strategy_kind, name)

    def declared(self, params, path=None):
        """The `~spherex_reduce.core.parameters.Parameter` list for ``params`` (with the chosen
        strategy's own parameters)."""
        declared = list(self.parameters)
        if self.strategy_kind:
            name = (params or {}).get("strategy", self.default_strategy)
            choice = Parameter("strategy", self.default_strategy, (str,),
                               f"{self.strategy_kind} strategy",
                               choices=tuple(self.strategy_names()))
            choice.check(name, f"{path or self.name}.strategy")
            declared = [choice, *declared, *self.strategy(name).parameters]
        return declared

    def validate(self, params, path=None):
        """``params`` checked against :meth:`declared`, defaults filled in (a new dict)."""
        return validate_parameters(params, self.declared(params, path), path or self.name)

    def kernel(self, context, **params):
        """The step's `Kernel` for blocks of ``context`` (a `~spherex_reduce.core.block.Context`),
        or None if it has none (then :meth:`run` works on whole exposures).

        Raises `~spherex_reduce.core.errors.StepSkipped` when there is nothing to do.
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
        through the executor, as a pipeline's pass of this one step (one
        implementation for both routes).
        """
        source = MemorySource(exposure)
        plan = plan_pass([PlannedStep(0, self.name, params, self)], 0, source, self.options)
        if isinstance(plan, Whole):
            raise NotImplementedError(f"step {self.name!r} has neither run, kernel nor consumer")
        if plan.skipped:
            raise StepSkipped(plan.skipped[0])
        return run_pass(source, plan, options=self.options)[0]


class Strategy:
    """A variant of a step (e.g. the ``mean`` reference correction).

    Attributes
    ----------
    kind : str
        The step family it belongs to (``'reference'`` for ``correct_reference``).
    name : str
        Value of the step's ``strategy`` parameter that selects it.
    parameters : tuple of `~spherex_reduce.core.parameters.Parameter`
        Its own parameters, accepted in the step's YAML mapping.
    """

    kind: ClassVar[str] = ""
    name: ClassVar[str] = ""
    parameters: ClassVar[tuple] = ()

    #: True if `estimate` needs the whole exposure, not only the side block: the step's
    #: pass then makes the exposure in memory for it (False, the default, streams; the
    #: exposure given is corrected in place after `estimate`: keep no view of it)
    needs_exposure = False

    #: what a reference strategy does to the noise, for the noise forecast: a
    #: `~spherex_reduce.reduce.noise_effect.ReferenceEffect` declared on the strategy's own
    #: class (not inherited); None, the default: the forecast refuses the strategy
    noise_effect: ClassVar[ReferenceEffect | None] = None

    def __init__(self, **params):
        self.params = params

    def estimate(self, side, context, exposure=None):
        """Offsets from the side block (a `~spherex_reduce.core.block.Block` of the reference
        reads of every frame), or from ``exposure`` when `needs_exposure`.

        ``context`` is the `~spherex_reduce.core.block.Context` of the blocks the
        offsets apply to (schedule, unit, row order, the threads it may use).

        Returns a `~spherex_reduce.reduce.steps.reference.strategies.ReferenceOffsets`;
        the step's kernel subtracts them.  A strategy that defines it streams
        like the built-in ones.
        """
        raise NotImplementedError

    def uses_phantom(self, context):
        """Whether `estimate` uses the phantom values of the blocks of ``context`` (a
        `~spherex_reduce.core.block.Context`).

        When True the step's kernel consumes them, as ``subtract_phantom`` does,
        so that a later ``subtract_phantom`` is skipped instead of correcting
        twice.  The default is False.
        """
        return False

    def __call__(self, exposure, **params):
        """Correct a whole exposure (strategies written before `estimate`)."""
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
