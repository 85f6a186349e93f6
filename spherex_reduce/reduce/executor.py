"""The executor: step kernels over bands of rows, into a consumer or a new exposure.

Every correction of the paper that works row by row (``unchop``,
``subtract_phantom``, ``correct_reference``) is a `~spherex_reduce.reduce.step.Kernel`
of its step, and ``fit_ramp`` is a `~spherex_reduce.reduce.step.Consumer` of bands.
`execute` runs a chain of kernels:

1. the *side block* (`~spherex_reduce.io.sources.side_block`: the reads of the
   reference rows of every frame, with their phantom values, a small part of
   the ramp) goes through the kernels' ``prepare`` (e.g. each frame's
   reference offsets) and ``apply_side``;
2. the input (a source of `spherex_reduce.io.sources`) is cut into bands of
   rows of every frame (read from a file with ``pread`` by
   `~spherex_reduce.io.FrameReader`, or views of an in-memory exposure); each
   band goes through every kernel's ``apply`` in YAML order and then to the
   consumer, or into the output arrays; bands run on the threads of the
   `~spherex_reduce.reduce.options.RunOptions`;
3. the kernels' ``record`` gives the tables and header cards, and `RunStats`
   what the pass took.

A step run alone (``Step.run``) is `execute` on the exposure in memory
(`~spherex_reduce.io.sources.MemorySource`), so the numbers of a streamed
reduction and of the steps run one by one agree bit for bit: each pixel's
arithmetic does not depend on the band that holds it.

It imports no step, so that the steps can run themselves through it.
"""

import threading
import time
from dataclasses import dataclass

import numpy as np

from ..core.exposure import Exposure, ReferenceReads, expected_shape
from .options import RunOptions, in_threads

__all__ = ["RunStats", "execute", "first_in_memory"]

#: pixels per band of a file (all frames together): 74 frames x 2**17 x 4 B = 39 MB per
#: band and thread, so memory stays near the output
BAND_PIXELS = 1 << 17
#: in memory a band is a view, so bands twice as large cost nothing and fit ~5 % faster
MEMORY_BAND_FACTOR = 2


@dataclass(frozen=True)
class RunStats:
    """What a pass of the executor took.

    Attributes
    ----------
    kernels : tuple of float
        Seconds spent in each kernel, in order, summed over threads.
    consumer : float
        Seconds in the consumer (or assembling the output).
    read : float
        Seconds reading the source.
    bands : int
        Bands of rows the input was cut into.
    threads : int
        Threads the bands ran on.
    """

    kernels: tuple
    consumer: float
    read: float
    bands: int
    threads: int


def first_in_memory(kernel, position, source):
    """Whether ``kernel`` can run at ``position`` of a pass over ``source``: a kernel whose
    estimate needs the whole exposure (``needs_exposure``) must be the first of a pass
    over an exposure in memory, or its estimate would see the pixels before the kernels
    ahead of it."""
    return not kernel.needs_exposure or (position == 0 and source.in_memory)


def bands(nrows, rows_per_band):
    """``(lo, hi)`` of consecutive bands covering ``nrows`` rows."""
    step = max(1, int(rows_per_band))
    return [(lo, min(nrows, lo + step)) for lo in range(0, nrows, step)]


class _Assembly:
    """The output arrays of a chain of kernels with no consumer: bands written in place."""

    def __init__(self, context):
        self.nrows = expected_shape(context.schedule, context.order, False)[0]
        self.order = context.order
        self._arrays = {}
        self._lock = threading.Lock()

    def _array(self, name, like):
        with self._lock:
            out = self._arrays.get(name)
            if out is None:
                shape = (like.shape[0], self.nrows, like.shape[-1])
                fill = 0 if like.dtype.kind in "ui" else np.nan
                out = self._arrays[name] = np.full(shape, fill, like.dtype)
        return out

    def band(self, block):
        for name in ("data", "phantom", "dq", "uncertainty"):
            values = getattr(block, name)
            if values is not None:
                self._array(name, values)[:, block.index] = values

    def get(self, name, ramp):
        values = self._arrays.get(name)
        if values is None or ramp:
            return values
        return values[0]


