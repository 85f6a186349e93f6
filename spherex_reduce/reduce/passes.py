"""How a list of steps runs: passes of kernels through the executor, or a step run whole.

`plan_pass` is the one place that decides.  From a step on, it gathers the
consecutive steps that have a `~spherex_reduce.reduce.step.Kernel` (each made
for the context the previous one leaves), ending in a step that has a
`~spherex_reduce.reduce.step.Consumer` (``fit_ramp``) if one follows: a
`Pass`, which `run_pass` runs through the executor in one reading of the
source.  A step without kernel or consumer, or with file inputs of its own
(``pair_difference``, ``subtract_dark``), is a `Whole` step: it runs on the
whole exposure (`~spherex_reduce.reduce.step.Step.apply_to`).
"""

from dataclasses import dataclass, field

from ..core.errors import StepSkipped
from .executor import execute, joins
from .options import RunOptions

__all__ = ["Pass", "PlannedStep", "Whole", "plan_pass", "run_pass"]


@dataclass(frozen=True)
class PlannedStep:
    """A step of a list, with its validated parameters.

    Attributes
    ----------
    index : int
        Its place in the list.
    name : str
    params : dict
    step : `~spherex_reduce.reduce.step.Step`
    """

    index: int
    name: str
    params: dict
    step: object


@dataclass
class Pass:
    """Steps run in one pass of the executor.

    Attributes
    ----------
    members : list of `PlannedStep`
        Every step of the pass, in order, skipped ones included.
    kernels : list of (`PlannedStep`, `~spherex_reduce.reduce.step.Kernel`)
        The kernels that run, in order.
    consumer : (`PlannedStep`, `~spherex_reduce.reduce.step.Consumer`) or None
        The step that consumes the bands, if any.
    skipped : dict
        Reason by step index, for the steps with nothing to do.
    end : int
        Index of the first step after the pass.
    """

    members: list = field(default_factory=list)
    kernels: list = field(default_factory=list)
    consumer: tuple | None = None
    skipped: dict = field(default_factory=dict)
    end: int = 0

    @property
    def runs(self):
        """Whether the executor has work (kernels or a consumer), not only skipped steps."""
        return bool(self.kernels) or self.consumer is not None


@dataclass(frozen=True)
class Whole:
    """A step run on the whole exposure."""

    planned: PlannedStep


def plan_pass(steps, start, source, options=None):
    """What runs next, from ``steps[start]`` on ``source``: a `Pass` or a `Whole` step.

    Parameters
    ----------
    steps : list of `PlannedStep`
    start : int
    source : `~spherex_reduce.io.sources.Source`
        What the pass would read (its context and whether it is in memory).
    options : `~spherex_reduce.reduce.options.RunOptions`, optional
        Its ``threads`` are recorded in the context the kernels are made for.

    Returns
    -------
    `Pass` or `Whole`
        A pass holds at least one step (it may have only skipped ones).
    """
    if not steps[start].step.streams():
        return Whole(steps[start])
    context = source.context.replace(threads=(options or RunOptions()).threads)
    plan = Pass()
    j = start
    while j < len(steps):
        planned = steps[j]
        if planned.step.inputs:
            break
        try:
            kernel = planned.step.kernel(context, **planned.params)
            consumer = (None if kernel is not None
                        else planned.step.consumer(context, **planned.params))
        except StepSkipped as skip:
            plan.skipped[j] = skip.reason
            plan.members.append(planned)
            j += 1
            continue
        if kernel is not None:
            if not joins(kernel, len(plan.kernels), source):
                break
            plan.kernels.append((planned, kernel))
            plan.members.append(planned)
            context = kernel.output
            j += 1
            continue
        if consumer is not None:
            plan.consumer = (planned, consumer)
            plan.members.append(planned)
            j += 1
        break
    if not plan.members:  # its kernel must see the whole exposure first
        return Whole(steps[start])
    plan.end = j
    return plan


def run_pass(source, plan, *, options=None, progress=None):
    """Run a `Pass` through the executor, with ``options`` (a
    `~spherex_reduce.reduce.options.RunOptions`) and ``progress`` (called with
    the rows done after each band).

    Returns
    -------
    result : `~spherex_reduce.Exposure`
    busy : dict
        Seconds each step that ran was busy (over threads), by step index;
        reading counts for the first.
    route : str
        How it ran, for provenance.
    """
    result, stats = execute(source, [k for _, k in plan.kernels],
                            None if plan.consumer is None else plan.consumer[1],
                            options=options, progress=progress)
    busy = {p.index: t for (p, _), t in zip(plan.kernels, stats.kernels, strict=True)}
    if plan.consumer is not None:
        busy[plan.consumer[0].index] = stats.consumer
    ran = [p.index for p in plan.members if p.index not in plan.skipped]
    busy[ran[0]] += stats.read
    route = (f"executor pass of {len(ran)} step(s): {stats.bands} band(s) of rows "
             f"from {source.where} on {stats.threads} thread(s)")
    if stats.stages > 1:
        route += f", in {stats.stages} stages (an exposure made for a whole-exposure estimate)"
    return result, busy, route
