"""Hook specifications: what a ``spherex_reduce`` plugin may implement.

A plugin is a module or object with functions decorated by :data:`hookimpl`,
exposed through the entry-point group ``spherex_reduce``::

    # pyproject.toml of the plugin package
    [project.entry-points.spherex_reduce]
    myplugin = "my_package.plugin"

Registration hooks return lists of classes; the run hooks are called around
every step run by a pipeline, or called alone with a registry
(``Step(registry)(exposure)``).  Step **order** comes from the pipeline's YAML
file, never from hook order.
"""

import pluggy

__all__ = ["hookimpl", "hookspec"]

PROJECT = "spherex_reduce"

hookspec = pluggy.HookspecMarker(PROJECT)
#: Decorator marking a plugin's implementation of a hook.
hookimpl = pluggy.HookimplMarker(PROJECT)


@hookspec
def register_steps():
    """Return a list of `~spherex_reduce.Step` subclasses this plugin provides."""


@hookspec
def register_strategies():
    """Return a list of `~spherex_reduce.Strategy` subclasses (each names its ``kind``)."""


@hookspec
def register_simulators():
    """Return a list of `~spherex_reduce.Simulator` subclasses."""


@hookspec
def before_step(step, exposure, params):
    """Called before a step runs, with the validated parameters (a dict).

    ``exposure`` is the step's input, or None when the step runs in an
    executor pass over a file (its pixels are never whole in memory).  For the
    steps of one pass, every ``before_step`` comes before the pass and every
    ``after_step`` after it, in YAML order.
    """


@hookspec
def after_step(step, exposure, result, params, status, reason, elapsed):
    """Called after a step ran.

    ``status`` is ``'COMPLETE'`` or ``'SKIPPED'`` (then ``reason`` says why;
    for a step run alone ``result is exposure``).  ``elapsed`` is in seconds:
    the wall time of a step run alone; in an executor pass, the time its
    kernel or consumer was busy, summed over threads (reading the file counts
    for the first step), and ``result`` is the pass's result.  Return a list
    of header cards ``(keyword, value, comment)`` to record in the result's
    header (``'HISTORY'`` cards may repeat), or None.
    """
