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
from ..io.sources import MemorySource
from .options import RunOptions, in_threads

__all__ = ["RunStats", "execute", "joins"]

#: pixels per band of a file (all frames together): 74 frames x 2**17 x 4 B = 39 MB per
#: band and thread, so memory stays near the output
BAND_PIXELS = 1 << 17
#: in memory a band is a view, so bands twice as large cost nothing and fit ~5 % faster
#: (unless there would then be fewer bands than threads: a 128 x 2048 strip is two bands)
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
    stages : int
        Runs over the bands: 1, or one more for each kernel after the first whose
        estimate needs the whole exposure (the bands before it made into an exposure
        first).
    """

    kernels: tuple
    consumer: float
    read: float
    bands: int
    threads: int
    stages: int = 1


def joins(kernel, position, source):
    """Whether ``kernel`` can run at ``position`` of a pass over ``source``.

    A kernel whose estimate needs the whole exposure (``needs_exposure``) can, except as
    the first of a pass over a file (its step then runs on the whole exposure): after
    other kernels, `execute` runs them over every band first, into an exposure of its
    own that the estimate sees and the kernels from it on then correct in place.
    """
    return not kernel.needs_exposure or position > 0 or source.in_memory


def bands(nrows, rows_per_band):
    """``(lo, hi)`` of consecutive bands covering ``nrows`` rows."""
    step = max(1, int(rows_per_band))
    return [(lo, min(nrows, lo + step)) for lo in range(0, nrows, step)]


class _Assembly:
    """The output arrays of a chain of kernels with no consumer: bands written in place.

    The arrays are made empty (no page is touched until a band writes it, on the thread
    that works on it: a full-size exposure filled first took a third of a pass, on one
    thread under the lock); the rows of an array no band wrote (a band without that
    array, e.g. flags only on the rows never read) are filled when it is taken: NaN, or 0
    for integers.  ``into`` (arrays by name, ``(frames, rows, columns)``): the arrays of
    the exposure the bands were read from, the executor's own, taken as the output where
    shape and type agree; a band that is their rows, corrected in place, is then not
    copied.
    """

    def __init__(self, context, into=None):
        self.nrows = expected_shape(context.schedule, context.order, False)[0]
        self.order = context.order
        self._into = into or {}
        self._arrays = {}
        self._written = {}  # name -> rows written
        self._lock = threading.Lock()

    def _array(self, name, like):
        with self._lock:
            out = self._arrays.get(name)
            if out is None:
                shape = (like.shape[0], self.nrows, like.shape[-1])
                out = self._into.get(name)
                if out is None or out.shape != shape or out.dtype != like.dtype:
                    out = np.empty(shape, like.dtype)
                self._arrays[name] = out
                self._written[name] = np.zeros(self.nrows, bool)
        return out, self._written[name]

    def band(self, block):
        for name in ("data", "phantom", "dq", "uncertainty"):
            values = getattr(block, name)
            if values is not None:
                out, written = self._array(name, values)
                if not _rows_of(values, out, block.index):
                    out[:, block.index] = values
                written[block.index] = True  # bands hold rows of their own

    def get(self, name, ramp):
        values = self._arrays.get(name)
        if values is None:
            return values
        written = self._written[name]
        if not written.all():
            values[:, ~written] = 0 if values.dtype.kind in "uib" else np.nan
            written[:] = True
        return values if ramp else values[0]


def _rows_of(values, out, index):
    """Whether ``values`` is the view of ``out``'s rows ``index`` (consecutive)."""
    if values.dtype != out.dtype or not index.size or index[-1] - index[0] != index.size - 1:
        return False
    view = out[:, index[0]:index[-1] + 1]
    return (values.shape == view.shape and values.strides == view.strides
            and values.ctypes.data == view.ctypes.data)


