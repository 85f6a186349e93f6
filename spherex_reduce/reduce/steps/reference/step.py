"""Reference correction: remove each channel's offset (paper §2.4, §4.3, §5.4).

The ``correct_reference`` step's kernel (`ReferenceKernel`) subtracts the
offsets a strategy (`spherex_reduce.reduce.steps.reference.strategies`) estimates,
flags channels without any, and records what it subtracted in the table
``REFOFFS`` (one row per frame, channel and parity), for every strategy
alike, a plugin's too.
"""

import dataclasses
import warnings

import numpy as np
from astropy.table import Table

from ....core import dq
from ....io.sources import MemorySource
from ...executor import execute
from ...hookspecs import hookimpl
from ...noise_effect import NoiseEffect
from ...plugins import default_registry
from ...step import Kernel, Record, Step, Strategy
from .strategies import (
    AcnReference,
    MeanReference,
    MedianReference,
    NoReferenceWarning,
    ReferenceOffsets,
    group_columns,
)
from .strategy_checks import StrategyOrigin, check_corrected, check_estimate
from .wiener import WienerReference

__all__ = [
    "CorrectReferenceStep",
    "ReferenceKernel",
    "ReferencePlan",
    "apply_offsets",
    "correct_reference",
    "missing_columns",
    "offsets_table",
]


@dataclasses.dataclass(frozen=True)
class ReferencePlan:
    """How `ReferenceKernel` subtracts a strategy's estimate from any block: its coefficients.

    `ReferenceKernel.prepare` makes it from the side block; ``apply``,
    ``apply_side`` and ``record`` read it, from several threads at once.
    ``L`` is the number of frames (1 for an image), ``P`` that of parity
    groups per channel (1, or 2 for even and odd samples).

    Attributes
    ----------
    estimate : `~spherex_reduce.reduce.steps.reference.strategies.ReferenceOffsets`
        The strategy's estimate (its parities, pixel counts and tables are
        recorded).
    offsets : `numpy.ndarray`
        ``(L, nchannels, P)`` float64 offsets; NaN where a group has none.
    missing : `numpy.ndarray`
        ``(L, nchannels, P)`` bool: the groups without an offset (left
        uncorrected, flagged).
    columns : `numpy.ndarray`
        ``(L, ncols)`` float64: the offset of every column (0 where missing).
    columns_missing : `numpy.ndarray` or None
        ``(L, ncols)`` bool: the columns of the missing groups, flagged
        `~spherex_reduce.core.dq.NO_REFERENCE`; None when no group is missing.
    rows_readout : `numpy.ndarray` or None
        ``(L, n_reads, nchannels * P)`` float64: an offset for every read (0
        where missing), subtracted instead of ``columns``, when the strategy
        estimates one (``ReferenceOffsets.rows``); else None.
    rows_physical : `numpy.ndarray` or None
        ``(L, nrows, nchannels * P)``: ``rows_readout`` per physical row (the
        mean over the row's reads) when the blocks are in physical order;
        else None.
    column_group : `numpy.ndarray` or None
        ``(ncols,)``: the group (``channel * P + parity``) of every column,
        given with ``rows_readout``.
    cycle : `numpy.ndarray` or None
        ``(nchannels, P)``: when every channel's columns cycle through ``P`` groups
        (``P`` = 1: one group per channel, its columns side by side; 2: ``acn``'s
        even and odd samples), the group of each place in the cycle; per-read
        offsets are then subtracted by broadcasting over the cycles, without a
        gathered row of offsets per pixel.  Else None (``column_group`` is used).
    """

    estimate: ReferenceOffsets
    offsets: np.ndarray
    missing: np.ndarray
    columns: np.ndarray
    columns_missing: np.ndarray | None = None
    rows_readout: np.ndarray | None = None
    rows_physical: np.ndarray | None = None
    column_group: np.ndarray | None = None
    cycle: np.ndarray | None = None

    def rows(self, order):
        """The per-read offsets for blocks in ``order`` (``'readout'`` or ``'physical'``),
        or None (one offset per group: ``columns``)."""
        if self.rows_readout is None:
            return None
        return self.rows_physical if order == "physical" else self.rows_readout


