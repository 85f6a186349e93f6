"""Fused streaming: the paper's per-frame corrections folded into the ramp fit.

At full size the per-frame steps ``unchop``, ``subtract_phantom`` and
``correct_reference`` (strategies ``mean`` and ``acn``) each read and write
every pixel of every frame into a new frame.  Each of them, though, only moves
rows and subtracts from a pixel an offset that is constant along a row read of
a channel (the phantom value) or along a channel's (even or odd) columns (the
reference offset), and the offsets come from a few thousand values per frame:
the phantom values and the reference reads.

When a pipeline streams a raw ramp through ``unchop``, then
``subtract_phantom`` (exactly when the input has phantom values) and
optionally ``correct_reference`` (``mean`` or ``acn``, no side columns), into
``fit_ramp`` (uniform weights, no saturation level), the first frame goes
through the steps as usual, and `FusedFrames.prepare_frames` takes the offsets
of every later frame from the steps' own functions applied to the phantom
values and reference reads.  Then:

* if nothing is flagged (no row left unread, no channel without reference
  pixels), the ramp fit's accumulator reads every frame a band of image rows
  at a time (`FusedFrames.band_fill`: the rows' reads copied with ``pread``,
  minus their phantom value, minus their offset) and fits each band as
  ``fit_ramp`` fits a whole cube (`~spherex_reduce.steps.ramp.RampAccumulator.fit_bands`):
  the result is identical, bit for bit, to running the steps on the whole
  ramp (``Pipeline.run(..., stream=False)``);
* otherwise `FusedFrame.fill` copies each frame, corrected the same way, from
  the memory-mapped input straight into the frame-by-frame fit's buffer, in
  blocks of rows that stay in cache: identical to running the steps frame by
  frame (``fuse=False``).

Either way the arithmetic of the corrections is the steps', in the same order
and precision (``tests/test_fused.py``), with one pass over the pixels instead
of five (reading, un-chopping, phantom, reference, copying into the fit) and
no intermediate frames.  Every other case (another strategy or step, side
reference columns, a step skipped on the first frame, flags or uncertainties
in the input) runs the steps one by one.
"""

import time

import numpy as np

from . import dq
from .steps.phantom import _subtract_rows
from .steps.reference import (
    ALL,
    EVEN,
    ODD,
    _column_plan,
    _offsets_of,
    _usable,
    missing_columns,
    offsets_table,
)
from .steps.unchop import _mean_of_reads, _physical_index

__all__ = ["FusedFrame", "FusedFrames", "fused_plan"]

_ROWS = 32  # rows per block when copying a frame (32 x 2048 x 4 B = 256 kB, in cache)


def fused_plan(prefix, consumer, cparams, source):
    """`FusedFrames` if ``prefix`` steps and the ``consumer`` step can be fused, else None.

    Parameters
    ----------
    prefix : list of ``(name, params, step)``
        The per-frame steps before the accumulating one.
    consumer : `~spherex_reduce.step.Step`
        The accumulating step; ``cparams`` its parameters.
    source
        The pipeline's frame source (it must offer ``raw(k)``).
    """
    from .builtin import UnchopStep
    from .reduction_plugin import CorrectReferenceStep, SubtractPhantomStep
    from .steps.fit_ramp import FitRampStep
    from .steps.reference import AcnReference, MeanReference

    if type(consumer) is not FitRampStep or not hasattr(source, "raw"):
        return None
    if cparams.get("weighting", "uniform") != "uniform" or cparams.get("saturation") is not None:
        return None
    kinds = [type(step) for _, _, step in prefix]
    if kinds not in ([UnchopStep], [UnchopStep, SubtractPhantomStep],
                     [UnchopStep, CorrectReferenceStep],
                     [UnchopStep, SubtractPhantomStep, CorrectReferenceStep]):
        return None
    reference = None
    if kinds[-1] is CorrectReferenceStep:
        _, params, step = prefix[-1]
        name = params.get("strategy", "mean")
        if name not in ("mean", "acn") or params.get("side_columns", False):
            return None
        if step.strategy(name) not in (MeanReference, AcnReference):
            return None  # a plugin replaced the built-in strategy
        reference = {"acn": name == "acn", "sigma": params.get("sigma", 3.0),
                     "maxiters": params.get("maxiters", 5), "strategy": name}
    schedule = source.schedule
    if reference is not None and schedule.reference_read_indices.size == 0:
        return None
    # raw floating-point pixels without flags or uncertainties, and phantom values
    # exactly when subtract_phantom is asked for (it would be skipped otherwise)
    if not source.fusable() or source.has_phantom != (SubtractPhantomStep in kinds):
        return None
    slots = [kinds.index(k) if k in kinds else None
             for k in (UnchopStep, SubtractPhantomStep, CorrectReferenceStep)]
    return FusedFrames(schedule, source.unit, phantom=source.has_phantom, reference=reference,
                       slots=slots)