def execute(source, kernels, consumer=None, *, options=None, rows_per_band=None,
            progress=None):
    """Run ``kernels`` over bands of ``source``, into ``consumer`` or a new exposure.

    A kernel after the first whose estimate needs the whole exposure (``needs_exposure``)
    splits the run into stages: the bands through the kernels before it into an exposure
    of the executor's own, which its ``prepare`` sees, then that exposure's bands through
    it and the kernels after it, corrected in place where the types allow and the rows
    stay in their order (the numbers are those of two passes).

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
        frame from a file, `MEMORY_BAND_FACTOR` times more in memory when every
        thread still has a band).
    progress : callable, optional
        Called with the number of rows done after each band.

    Returns
    -------
    result : `~spherex_reduce.Exposure`
    stats : `RunStats`
        The seconds spent in each kernel, the consumer and reading, the bands
        and threads.
    """
    cut = next((i for i, k in enumerate(kernels) if i and k.needs_exposure), None)
    if cut is not None:
        return _staged(source, kernels, cut, consumer, options, rows_per_band, progress)
    chain = _Chain(kernels, consumer, into=source.arrays())
    side = chain.prepare(source)
    nthreads = (options or RunOptions()).thread_count()
    if rows_per_band is None:
        rows_per_band = max(1, BAND_PIXELS // source.context.geometry.ncols)
        larger = MEMORY_BAND_FACTOR * rows_per_band
        if source.in_memory and -(-source.nrows // larger) >= nthreads:  # no thread idle
            rows_per_band = larger
    cuts = bands(source.nrows, rows_per_band)
    _run_bands(cuts, lambda lo, hi: chain.run(chain.read(source, lo, hi)), nthreads, progress)
    for i, (kernel, c) in enumerate(zip(kernels, chain.coefficients, strict=True)):
        extra = kernel.extra_rows(c)
        if extra is not None:
            chain.run(extra, i + 1)
    result = chain.finish(source, side)
    return result, RunStats(kernels=tuple(chain.busy[:len(kernels)]),
                            consumer=chain.busy[len(kernels)], read=chain.busy[-1],
                            bands=len(cuts), threads=nthreads)


def _staged(source, kernels, cut, consumer, options, rows_per_band, progress):
    """`execute` with ``kernels[cut]`` needing the whole exposure: the kernels before it
    over every band into an exposure of the executor's own (its estimate's input), then
    the others over that exposure's bands, in place (their output is that exposure's
    arrays, where the types allow), into ``consumer``.  ``progress`` is told the source's
    rows, half of them over each stage."""
    share = None if progress is None else _Share(progress, source.nrows)
    first, one = execute(source, kernels[:cut], options=options, rows_per_band=rows_per_band,
                         progress=None if share is None else share.part(source.nrows))
    inner = MemorySource(first, owned=True)
    result, two = execute(inner, kernels[cut:], consumer, options=options,
                          rows_per_band=rows_per_band,
                          progress=None if share is None else share.part(inner.nrows))
    if share is not None:
        share.finish()
    return result, RunStats(kernels=one.kernels + two.kernels, consumer=two.consumer,
                            read=one.read + one.consumer + two.read, bands=one.bands,
                            threads=one.threads, stages=one.stages + two.stages)


class _Share:
    """Rows of stages reported to ``progress`` as shares of ``total`` rows (whole rows, in
    order): each stage of ``n`` rows counts for half of them."""

    def __init__(self, progress, total):
        self.progress, self.total = progress, total
        self.done, self.sent = 0.0, 0

    def part(self, nrows):
        factor = self.total / (2.0 * max(nrows, 1))

        def report(rows):  # (called in the calling thread, after each band: `_run_bands`)
            self.done += rows * factor
            step = min(int(self.done), self.total) - self.sent
            self.sent += step
            if step > 0:
                self.progress(step)
        return report

    def finish(self):
        if self.total > self.sent:
            self.progress(self.total - self.sent)
            self.sent = self.total


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

    def __init__(self, kernels, consumer, into=None):
        self.kernels, self.consumer, self.into = kernels, consumer, into
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
            if kernel.needs_exposure and not (i == 0 and source.in_memory):
                raise ValueError(f"{type(kernel).__name__} needs the whole exposure in "
                                 "memory, as the first kernel of a stage")
            if kernel.needs_exposure:
                c = kernel.prepare(side, source.exposure())
            else:
                c = kernel.prepare(side)
            side = kernel.apply_side(c, side)
            self.coefficients.append(c)
            t = self._spent(i, t)
        self.output = self.kernels[-1].output if self.kernels else source.context
        # the source's own arrays are the output only where every band's rows stay where
        # they were read (``unchop`` writes readout rows to physical ones: other bands'
        # rows, some not yet read)
        into = self.into if self.output.order == source.context.order else None
        self.sink = (self.consumer if self.consumer is not None
                     else _Assembly(self.output, into))
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
