"""The executor: step kernels over bands of rows, into a consumer or a new exposure.

Every correction of the paper that works row by row (``unchop``,
``subtract_phantom``, ``correct_reference``) is a `~spherex_reduce.reduce.step.Kernel`
of its step, and ``fit_ramp`` is a `~spherex_reduce.reduce.step.Consumer` of bands.
`execute` runs a chain of kernels:

1. the *side block* (`side_block`: the reads of the reference rows of every
   frame, with their phantom values, a small part of the ramp) goes through
   the kernels' ``prepare`` (e.g. each frame's reference offsets) and
   ``apply_side``;
2. the input is cut into bands of rows of every frame (read from a file with
   ``pread`` by `~spherex_reduce.io.FrameReader`, or views of an in-memory
   exposure); each band goes through every kernel's ``apply`` in YAML order
   and then to the consumer, or into the output arrays; bands run on
   ``threads`` threads;
3. the kernels' ``record`` gives the tables and header cards.

A step run alone (``Step.run``) is `execute` on the exposure in memory
(`MemorySource`), so the numbers of a streamed reduction and of the steps run
one by one agree bit for bit: each pixel's arithmetic does not depend on the
band that holds it.

It sits at the bottom of the steps layer (it imports no step) so that the
steps can run themselves through it.
"""

import os
import threading
import time
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from ..core.block import Block, Context
from ..core.exposure import Exposure, ReferenceReads, expected_shape

__all__ = ["FileSource", "MemorySource", "default_threads", "execute", "side_block", "side_indices"]

#: pixels per band of a file (all frames together): 74 frames x 2**17 x 4 B = 39 MB per
#: band and thread, so memory stays near the output
BAND_PIXELS = 1 << 17
#: in memory a band is a view, so bands twice as large cost nothing and fit ~5 % faster
MEMORY_BAND_FACTOR = 2


def default_threads():
    """Threads used when none are asked for: the cores available, at most 4."""
    try:
        n = len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        n = os.cpu_count() or 1
    return max(1, min(4, n))


def side_indices(schedule):
    """Reads of a frame the kernels prepare from: those of reference rows and of rows read
    more than once (their mean is the row's value)."""
    counts = np.bincount(schedule.rows, minlength=schedule.geometry.nrows)
    return np.flatnonzero(schedule.is_reference | (counts[schedule.rows] > 1))


def _frames(values, ramp):
    """``values`` with a leading frame axis (a 2-D image is one frame); None stays None."""
    if values is None:
        return None
    values = np.asarray(values)
    return values if ramp else values[None]


def side_block(exposure):
    """The side block of an exposure (see the module's description).

    In readout order: the reads of `side_indices` taken from the pixels.
    In physical order: the reference reads kept aside by ``unchop`` if there
    are any, else the physical reference rows that were read.
    """
    s = exposure.schedule
    ramp = exposure.is_ramp
    unc = exposure.data.uncertainty
    unc = None if unc is None else unc.array

    def take(values, idx):
        return None if values is None else np.take(_frames(values, ramp), idx, axis=-2)

    every = read_phantom(exposure)
    if exposure.order == "readout":
        idx = side_indices(s)
        return Block(take(exposure.data.data, idx), idx, "readout",
                     phantom=take(exposure.phantom, idx), dq=take(exposure.dq, idx),
                     uncertainty=take(unc, idx), read_phantom=every)
    ref = exposure.reference
    if ref is not None and np.shape(ref.data)[-2] > 0:
        return Block(_frames(ref.data, ramp), np.asarray(ref.reads), "readout",
                     phantom=_frames(ref.phantom, ramp), dq=_frames(ref.dq, ramp),
                     read_phantom=every)
    rows = s.geometry.reference_rows
    rows = rows[s.read_of_row()[rows] >= 0] if rows.size else rows
    return Block(take(exposure.data.data, rows), rows, "physical",
                 phantom=take(exposure.phantom, rows), dq=take(exposure.dq, rows),
                 uncertainty=take(unc, rows), read_phantom=every)


def read_phantom(exposure):
    """The phantom values of every read of every frame ``(frames, n_reads, nchannels)``, in
    readout order (None without phantom values).

    In physical order a read takes its row's phantom value (the mean over the
    row's reads for a row read more than once), and the reference reads kept
    aside by ``unchop`` their own.
    """
    if exposure.phantom is None:
        return None
    ph = _frames(exposure.phantom, exposure.is_ramp)
    if exposure.order == "readout":
        return ph
    s = exposure.schedule
    out = np.take(ph, s.rows, axis=1)
    ref = exposure.reference
    if ref is not None and ref.phantom is not None and np.shape(ref.data)[-2] > 0:
        out[:, np.asarray(ref.reads)] = _frames(ref.phantom, exposure.is_ramp)
    return out