class ReferenceKernel(Kernel):
    """`correct_reference` on a block: minus each (frame, channel, parity) offset.

    Parameters
    ----------
    context : `~spherex_reduce.core.block.Context`
    strategy : `~spherex_reduce.Strategy`
        A configured strategy with an ``estimate`` method.
    origin : `~spherex_reduce.reduce.steps.reference.strategy_checks.StrategyOrigin`, optional
        The strategy and its plugin, named when its estimate fails the checks
        (`~spherex_reduce.reduce.steps.reference.strategy_checks.check_estimate`); default:
        this package's.
    """

    def __init__(self, context, strategy, origin=None):
        super().__init__(context)
        self.strategy = strategy
        self.origin = origin or StrategyOrigin(strategy.kind, strategy.name)
        self.needs_exposure = bool(strategy.needs_exposure)
        #: the strategy estimates from the phantom values, which it then consumes (a later
        #: ``subtract_phantom`` is skipped, as after that step)
        self.consumes_phantom = bool(strategy.uses_phantom(context))

    @property
    def output(self):
        return self.context.replace(has_phantom=False) if self.consumes_phantom else self.context

    def prepare(self, side, exposure=None):
        """The strategy's estimate from ``side`` (or ``exposure``), as a `ReferencePlan`."""
        est = self.strategy.estimate(side, self.context, exposure)
        est = check_estimate(est, self.context, side.data.shape[0], self.origin)
        return _plan(self.context, est,
                     self.strategy.name)

    def apply(self, plan, block):
        # float64, the fit's precision: float32 would round each corrected read to its
        # spacing at the pixel's level (1e-3 ADU at 1e4), a bias of the slopes
        out = block.writable(np.float64)
        rows = plan.rows(block.order)
        nch = self.context.geometry.nchannels
        for f in range(out.shape[0]):
            if rows is None:
                np.subtract(out[f], plan.columns[f], out=out[f])
            elif plan.cycle is not None:  # each channel's columns cycle through its groups
                per_cycle = out[f].reshape(out.shape[1], nch, -1, plan.cycle.shape[1])
                np.subtract(per_cycle, rows[f][block.index][:, plan.cycle][:, :, None, :],
                            out=per_cycle, casting="unsafe")
            else:  # an offset per read: the row's own
                np.subtract(out[f], rows[f][block.index][:, plan.column_group], out=out[f],
                            casting="unsafe")
        block = block.replace(data=out, owned=block.owned | {"data"})
        if plan.columns_missing is not None:
            flags = np.where(plan.columns_missing[:, None, :], np.uint32(dq.NO_REFERENCE),
                             np.uint32(0))
            block = block.with_flags(flags)
        if self.consumes_phantom:
            block = block.replace(phantom=None, read_phantom=None)
        return block

    def apply_side(self, plan, side):
        if not (self.context.order == "physical" and side.order == "readout"):
            return self.apply(plan, side)  # the side block is part of the pixels
        # the reference reads kept aside: minus the offsets in float64
        rd = side.data
        rows = plan.rows("readout")
        sub = (plan.columns[:, None, :] if rows is None
               else rows[:, side.index][..., plan.column_group])
        data = np.subtract(rd, sub, dtype=np.float64)
        side = side.replace(data=data, owned=side.owned | {"data"})
        if self.consumes_phantom:
            side = side.replace(phantom=None, read_phantom=None)
        return side

    def record(self, plan):
        est = plan.estimate
        found = est.telegraph
        table = offsets_table(plan.offsets, plan.missing, est.parity, est.n_used,
                              est.n_clipped, self.strategy.name, self.context.unit,
                              ramp=self.context.ramp,
                              n_telegraph=None if found is None else found.count)
        tables = {"REFOFFS": table, **est.tables}
        cards = [("REFSTRAT", self.strategy.name, "reference correction strategy"),
                 ("NNOREF", int(plan.missing.sum()), "offsets without usable reference pixels")]
        if found is not None:
            tables["REFTELEG"] = found.table()
            cards.append(("NTELEG", int(found.count.sum()),
                          "telegraph reference pixels left out"))
        if self.consumes_phantom:
            cards.append(("REFPHANT", True, "the strategy estimated from the phantom values"))
        return Record(tables, cards)


