"""What a reference strategy returns, checked before anything uses it.

A strategy may come from a plugin.  Its result is checked here, in one place
for every route (``spherex-reduce reduce``, ``compare-strategies``, a sweep,
`~spherex_reduce.correct_reference` called alone): an estimate
(`check_estimate`) must be a
`~spherex_reduce.reduce.steps.reference.strategies.ReferenceOffsets` whose
arrays have the shapes of the data it corrects (never broadcast), and a
whole-exposure strategy's result (`check_corrected`) an
`~spherex_reduce.Exposure` of its input's shape.  A result that fails is a
`~spherex_reduce.core.errors.PluginError` naming the plugin and the strategy
(exit code 2 on the command line: a fault of the plugin, not of the input nor
of this package); a built-in strategy's is a bug of this package
(`RuntimeError`).
"""

from dataclasses import dataclass

import numpy as np

from ....core.errors import PluginError
from ....core.exposure import Exposure
from ...plugins import BLOCK_ENV, BUILTIN_PLUGINS, describe_plugin
from .strategies import ALL, EVEN, ODD, ReferenceOffsets

__all__ = ["StrategyOrigin", "check_corrected", "check_estimate"]


@dataclass(frozen=True)
class StrategyOrigin:
    """A strategy and the plugin that registered it, for messages.

    Parameters
    ----------
    kind, name : str
        The strategy's kind and name (``'reference'``, ``'mean'``).
    plugin : str or None
        The registering plugin's name; None or a built-in plugin: this package.

    Examples
    --------
    >>> from spherex_reduce.reduce.steps.reference.strategy_checks import StrategyOrigin
    >>> str(StrategyOrigin("reference", "mean", "builtin.reference"))
    "reference strategy 'mean' of plugin 'builtin.reference'"
    """

    kind: str
    name: str
    plugin: str | None = None

    @property
    def builtin(self):
        return self.plugin is None or self.plugin in BUILTIN_PLUGINS

    def __str__(self):
        where = describe_plugin(self.plugin) if self.plugin else "this package"
        return f"{self.kind} strategy {self.name!r} of {where}"

    def fault(self, what):
        """The error for a result that fails a check: `PluginError` for a plugin's strategy,
        `RuntimeError` (a bug) for a built-in one."""
        text = f"{self} returned {what}"
        if self.builtin:
            return RuntimeError(text)
        return PluginError(f"{text}. Report it to the plugin's authors, or block it with "
                           f"{BLOCK_ENV}={self.plugin}")


def _what(value):
    """A short description of a returned value."""
    if value is None:
        return "None"
    shape = getattr(value, "shape", None)
    return f"a {type(value).__name__}" + (f" of shape {tuple(shape)}" if shape is not None
                                          else "")


def _numbers(value, name, shape, origin):
    """``value`` as a real array of ``shape`` (no broadcasting), else ``origin.fault``."""
    try:
        arr = np.asarray(value)
    except Exception:  # an object numpy cannot hold: described below
        arr = None
    if arr is None or arr.dtype.kind not in "biuf":
        raise origin.fault(f"{name} of {_what(value)} (dtype "
                           f"{getattr(arr, 'dtype', '?')}); expected real numbers")
    if arr.shape != shape:
        raise origin.fault(f"{name} of shape {arr.shape}; expected {shape}")
    return arr