class FusedFrames:
    """Offsets of each frame for the fused path, and the copy that applies them.

    Parameters
    ----------
    schedule : `~spherex_reduce.ReadoutSchedule`
    unit : `astropy.units.Unit`
        Unit of the pixels (for the ``REFOFFS`` table).
    phantom : bool
        Whether ``subtract_phantom`` is among the steps.
    reference : dict or None
        ``correct_reference`` settings (``acn``, ``sigma``, ``maxiters``,
        ``strategy``), or None if that step is not among them.
    slots : list of int or None, optional
        Index, among the pipeline's per-frame steps, of ``unchop``,
        ``subtract_phantom`` and ``correct_reference`` (None if absent): where
        the time of each part of `FusedFrame.elapsed` is booked.
    """

    def __init__(self, schedule, unit, *, phantom, reference, slots=(0, None, None)):
        self.schedule = schedule
        self.unit = unit
        self.phantom = phantom
        self.reference = reference
        self.slots = list(slots)
        first, self.repeated = _physical_index(schedule)
        self.unread = first < 0  # rows never read
        self.any_unread = bool(self.unread.any())
        self.src = np.maximum(first, 0)  # the read each physical row is copied from
        self.ref_idx = schedule.reference_read_indices
        nrows = schedule.geometry.nrows
        self.reread_in_block = {b0: [(int(r) - b0, int(r)) for r in self.repeated
                                     if b0 <= r < b0 + _ROWS]
                                for b0 in range(0, nrows, _ROWS)}
        #: physical rows in the order of their (first) read: bands of it read the
        #: file in order
        self.order = np.argsort(self.src, kind="stable")
        # the reads of the re-read rows, and where each row's are among them
        self.reread_reads = np.flatnonzero(np.isin(schedule.rows, self.repeated))
        self.reread_idx = {int(row): np.flatnonzero(schedule.rows[self.reread_reads] == row)
                           for row in self.repeated}

    def prepare_frames(self, ks, raws, phantoms, template):
        """The offsets of frames ``ks``, and what writes their corrected pixels.

        The reference pixels of all of them are σ-clipped in one call (a few
        frames at a time keep the temporaries in cache).

        Parameters
        ----------
        ks : list of int
        raws : list of `numpy.ndarray`
            Each frame's pixels ``(reads, columns)`` in readout order (not modified).
        phantoms : list of `numpy.ndarray` or None
            Their phantom values ``(reads, channels)``.
        template : `~spherex_reduce.Exposure`
            The first frame after the steps (run one by one): its header.

        Returns
        -------
        list of `FusedFrame`
        """
        s = self.schedule
        g = s.geometry
        width = g.channel_width
        t0 = time.perf_counter()
        use_ph = self.phantom
        # the steps' precisions: un-chopped rows keep the pixels' type, the corrections
        # work in the common type of pixels, phantom values and float32
        raw_t = raws[0].dtype.newbyteorder("=")
        ph_t = phantoms[0].dtype.newbyteorder("=") if use_ph else raw_t
        native = np.result_type(raw_t, ph_t, np.float32)
        ref = np.stack([np.take(raw, self.ref_idx, axis=0) for raw in raws]).astype(raw_t)
        # the reads of re-read rows: (frames, reads, columns)
        again = np.stack([np.take(raw, self.reread_reads, axis=0) for raw in raws])
        reread = {row: _mean_of_reads(again, idx).astype(raw_t)
                  for row, idx in self.reread_idx.items()}
        t1 = time.perf_counter()
        if use_ph:  # subtract_phantom on the reference reads and the re-read rows
            ph = np.stack(phantoms)
            ref = _subtract_rows(ref, np.take(ph, self.ref_idx, axis=1), width)
            ph_again = np.take(ph, self.reread_reads, axis=1)
            for row, idx in self.reread_idx.items():
                ph_row = _mean_of_reads(ph_again, idx).astype(ph_t)
                reread[row] = (reread[row].astype(native)
                               - np.repeat(ph_row, width, axis=-1).astype(native))
        t2 = time.perf_counter()
        n = len(ks)
        tables = [{} for _ in ks]
        headers = [template.header] * n
        cols = [None] * n
        noref = [None] * n  # per frame: columns without a reference offset
        refs = list(ref)
        if self.reference is not None:  # correct_reference: offsets from the reference reads
            r = self.reference
            off, used, clipped = _offsets_of(g, _usable(ref, None), acn=r["acn"],
                                             sigma=r["sigma"], maxiters=r["maxiters"])
            parity = [EVEN, ODD] if r["acn"] else [ALL]
            for i in range(n):  # frame by frame, as the step warns
                offsets, missing, col = _column_plan(g, off[i:i + 1], r["strategy"], r["acn"])
                if missing.any():
                    noref[i] = missing_columns(g, missing, r["acn"])[0]
                refs[i] = (ref[i] - col).astype(np.result_type(ref, np.float32))
                tables[i]["REFOFFS"] = offsets_table(
                    offsets, missing, parity, used[i:i + 1], clipped[i:i + 1], r["strategy"],
                    self.unit, ramp=True)
                headers[i] = template.header.copy()
                headers[i]["NNOREF"] = (int(missing.sum()),
                                        "offsets without usable reference pixels")
                cols[i] = col[0].astype(native)
        t3 = time.perf_counter()
        spent = [(t1 - t0) / n, (t2 - t1) / n, (t3 - t2) / n]
        return [FusedFrame(self, k, raws[i], phantoms[i] if use_ph else None, native,
                           {row: v[i] for row, v in reread.items()}, cols[i], noref[i],
                           refs[i], tables[i], headers[i], list(spent))
                for i, k in enumerate(ks)]

    def bandable(self, first, parts):
        """Whether frame ``first`` (after the steps) and the prepared ``parts`` of the
        later frames can be fitted band by band (`band_fill`): nothing flagged
        (no rows left unread, no channel without reference pixels), and every
        frame's pixels of one type."""
        ref = first.reference
        dtype = first.data.data.dtype
        return (first.dq is None and first.phantom is None
                and (ref is None or (ref.dq is None and ref.phantom is None))
                and all(not p.flagged and p.dtype == dtype for p in parts))

    def band_fill(self, first, parts, source):
        """``fill(rows, out)``: the corrected pixels of image ``rows`` of every frame.

        ``out`` is ``(frames, len(rows), columns)``: frame 0 from ``first``
        (after the steps), the others from their `FusedFrame` in ``parts``,
        their reads taken from ``source.reads`` (for a file, ``pread`` into a
        small buffer: no page faults, and threads read side by side).
        """
        data0 = np.asarray(first.data.data[0])
        repeated = np.zeros(self.schedule.geometry.nrows, bool)
        repeated[self.repeated] = True

        def fill(rows, out):
            src = self.src[rows]
            rereads = [(int(i), int(rows[i])) for i in np.flatnonzero(repeated[rows])]
            np.take(data0, rows, axis=0, out=out[0])
            lo, hi = int(src.min()), int(src.max()) + 1
            for i, part in enumerate(parts, start=1):
                part.rows(src, rereads, out[i], raw=source.reads(part.k, lo, hi), first=lo)

        return fill

    @staticmethod
    def reference_reads(first, parts):
        """The corrected reference reads of every frame ``(frames, reads, columns)``,
        or None if the frames carry none."""
        ref = first.reference
        if ref is None or np.ndim(ref.data) != 3:
            return None
        return np.concatenate([np.asarray(ref.data)] + [p.reference[None] for p in parts])