class MemorySource:
    """Bands of an in-memory `~spherex_reduce.Exposure` (views: never written).

    Parameters
    ----------
    exposure : `~spherex_reduce.Exposure`
    """

    def __init__(self, exposure):
        self.exposure = exposure
        self.context = context_of(exposure)
        self.header, self.tables = exposure.header, exposure.tables
        self.reference = exposure.reference
        self.nrows = exposure.data.data.shape[-2]
        ramp = exposure.is_ramp
        unc = exposure.data.uncertainty
        self._arrays = (_frames(exposure.data.data, ramp), _frames(exposure.phantom, ramp),
                        _frames(exposure.dq, ramp), None if unc is None else _frames(unc.array,
                                                                                    ramp))

    def side(self):
        return side_block(self.exposure)

    def read(self, lo, hi):
        data, phantom, flags, unc = (None if a is None else a[:, lo:hi] for a in self._arrays)
        return Block(data, np.arange(lo, hi), self.context.order, phantom=phantom, dq=flags,
                     uncertainty=unc)


class FileSource:
    """Bands of a raw ramp file, read with ``pread`` (no page of the file is mapped).

    Parameters
    ----------
    reader : `~spherex_reduce.io.FrameReader` or `~spherex_reduce.io.read_files.ReadFiles`
        An open reader of a file whose pixels are stored as they are
        (floating point, not scaled, not compressed: ``reader.readable_in_bands()``),
        or of a ramp stored as one file per read, in readout order.
    """

    def __init__(self, reader):
        self.reader = reader
        s = reader.schedule
        self.context = Context(s, "readout", True, reader.unit, reader.header,
                               phantom=reader.has_phantom)
        self.header, self.tables = reader.header, reader.tables
        self.reference = None
        self.nrows = s.n_reads
        self._dtype = reader.stored_dtype.newbyteorder("=")
        self._phantom = reader.phantom

    @staticmethod
    def usable(reader):
        """Whether a reader's file can be read in bands (else: read it whole)."""
        return reader.readable_in_bands()

    def _reads(self, idx):
        """Reads ``idx`` (sorted) of every frame ``(frames, len(idx), ncols)``, native order."""
        s = self.context.schedule
        out = np.empty((s.nframes, idx.size, s.geometry.ncols), self._dtype)
        if idx.size == 0:
            return out
        runs = np.split(np.arange(idx.size), np.flatnonzero(np.diff(idx) != 1) + 1)
        for k in range(s.nframes):
            for run in runs:
                out[k, run[0]:run[-1] + 1] = self.reader.reads(k, int(idx[run[0]]),
                                                              int(idx[run[-1]]) + 1)
        return self.reader.scale(out)  # the gain of input:, as a whole read applies it

    def side(self):
        idx = side_indices(self.context.schedule)
        phantom = None if self._phantom is None else self._phantom[:, idx]
        return Block(self._reads(idx), idx, "readout", phantom=phantom, owned={"data"},
                     read_phantom=self._phantom)

    def read(self, lo, hi):
        idx = np.arange(lo, hi)
        phantom = None if self._phantom is None else self._phantom[:, lo:hi]
        return Block(self._reads(idx), idx, "readout", phantom=phantom, owned={"data"})


def context_of(exposure):
    """The `~spherex_reduce.core.block.Context` of an exposure."""
    return Context(exposure.schedule, exposure.order, exposure.is_ramp, exposure.unit,
                   exposure.header, phantom=exposure.phantom is not None)


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


