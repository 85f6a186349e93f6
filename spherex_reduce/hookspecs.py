"""Hook specifications: what a ``spherex_reduce`` plugin may implement.

A plugin is a module or object with functions decorated by :data:`hookimpl`,
exposed through the entry-point group ``spherex_reduce``::

    # pyproject.toml of the plugin package
    [project.entry-points.spherex_reduce]
    myplugin = "my_package.plugin"

Registration hooks return lists of classes; the run hooks are called around
every step the pipeline runs.  Step **order** comes from the pipeline's YAML
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
    """Called before a step runs, with the validated parameters (a dict)."""


@hookspec
def after_step(step, exposure, result, params, status, reason, elapsed):
    """Called after a step ran.

    ``status`` is ``'COMPLETE'`` or ``'SKIPPED'`` (then ``reason`` says why and
    ``result is exposure``); ``elapsed`` is the wall time in seconds.  Return
    a list of header cards ``(keyword, value, comment)`` to record in the
    result's header (``'HISTORY'`` cards may repeat), or None.
    """