def execute(source, kernels, consumer=None, *, options=None, rows_per_band=None,
            progress=None):
    """Run ``kernels`` over bands of ``source``, into ``consumer`` or a new exposure.

    Parameters
    ----------
    source : `~spherex_reduce.io.sources.Source`
        Where bands come from (``side()``, ``read(lo, hi)``, ``context``,
        ``header``, ``tables``, ``reference``, ``nrows``).
    kernels : list of `~spherex_reduce.reduce.step.Kernel`
        In the order they run (each made for the previous one's output context).
    consumer : `~spherex_reduce.reduce.step.Consumer`, optional
        Takes the corrected bands (``fit_ramp``); else they are assembled into
        an exposure like the input.
    options : `~spherex_reduce.reduce.options.RunOptions`, optional
        Its ``threads``: bands corrected at once (default
        `~spherex_reduce.reduce.options.default_threads`).
    rows_per_band : int, optional
        Rows of every frame per band (default: `BAND_PIXELS` pixels of every
        frame from a file, `MEMORY_BAND_FACTOR` times more in memory).
    progress : callable, optional
        Called with the number of rows done after each band.

    Returns
    -------
    result : `~spherex_reduce.Exposure`
    stats : `RunStats`
        The seconds spent in each kernel, the consumer and reading, the bands
        and threads.
    """
    chain = _Chain(kernels, consumer)
    side = chain.prepare(source)
    if rows_per_band is None:
        pixels = BAND_PIXELS * (MEMORY_BAND_FACTOR if source.in_memory else 1)
        rows_per_band = max(1, pixels // source.context.geometry.ncols)
    cuts = bands(source.nrows, rows_per_band)
    nthreads = (options or RunOptions()).thread_count()
    _run_bands(cuts, lambda lo, hi: chain.run(chain.read(source, lo, hi)), nthreads, progress)
    for i, (kernel, c) in enumerate(zip(kernels, chain.coefficients, strict=True)):
        extra = kernel.extra_rows(c)
        if extra is not None:
            chain.run(extra, i + 1)
    result = chain.finish(source, side)
    return result, RunStats(kernels=tuple(chain.busy[:len(kernels)]),
                            consumer=chain.busy[len(kernels)], read=chain.busy[-1],
                            bands=len(cuts), threads=nthreads)


def _run_bands(cuts, run, nthreads, progress):
    """``run(lo, hi)`` for every band, on ``nthreads`` threads; ``progress`` after each."""
    bands = in_threads(cuts, lambda cut: run(*cut), nthreads, name="spherex-reduce-band")
    for (lo, hi), _ in zip(cuts, bands, strict=True):
        if progress is not None:
            progress(hi - lo)


class _Chain:
    """The kernels of a pass with their coefficients, where bands end (the consumer or the
    output arrays), and the seconds spent in each (``busy``: kernels, the consumer or the
    assembly, reading; summed over threads)."""

    def __init__(self, kernels, consumer):
        self.kernels, self.consumer = kernels, consumer
        self.coefficients = []
        self.busy = [0.0] * (len(kernels) + 2)
        self._lock = threading.Lock()
        self.sink = None

    def _spent(self, i, t0):
        t1 = time.perf_counter()
        with self._lock:
            self.busy[i] += t1 - t0
        return t1

    def prepare(self, source):
        """Each kernel's coefficients from the side block; the side block they leave."""
        t = time.perf_counter()
        side = source.side()
        t = self._spent(-1, t)
        for i, kernel in enumerate(self.kernels):
            if not first_in_memory(kernel, i, source):
                raise ValueError(f"{type(kernel).__name__} needs the whole exposure in "
                                 "memory, as the first kernel of a pass")
            if kernel.needs_exposure:
                c = kernel.prepare(side, source.exposure())
            else:
                c = kernel.prepare(side)
            side = kernel.apply_side(c, side)
            self.coefficients.append(c)
            t = self._spent(i, t)
        self.output = self.kernels[-1].output if self.kernels else source.context
        self.sink = self.consumer if self.consumer is not None else _Assembly(self.output)
        return side

    def read(self, source, lo, hi):
        t = time.perf_counter()
        block = source.read(lo, hi)
        self._spent(-1, t)
        return block

    def run(self, block, start=0):
        """A block through the kernels from ``start`` on, into the sink."""
        t = time.perf_counter()
        for i in range(start, len(self.kernels)):
            block = self.kernels[i].apply(self.coefficients[i], block)
            t = self._spent(i, t)
        self.sink.band(block)
        self._spent(len(self.kernels), t)

    def finish(self, source, side):
        """The result: the kernels' records in the header and tables, then the consumer's
        image or the assembled exposure."""
        header = source.header.copy()
        tables = dict(source.tables)
        for kernel, c in zip(self.kernels, self.coefficients, strict=True):
            record = kernel.record(c)
            tables.update(record.tables)
            for key, value, comment in record.cards:
                header[key] = (value, comment)
        reference = reference_after(source.reference, side, self.output)
        t = time.perf_counter()
        if self.consumer is not None:
            result = self.consumer.finish(reference, header, tables)
        else:
            result = _exposure(self.sink, reference, header, tables, self.output)
        self._spent(len(self.kernels), t)
        return result


def reference_after(reference, side, after):
    """The reference reads kept aside after the kernels: the side block once the rows are in
    physical order (un-chopped here, or before), else the input's."""
    if after.order != "physical" or side.order != "readout":
        return reference
    s = after.schedule
    ref_idx = s.reference_read_indices
    keep = np.isin(side.index, ref_idx)
    ramp = after.ramp

    def sel(values):
        if values is None:
            return None
        values = values[:, keep] if not keep.all() else values
        return values if ramp else values[0]

    return ReferenceReads(data=sel(side.data), rows=s.rows[side.index[keep]],
                          reads=side.index[keep], phantom=sel(side.phantom), dq=sel(side.dq))


def _exposure(sink, reference, header, tables, context):
    """The assembled output as an `~spherex_reduce.Exposure`."""
    ramp = context.ramp
    return Exposure.from_arrays(sink.get("data", ramp), context.schedule, unit=context.unit,
                                uncertainty=sink.get("uncertainty", ramp),
                                mask=sink.get("dq", ramp), phantom=sink.get("phantom", ramp),
                                header=header, order=sink.order, reference=reference,
                                tables=tables)