def execute(source, kernels, consumer=None, *, threads=None, rows_per_band=None,
            progress=None, timings=None):
    """Run ``kernels`` over bands of ``source``, into ``consumer`` or a new exposure.

    Parameters
    ----------
    source : `MemorySource` or `FileSource`
        Where bands come from (``side()``, ``read(lo, hi)``, ``context``,
        ``header``, ``tables``, ``reference``, ``nrows``).
    kernels : list of `~spherex_reduce.reduce.step.Kernel`
        In the order they run (each made for the previous one's output context).
    consumer : `~spherex_reduce.reduce.step.Consumer`, optional
        Takes the corrected bands (``fit_ramp``); else they are assembled into
        an exposure like the input.
    threads : int, optional
        Bands corrected at once (default `default_threads`).
    rows_per_band : int, optional
        Rows of every frame per band (default: `BAND_PIXELS` pixels of every
        frame from a file, `MEMORY_BAND_FACTOR` times more in memory).
    progress : callable, optional
        Called with the number of rows done after each band.
    timings : dict, optional
        Filled with the seconds spent in each kernel (``kernels``), in the
        consumer (``consumer``) and reading (``read``), summed over threads,
        and the number of ``bands`` and ``threads``.

    Returns
    -------
    `~spherex_reduce.Exposure`
    """
    context = source.context
    busy = [0.0] * (len(kernels) + 2)  # seconds in each kernel, the consumer, reading
    lock = threading.Lock()

    def spent(i, t0):
        t1 = time.perf_counter()
        with lock:
            busy[i] += t1 - t0
        return t1

    t = time.perf_counter()
    side = source.side()
    t = spent(-1, t)
    coefficients = []
    for i, kernel in enumerate(kernels):
        if kernel.needs_exposure:
            if i > 0 or getattr(source, "exposure", None) is None:
                # its estimate would see the pixels before the kernels ahead of it
                raise ValueError(f"{type(kernel).__name__} needs the whole exposure in memory, "
                                 "as the first kernel of a pass")
            c = kernel.prepare(side, source.exposure)
        else:
            c = kernel.prepare(side)
        side = kernel.apply_side(c, side)
        coefficients.append(c)
        t = spent(i, t)
    out_context = kernels[-1].output if kernels else context
    sink = consumer if consumer is not None else _Assembly(out_context)

    def run(block, start=0):
        t = time.perf_counter()
        for i in range(start, len(kernels)):
            block = kernels[i].apply(coefficients[i], block)
            t = spent(i, t)
        sink.band(block)
        spent(len(kernels), t)
        return block.data.shape[1]

    def read(lo, hi):
        t = time.perf_counter()
        block = source.read(lo, hi)
        spent(-1, t)
        return block

    if rows_per_band is None:
        ncols = context.geometry.ncols
        pixels = BAND_PIXELS * (MEMORY_BAND_FACTOR if isinstance(source, MemorySource) else 1)
        rows_per_band = max(1, pixels // ncols)
    cuts = bands(source.nrows, rows_per_band)
    nthreads = default_threads() if threads is None else max(1, int(threads))
    if nthreads == 1 or len(cuts) == 1:
        for lo, hi in cuts:
            run(read(lo, hi))
            if progress is not None:
                progress(hi - lo)
    else:
        with ThreadPoolExecutor(nthreads, thread_name_prefix="spherex-reduce-band") as pool:
            futures = [pool.submit(lambda lo=lo, hi=hi: run(read(lo, hi)))
                       for lo, hi in cuts]
            try:
                for (lo, hi), future in zip(cuts, futures, strict=True):
                    future.result()
                    if progress is not None:
                        progress(hi - lo)
            except BaseException:  # a band failed (or Ctrl-C): the others are not started
                for future in futures:
                    future.cancel()
                raise
    for i, (kernel, c) in enumerate(zip(kernels, coefficients, strict=True)):
        extra = kernel.extra_rows(c)
        if extra is not None:
            run(extra, i + 1)
    header = source.header.copy()
    tables = dict(source.tables)
    for kernel, c in zip(kernels, coefficients, strict=True):
        record = kernel.record(c)
        tables.update(record.tables)
        for key, value, comment in record.cards:
            header[key] = (value, comment)
    reference = reference_after(source.reference, side, context, out_context)
    t = time.perf_counter()
    if consumer is not None:
        result = consumer.finish(reference, header, tables)
    else:
        result = _exposure(source, sink, reference, header, tables, out_context)
    spent(len(kernels), t)
    if timings is not None:
        timings.update(kernels=busy[:len(kernels)], consumer=busy[len(kernels)],
                       read=busy[-1], bands=len(cuts), threads=nthreads)
    return result


def reference_after(reference, side, before, after):
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


def _exposure(source, sink, reference, header, tables, context):
    """The assembled output as an `~spherex_reduce.Exposure`."""
    ramp = context.ramp
    return Exposure.from_arrays(sink.get("data", ramp), context.schedule, unit=context.unit,
                                uncertainty=sink.get("uncertainty", ramp),
                                mask=sink.get("dq", ramp), phantom=sink.get("phantom", ramp),
                                header=header, order=sink.order, reference=reference,
                                tables=tables)