def _plan(context, est, name):
    """The `ReferencePlan` of estimate ``est`` for blocks of ``context``."""
    geometry = context.geometry
    offsets, missing, columns = _column_plan(geometry, est.offsets, name, est.acn)
    columns_missing = missing_columns(geometry, missing, est.acn) if missing.any() else None
    plan = ReferencePlan(est, offsets, missing, columns, columns_missing)
    if est.rows is not None:
        plan = _row_plan(context, est, plan)
    return plan


def _row_plan(context, est, plan):
    """``plan`` with the per-read offsets ``(L, n_reads, groups)`` (0 where missing), the
    group of every column, and the same per physical row (the mean over the row's reads)
    when the blocks are in physical order."""
    s = context.schedule
    groups = group_columns(s.geometry, est.acn)  # (nch, P, k)
    colgroup = np.zeros(s.geometry.ncols, dtype=np.intp)
    for ch in range(groups.shape[0]):
        for p in range(groups.shape[1]):
            cols = groups[ch, p][groups[ch, p] >= 0]
            colgroup[cols] = ch * groups.shape[1] + p
    rows = np.asarray(est.rows, dtype=np.float64)  # the estimate's own array when float64:
    rows = np.nan_to_num(rows, copy=False, nan=0.0, posinf=0.0, neginf=0.0)  # no copy held
    rows = rows.reshape(rows.shape[0], rows.shape[1], -1)
    width = s.geometry.channel_width
    cycle = None
    for period in (1, 2):  # one group per channel, or acn's even and odd
        if width % period == 0:
            by_place = colgroup.reshape(groups.shape[0], width // period, period)
            if (by_place == by_place[:, :1]).all():
                cycle = by_place[:, 0]
                break
    phys = None
    if context.order == "physical":
        nrows = s.geometry.nrows
        counts = np.bincount(s.rows, minlength=nrows)
        phys = np.zeros((rows.shape[0], nrows, rows.shape[2]))
        phys[:, s.rows] = rows  # a row read once: its read's offset
        for row in np.flatnonzero(counts > 1):  # a row read more: the mean of its reads'
            phys[:, row] = rows[:, s.rows == row].mean(axis=1)
    return dataclasses.replace(plan, rows_readout=rows, rows_physical=phys,
                               column_group=colgroup, cycle=cycle)


class _Given(Strategy):
    """A strategy whose offsets are given (`apply_offsets`)."""

    def __init__(self, estimate, name):
        super().__init__()
        self.estimate_, self.name = estimate, name

    def estimate(self, side, context, exposure=None):
        return self.estimate_


def apply_offsets(exposure, offsets, parity, n_used, n_clipped, strategy):
    """Subtract per-(frame, channel, parity) offsets and record them in ``REFOFFS``.

    Groups whose offset is NaN are left uncorrected, flagged in the table and
    the mask (`~spherex_reduce.core.dq.NO_REFERENCE`), and reported with a
    `~spherex_reduce.reduce.steps.reference.strategies.NoReferenceWarning`.
    This is the ``correct_reference`` kernel applied with offsets given
    instead of estimated: for a whole-exposure strategy (``__call__``) that
    computes its offsets itself.

    Parameters
    ----------
    exposure : `~spherex_reduce.Exposure`
    offsets, n_used, n_clipped : array_like
        Shape ``(L, nchannels, P)`` (``L`` frames, or 1 for an image).
    parity : sequence of int
        Parity label of each of the ``P`` groups: ``-1`` all columns, ``0``
        even samples, ``1`` odd samples.
    strategy : str
        Name recorded in the header (``REFSTRAT``); the groups are even and odd
        samples when ``parity`` has two entries.

    Returns
    -------
    `~spherex_reduce.Exposure`
    """
    off = np.asarray(offsets, dtype=np.float64)
    est = ReferenceOffsets(off, np.asarray(n_used), np.asarray(n_clipped), list(parity))
    source = MemorySource(exposure)
    kernel = ReferenceKernel(source.context, _Given(est, strategy))
    return execute(source, [kernel])[0]


def _column_plan(geometry, offsets, strategy, acn):
    """Offsets (float64), the groups without one (warned about), and per-column offsets.

    Returns ``offsets, missing, col``; ``col`` ``(L, ncols)`` has 0 where the
    offset is missing (those channels are left uncorrected).
    """
    offsets = np.asarray(offsets, dtype=np.float64)
    missing = ~np.isfinite(offsets)
    if missing.any():
        chans = sorted({int(c) for c in np.nonzero(missing)[1]})
        warnings.warn(
            f"correct_reference ({strategy}): no usable reference pixels for channel(s) "
            f"{chans}; offset NaN, flagged NO_REFERENCE, those channels left uncorrected",
            NoReferenceWarning, stacklevel=4)
    groups = group_columns(geometry, acn)
    return offsets, missing, _column_offsets(np.where(missing, 0.0, offsets), groups,
                                             geometry.ncols)


def _column_offsets(offsets, groups, ncols):
    """Per-column offsets ``(L, ncols)`` from per-group offsets ``(L, nch, P)``."""
    col = np.zeros((offsets.shape[0], ncols))
    for ch in range(groups.shape[0]):
        for p in range(groups.shape[1]):
            cols = groups[ch, p][groups[ch, p] >= 0]
            col[:, cols] = offsets[:, ch, p][:, None]
    return col


def missing_columns(geometry, missing, acn):
    """Columns ``(L, ncols)`` of the (frame, channel, parity) groups flagged ``missing``."""
    groups = group_columns(geometry, acn)
    return _column_offsets(missing.astype(float), groups, geometry.ncols) > 0


def offsets_table(offsets, missing, parity, n_used, n_clipped, strategy, unit, ramp,
                  n_telegraph=None):
    """The ``REFOFFS`` table of offsets ``(L, nchannels, P)`` (see `correct_reference`);
    ``n_telegraph`` ``(nchannels,)``: the telegraph reference pixels left out per channel
    (a column when given)."""
    L, nch, P = offsets.shape
    fr, ch, pa = np.meshgrid(np.arange(L), np.arange(nch), np.arange(P), indexing="ij")
    cols = {}
    if ramp:
        cols["frame"] = fr.ravel()
    cols["channel"] = ch.ravel()
    cols["parity"] = np.asarray(parity)[pa.ravel()]
    cols["offset"] = offsets.ravel()
    cols["n_used"] = np.asarray(n_used).ravel()
    cols["n_clipped"] = np.asarray(n_clipped).ravel()
    cols["flag"] = np.where(missing.ravel(), dq.NO_REFERENCE, 0).astype(np.uint32)
    if n_telegraph is not None:
        cols["n_telegraph"] = np.asarray(n_telegraph, dtype=np.int64)[ch.ravel()]
    table = Table(cols, meta={"strategy": strategy})
    table["offset"].unit = unit  # (the writer puts a unit FITS lacks in TUNIT as text)
    table["offset"].description = "offset subtracted"
    return table


def correct_reference(exposure, strategy="mean", *, registry=None, **params):
    """Remove each channel's offset with a reference-correction strategy.

    Parameters
    ----------
    exposure : `~spherex_reduce.Exposure`
        Ramps (offsets per frame) or a 2-D image (e.g. slopes from
        `fit_ramp`), in readout or physical order.
    strategy : str
        ``'mean'`` (paper's default: one σ-clipped mean of the reference
        pixels per channel), ``'acn'`` (even/odd samples), ``'median'``
        (median of all pixels per channel, §5.4), ``'wiener'`` (each
        channel's drift at every row read, the kriging estimate from its
        reference reads and phantom values,
        `~spherex_reduce.reduce.steps.reference.wiener.WienerReference`), or any strategy of
        kind ``'reference'`` a plugin registers.
    registry : `~spherex_reduce.reduce.plugins.Registry`, optional
        Where to look strategies up, and whose ``before_step`` and
        ``after_step`` hooks to call (default: no hooks, the strategies of
        the built-in and installed plugins,
        `~spherex_reduce.reduce.plugins.default_registry`).
    **params
        The strategy's parameters (``sigma``, ``maxiters``, ``side_columns``
        for ``mean``/``acn``; ``mask_sources`` ... for ``median``; ``noise``,
        ``domain`` ... for ``wiener``).

    Returns
    -------
    `~spherex_reduce.Exposure`
        Corrected copy with the table ``REFOFFS``: ``frame`` (ramps only),
        ``channel``, ``parity`` (-1 all, 0 even, 1 odd samples), ``offset``
        (in the data unit, the column's unit), ``n_used``,
        ``n_clipped`` and ``flag``
        (`~spherex_reduce.core.dq.NO_REFERENCE` when the channel had no usable
        reference pixel: offset NaN, channel left uncorrected, a
        `~spherex_reduce.reduce.steps.reference.strategies.NoReferenceWarning`),
        and with ``telegraph: auto`` (``mean``, ``acn``, ``wiener``)
        ``n_telegraph``, the channel's telegraph reference pixels left out (also
        the keyword ``NTELEG``, the total, and the table ``REFTELEG`` listing
        them; `~spherex_reduce.reduce.steps.reference.telegraph`).

    Raises
    ------
    `~spherex_reduce.reduce.steps.reference.strategies.NoReferenceError`
        The exposure has no reference rows (``mean``, ``acn``).

    Examples
    --------
    >>> import numpy as np
    >>> from spherex_reduce import DetectorGeometry, Exposure, ReadoutSchedule
    >>> from spherex_reduce import correct_reference
    >>> s = ReadoutSchedule(DetectorGeometry(8, 8, 2, ref_border=1), skip=1, ref_mode="none",
    ...                     phantom_reads=0, nframes=1)
    >>> img = np.ones((8, 8)) * np.repeat([10.0, -3.0], 4)   # channel offsets
    >>> out = correct_reference(Exposure.from_arrays(img, s), "mean")
    >>> np.abs(out.data.data).max(), out.tables["REFOFFS"]["offset"].tolist()
    (np.float64(0.0), [10.0, -3.0])
    """
    return CorrectReferenceStep(registry)(exposure, strategy=strategy, **params)


def _streams(cls):
    """Whether a strategy class estimates (a kernel applies its offsets), or is an older
    whole-exposure strategy (``__call__(exposure, **params)`` only)."""
    return cls.estimate is not Strategy.estimate


class CorrectReferenceStep(Step):
    """Remove channel offsets with a reference strategy (`~spherex_reduce.correct_reference`)."""

    name, keyword = "correct_reference", "S_REFCOR"
    strategy_kind, default_strategy = "reference", "mean"
    #: the strategy decides (its own ``noise_effect``; one without is not forecast)
    noise_effect = NoiseEffect("reference")

    def strategy_registry(self):
        """Its registry or its strategies, else the built-in and installed plugins'
        (`~spherex_reduce.reduce.plugins.default_registry`): the step made alone knows
        every reference strategy."""
        found = super().strategy_registry()
        return default_registry() if found is None else found

    def origin(self, strategy):
        """The `~spherex_reduce.reduce.steps.reference.strategy_checks.StrategyOrigin` of strategy
        ``strategy``: its name and the plugin that registers it."""
        found = self.strategy_registry().strategies[self.strategy_kind][strategy]
        return StrategyOrigin(self.strategy_kind, strategy, found.plugin)

    def kernel(self, context, strategy, **params):
        cls = self.strategy(strategy)
        if not _streams(cls):
            return None
        return ReferenceKernel(context, cls(**params), self.origin(strategy))

    def run(self, exposure, strategy, **params):
        cls = self.strategy(strategy)
        if not _streams(cls):  # a strategy written before kernels: on the whole exposure
            return check_corrected(cls()(exposure, **params), exposure, self.origin(strategy))
        return super().run(exposure, strategy=strategy, **params)


@hookimpl
def register_steps():
    return [CorrectReferenceStep]


@hookimpl
def register_strategies():
    return [MeanReference, AcnReference, MedianReference, WienerReference]