class FusedFrame:
    """One frame prepared by `FusedFrames.prepare_frames`.

    Attributes
    ----------
    k : int
        The frame's index.
    dtype : `numpy.dtype`
        Type of the corrected pixels.
    flags : `numpy.ndarray` or None
        DQ flags ``(rows, columns)`` the steps would set (``NOT_READ``,
        ``NO_REFERENCE``), made when asked for (frames waiting to be fitted
        keep only which rows and columns are flagged).
    flagged : bool
        Whether ``flags`` would not be None.
    reference : `numpy.ndarray`
        The corrected reference reads ``(reads, columns)``.
    tables : dict
        The tables the steps record for this frame (``REFOFFS``).
    header : `astropy.io.fits.Header`
    elapsed : list of float
        Seconds spent for ``unchop``, ``subtract_phantom`` and
        ``correct_reference`` (`fill` adds its time to the first).
    """

    def __init__(self, plan, k, raw, phantom, dtype, reread, col, noref, reference, tables,
                 header, elapsed):
        self.plan, self.k, self.raw, self.phantom, self.dtype = plan, k, raw, phantom, dtype
        self.reread, self.col, self.noref = reread, col, noref
        self.reference, self.tables, self.header = reference, tables, header
        self.elapsed = elapsed
        #: ``release()``: frees the file pages of the frame once copied (set by the
        #: caller; by default nothing to free)
        self.release = lambda: None

    @property
    def flagged(self):
        return self.plan.any_unread or self.noref is not None

    @property
    def flags(self):
        if not self.flagged:
            return None
        g = self.plan.schedule.geometry
        flags = np.zeros((g.nrows, g.ncols), np.uint16)
        flags[self.plan.unread] |= dq.NOT_READ
        if self.noref is not None:
            flags[:, self.noref] |= dq.NO_REFERENCE
        return flags

    def fill(self, out):
        """Write the corrected frame, physical order, into ``out`` (flat, ``rows*columns``).

        Blocks of rows stay in cache (see `rows`).
        """
        t0 = time.perf_counter()
        plan = self.plan
        g = plan.schedule.geometry
        out = out.reshape(g.nrows, g.ncols)
        for b0 in range(0, g.nrows, _ROWS):
            b1 = min(g.nrows, b0 + _ROWS)
            self.rows(plan.src[b0:b1], plan.reread_in_block[b0], out[b0:b1])
        out[plan.unread] = np.nan
        self.elapsed[0] += time.perf_counter() - t0

    def rows(self, src, rereads, out, raw=None, first=0):
        """Corrected image rows read at ``src`` into ``out`` ``(len(src), columns)``.

        ``raw``: the reads to take them from (default: the frame's), starting
        at read ``first``.

        In the steps' order of operations: copied into native byte order, minus
        the phantom value of their row read and channel, re-read rows
        (``rereads``: pairs of index in ``src`` and image row) replaced by the
        mean of their reads, minus the column offsets.
        """
        g = self.plan.schedule.geometry
        out[...] = np.take(self.raw, src, axis=0) if raw is None else raw[src - first]
        if self.phantom is not None:
            per_channel = out.reshape(len(src), g.nchannels, g.channel_width)
            np.subtract(per_channel, np.take(self.phantom, src, axis=0)[:, :, None],
                        out=per_channel)
        for i, row in rereads:
            out[i] = self.reread[row]
        if self.col is not None:
            out -= self.col