def check_estimate(est, context, nframes, origin):
    """Check a strategy's estimate for blocks of ``context``; returns it unchanged.

    Parameters
    ----------
    est : object
        What `Strategy.estimate <spherex_reduce.Strategy.estimate>` returned.
    context : `~spherex_reduce.core.block.Context`
        What the offsets apply to (its geometry and schedule).
    nframes : int
        Frames of the data (``L``; 1 for an image).
    origin : `StrategyOrigin`

    Returns
    -------
    `~spherex_reduce.reduce.steps.reference.strategies.ReferenceOffsets`

    Raises
    ------
    PluginError
        A plugin's strategy returned something else, arrays of another shape
        than ``(L, nchannels, P)`` (``P`` groups of ``parity``: ``[-1]`` or
        ``[0, 1]``) or per-read offsets of another shape than ``(L, n_reads,
        nchannels, P)``, infinite offsets, or NaN offsets for every group
        although reference pixels were used.
    RuntimeError
        The same from a built-in strategy (a bug).

    Examples
    --------
    >>> import numpy as np
    >>> from spherex_reduce import ReadoutSchedule
    >>> from spherex_reduce.core.block import Context
    >>> from spherex_reduce.reduce.steps.reference.strategies import ReferenceOffsets
    >>> from spherex_reduce.reduce.steps.reference.strategy_checks import (
    ...     StrategyOrigin, check_estimate)
    >>> context = Context(ReadoutSchedule(), "readout", False)
    >>> wrong = ReferenceOffsets(np.zeros((1, 1, 1)), np.ones((1, 1, 1)), np.zeros((1, 1, 1)),
    ...                          [-1])
    >>> check_estimate(wrong, context, 1, StrategyOrigin("reference", "toy", "toy"))
    Traceback (most recent call last):
    ...
    spherex_reduce.core.errors.PluginError: reference strategy 'toy' of plugin 'toy' returned ...
    """
    if not isinstance(est, ReferenceOffsets):
        raise origin.fault(f"{_what(est)}, not ReferenceOffsets")
    parity = list(est.parity) if isinstance(est.parity, (list, tuple)) else None
    if parity not in ([ALL], [EVEN, ODD]):
        raise origin.fault(f"parity {est.parity!r}; expected [{ALL}] or [{EVEN}, {ODD}]")
    shape = (int(nframes), context.geometry.nchannels, len(parity))
    offsets = _numbers(est.offsets, "offsets", shape, origin)
    n_used = _numbers(est.n_used, "n_used", shape, origin)
    _numbers(est.n_clipped, "n_clipped", shape, origin)
    if np.isinf(offsets).any():
        raise origin.fault("infinite offsets")
    if np.isnan(offsets).all() and (n_used > 0).any():
        raise origin.fault(f"NaN offsets for every channel although it used "
                           f"{int(n_used.sum())} reference pixel values")
    if est.rows is not None:
        s = context.schedule
        _numbers(est.rows, "per-read offsets (rows)", (shape[0], s.n_reads, *shape[1:]),
                 origin)
    if not isinstance(est.tables, dict):
        raise origin.fault(f"tables of {_what(est.tables)}; expected a dict of tables")
    return est


def check_corrected(result, exposure, origin):
    """Check a whole-exposure strategy's result (``strategy(exposure)``); returns it.

    Parameters
    ----------
    result : object
        What the strategy returned.
    exposure : `~spherex_reduce.Exposure`
        Its input.
    origin : `StrategyOrigin`

    Returns
    -------
    `~spherex_reduce.Exposure`

    Raises
    ------
    PluginError
        A plugin's strategy returned something else than an exposure, one of
        another shape, or one with no finite pixel where its input had some.
    RuntimeError
        The same from a built-in strategy (a bug).

    Examples
    --------
    >>> from spherex_reduce.io.examples import example_raw_exposure
    >>> from spherex_reduce.reduce.steps.reference.strategy_checks import (
    ...     StrategyOrigin, check_corrected)
    >>> raw = example_raw_exposure()
    >>> check_corrected(raw.data.data, raw, StrategyOrigin("reference", "toy", "toy"))
    Traceback (most recent call last):
    ...
    spherex_reduce.core.errors.PluginError: ... returned a ndarray of shape (6, 64, 64), not an ...
    """
    if not isinstance(result, Exposure):
        raise origin.fault(f"{_what(result)}, not an Exposure")
    if result.shape != exposure.shape:
        raise origin.fault(f"an exposure of shape {result.shape}; its input has "
                           f"{exposure.shape}")
    data = np.asarray(result.data.data)
    if data.dtype.kind not in "biuf":
        raise origin.fault(f"an exposure of dtype {data.dtype}; expected real numbers")
    if data.dtype.kind == "f" and data.size and not np.isfinite(data).any() and np.isfinite(
            np.asarray(exposure.data.data)).any():
        raise origin.fault("an exposure without a finite pixel (all NaN or infinite); its "
                           "input has finite pixels")
    return result
