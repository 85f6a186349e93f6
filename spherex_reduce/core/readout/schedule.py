"""When every sample of a frame is taken: row chopping, reference and phantom reads.

:class:`ReadoutSchedule` is the single source of truth for read order and
timing.  The simulator places noise with it, the reduction steps un-chop and
find reference reads with it, and it round-trips through FITS (header keywords
plus a ``READOUT`` table, cross-checked on read); its parameters are the
``readout`` fields of the one table `spherex_reduce.core.fields.FIELDS`.

Timing model (all in samples of one channel at ``pixel_rate``): every row read
takes ``phantom_reads + channel_width + row_overhead`` samples, the ``c``
phantom samples of the Video8 reference first, then the row's pixels in the
channel's fast-scan direction, then the row overhead.  After the last row read
of a frame come ``frame_overhead`` samples (reset, idle).  A frame therefore
lasts ``n_reads * row_samples + frame_overhead`` samples.
A stored frame is one read of the array or the mean of a group of reads
(`spherex_reduce.core.readout.groups`); a ramp fit takes `frame_starts`,
`read_noise_factors` and `shot_covariance`.
"""

import dataclasses
import logging
import math
from collections.abc import Mapping

import numpy as np
from astropy import units as u
from astropy.io import fits
from astropy.table import Table

from .._text import plural
from ..errors import FormatError
from ..fields import (
    DEFAULT_FRAME_OVERHEAD,
    FIELD,
    FIELDS,
    REF_MODES,
    check_field,
    field_cards,
    header_keyword,
    read_field,
    section_fields,
    table_dataclass,
)
from ..geometry import DetectorGeometry, RefBorder
from ..limits import check_size
from ..window import (
    WINDOW_DERIVED,
    WINDOW_FIELDS,
    default_overhead,
    fill_window_geometry,
    geometry_of,
    window_reads,
)
from .frame_times import StoredFrameTimes, check_read_times, describe_read_times
from .groups import describe_groups, resolve_groups
from .read_order import EXPLICIT, ORDER_REPLACES, check_order, order_from_table

__all__ = ["REF_MODES", "ReadoutSchedule", "chopped_order"]

log = logging.getLogger(__name__)

ACTIVE, REFERENCE = "active", "reference"

#: Samples of one channel an exposure may have (2**53: sample times stay exact in
#: float64; at 100 kHz, 2850 years).
MAX_SAMPLES = 2**53

# Memory a schedule holds per read of a frame and per column (all its arrays,
# with room to spare): the one estimate `_check_schedule_size` uses.
_BYTES_PER_READ = 100
_BYTES_PER_COLUMN = 40


def chopped_order(n, skip):
    """Order in which ``n`` rows are read with row-chopping skip ``skip``.

    Rows ``k, k+S, k+2S, ...`` are read for ``k = 0 ... S-1``: after the
    bottom of the array the read returns to the first unread row (paper §2.3,
    Fig. 3).  ``skip = 1`` is physical order; ``skip >= n`` is too.

    Parameters
    ----------
    n : int
        Number of rows.
    skip : int
        Skip parameter ``S`` (>= 1).

    Returns
    -------
    order : `numpy.ndarray` of int
        Row indices (0-based) in read order; a permutation of ``range(n)``.

    Examples
    --------
    >>> from spherex_reduce.core.readout.schedule import chopped_order
    >>> chopped_order(16, 4).tolist()
    [0, 4, 8, 12, 1, 5, 9, 13, 2, 6, 10, 14, 3, 7, 11, 15]
    """
    skip = check_field(FIELD["skip"], skip)
    return np.concatenate([np.arange(k, n, skip)
                           for k in range(min(skip, n))] or [[]]).astype(int)


@table_dataclass("readout", eq=False)
class ReadoutSchedule(StoredFrameTimes):
    """Read order and sample times of every frame of an exposure.

    Parameters
    ----------
    geometry : `DetectorGeometry`, optional
        Array layout; the SPHEREx H2RG by default.
    skip : int
        Row-chopping skip ``S`` (>= 1; 1 is physical order).  It need not
        divide the number of rows.
    ref_reads : int
        Number ``r`` of reference-row reads per frame for ``ref_mode``
        ``'repeated'`` and ``'distributed'`` (>= 0).  Ignored for ``'none'``.
    ref_mode : {'none', 'repeated', 'distributed'}
        ``'none'``: the physical reference rows are read once each, the top
        ones (``top`` of ``ref_border``, from row 0) before the active rows and the
        bottom ones after.
        ``'repeated'``: the top reference rows are re-read in place at the
        start of the frame (``ceil(r/2)`` reads) and the bottom ones at the end
        (``floor(r/2)``), cycling through the rows; all ``r`` at the one end
        that has reference rows if the other has none.
        ``'distributed'``: ``r`` reference reads evenly spaced through the
        frame (gaps differ by at most one read), cycling through all the
        declared physical reference rows, top then bottom (paper §4.3).
    phantom_reads : int
        ``c``, samples of the Video8 reference voltage before every row read
        (averaged into one phantom value per read and channel); 0 for none.
    row_overhead, frame_overhead : int, optional
        Idle samples after each row read and after each frame.
        ``frame_overhead`` defaults to the value giving 1.51 s for the paper's
        parameters, unless ``frame_time`` is given.
    nframes : int
        Frames up the ramp, ``N``.
    frame_time : `~astropy.units.Quantity` or float, optional
        State the frame time (s) directly instead of ``frame_overhead``; the
        overhead is derived from it and must not be negative.  It is the time
        of one read of the array, whether or not reads are grouped.
    frames_per_group, group_gap : int
        Each of the ``nframes`` stored frames is the mean of
        ``frames_per_group`` consecutive reads, and ``group_gap`` reads are
        discarded between groups (JWST's ``NFRAMES`` and ``GROUPGAP``);
        1 and 0 (every read stored) by default.
    groups : list of list of int, optional
        Instead: the reads (0-based frames of the exposure, strictly increasing,
        groups in time order without overlap) averaged into each stored frame,
        ``nframes`` lists, e.g. Roman's ``[[0], [1, 2], [3, 4, 5, 6]]``.
    read_times : list of float, optional
        Instead of even spacing: the time (s) of every stored frame's read,
        ``nframes`` times at least one read of the array apart, e.g. HST's
        ``SAMPTIME`` (`spherex_reduce.core.readout.frame_times`).
    order : list of int or str, optional
        Instead of ``skip``, ``ref_reads`` and ``ref_mode``: the physical row
        of every read, or an ECSV file of them (`spherex_reduce.core.readout.read_order`).

    Examples
    --------
    >>> from spherex_reduce import ReadoutSchedule
    >>> s = ReadoutSchedule()             # the paper's Table 3 case
    >>> s.n_reads, s.frame_time
    (2072, <Quantity 1.51 s>)
    >>> s.integration_time.round(2)
    <Quantity 111.74 s>
    >>> g = s.replace(nframes=3, groups=[[0], [1, 2], [4, 5, 6]])
    >>> g.frame_starts, g.read_noise_factors.round(3).tolist()
    (<Quantity [0.  , 2.265, 7.55 ] s>, [1.0, 0.5, 0.333])
    """

    geometry: DetectorGeometry = dataclasses.field(default_factory=DetectorGeometry)
    # Then the fields of `spherex_reduce.core.fields.FIELDS` (section "readout"), in its order.

    def __post_init__(self):
        set_ = object.__setattr__
        if not isinstance(self.geometry, DetectorGeometry):
            raise ValueError(f"geometry must be a DetectorGeometry, got "
                             f"{type(self.geometry).__name__}")
        set_(self, "geometry", self.geometry.frame)  # the readout frame (channel_layout)
        for f in section_fields("readout"):
            if not f.nullable:  # frame_overhead, frame_time: see _set_frame_timing
                set_(self, f.name, check_field(f, getattr(self, f.name)))
        groups, reads = resolve_groups(self.nframes, self.frames_per_group, self.group_gap,
                                       self.groups)
        set_(self, "groups", groups)
        set_(self, "_reads", reads)  # None: one read per stored frame
        g = self.geometry
        full = g if g.window is None else g.window.full  # a window follows its full readout
        if self.order is not None:
            given = [f"{n}={getattr(self, n)!r}" for n in ORDER_REPLACES
                     if getattr(self, n) != FIELD[n].default]
            order = check_order(self.order, g, given)
            set_(self, "order", order[0].tolist())
        elif self.ref_mode != "none" and self.ref_reads > 0 and full.border.rows == 0:
            raise ValueError(
                f"ref_reads={self.ref_reads} with ref_mode={self.ref_mode!r} needs reference "
                f"rows, but ref_border is {full.border}: set ref_reads to 0 or ref_mode to 'none'")
        _check_schedule_size(full.nrows, full.ncols, full.nchannels,
                             self.ref_reads if self.ref_mode != "none" else 0, full.border)
        rows, kinds, index = window_reads(
            g, *(self._build_order(full) if self.order is None else order))
        set_(self, "_index", index)  # each read's index in the (full) readout
        set_(self, "_rows", rows)
        set_(self, "_is_ref", kinds)
        self._set_frame_timing()
        set_(self, "read_times", check_read_times(self.read_times, self.nframes, reads is not None,
                                                  self.n_reads * self.row_samples / g.pixel_rate))
        for arr in (rows, kinds):
            arr.setflags(write=False)

    # -- construction -------------------------------------------------------
    def _set_frame_timing(self):
        set_ = object.__setattr__
        rate = self.geometry.pixel_rate
        read_samples = self.read_samples
        if self.frame_time is None:
            overhead = default_overhead(self.geometry, self.frame_overhead, DEFAULT_FRAME_OVERHEAD)
            limit = MAX_SAMPLES - 1 - read_samples
            overhead = check_field(FIELD["frame_overhead"], overhead, limit)
            set_(self, "frame_overhead", overhead)
            set_(self, "frame_time", ((read_samples + overhead) / rate) * u.s)
            self._check_exposure()
            return
        tframe = check_field(FIELD["frame_time"], self.frame_time) * u.s
        samples = tframe.to_value(u.s) * rate
        if samples >= MAX_SAMPLES:
            raise ValueError(f"frame_time={tframe} is {samples:.3g} samples at {rate:g} Hz, "
                             f"more than the {MAX_SAMPLES:.3g} a schedule can count")
        overhead = round(samples) - read_samples
        if overhead < 0:
            raise ValueError(f"frame_time must be >= {read_samples / rate:.6g} s, the time to read "
                             f"{read_samples // self.row_samples} rows of {self.row_samples} "
                             f"samples (phantom_reads + pixels + row_overhead); got {tframe}")
        if self.frame_overhead is not None and check_field(
                FIELD["frame_overhead"], self.frame_overhead) != overhead:
            raise ValueError(
                f"frame_time={tframe} implies frame_overhead={overhead} samples, but "
                f"frame_overhead={self.frame_overhead} was also given: give only one")
        set_(self, "frame_overhead", overhead)
        set_(self, "frame_time", tframe)
        self._check_exposure()

    def _check_exposure(self):
        total = self.frames_read * self.frame_samples
        if total >= MAX_SAMPLES or not np.isfinite(self.frame_time.value):
            raise ValueError(
                f"nframes={self.nframes} frames ({self.frames_read} read) of "
                f"{self.frame_samples} samples make "
                f"{total:.3g} samples, more than the {MAX_SAMPLES:.3g} a schedule can count")

    def _build_order(self, g):
        active = g.active_rows[chopped_order(g.n_active_rows, self.skip)]
        top, bottom = g.top_rows, g.bottom_rows
        r = self.ref_reads
        if self.ref_mode == "none":
            rows = np.concatenate([top, active, bottom])
            is_ref = np.concatenate([np.ones(top.size, bool), np.zeros(active.size, bool),
                                     np.ones(bottom.size, bool)])
        elif self.ref_mode == "repeated":
            n_top = (r + 1) // 2 if top.size and bottom.size else r if top.size else 0
            n_bottom = r - n_top
            head = top[np.arange(n_top) % top.size] if n_top else top[:0]
            tail = bottom[np.arange(n_bottom) % bottom.size] if n_bottom else bottom[:0]
            rows = np.concatenate([head, active, tail])
            is_ref = np.concatenate([np.ones(n_top, bool), np.zeros(active.size, bool),
                                     np.ones(n_bottom, bool)])
        else:  # distributed
            refs = g.reference_rows
            n = active.size + r
            rows = np.empty(n, dtype=int)
            is_ref = np.zeros(n, dtype=bool)
            if r:
                # reference read j goes before active read floor(j * n_active / r)
                before = (np.arange(r) * active.size) // r
                pos = before + np.arange(r)
                is_ref[pos] = True
                rows[pos] = refs[np.arange(r) % refs.size]
            rows[~is_ref] = active
        return rows.astype(int), is_ref

    # -- read order -----------------------------------------------------------
    @property
    def n_reads(self):
        """Row reads per frame (active plus reference)."""
        return int(self._rows.size)

    @property
    def rows(self):
        """Physical row of every read of a frame, shape ``(n_reads,)``."""
        return self._rows

    @property
    def is_reference(self):
        """True for reads of a reference row, shape ``(n_reads,)``."""
        return self._is_ref

    @property
    def kinds(self):
        """``'active'`` or ``'reference'`` for every read."""
        return np.where(self._is_ref, REFERENCE, ACTIVE)

    @property
    def row_samples(self):
        """Samples per row read: phantom + pixels (a window: its full channel's) + overhead."""
        return self.phantom_reads + self.geometry.read_width + self.row_overhead

    @property
    def starts(self):
        """Sample index (within the frame) of the first pixel of every read."""
        return self._index.astype(np.int64) * self.row_samples + self.phantom_reads

    @property
    def start_times(self):
        """Time (s, within the frame) of the first pixel of every read."""
        return (self.starts / self.geometry.pixel_rate) * u.s

    @property
    def read_samples(self):
        """Samples from the frame's start to the end of its last read (a window's: in the full
        readout)."""
        return (int(self._index[-1]) + 1) * self.row_samples

    @property
    def frame_samples(self):
        """Samples per frame (the frame time times the pixel rate)."""
        return self.read_samples + self.frame_overhead

    def pixel_samples(self):
        """Sample index (within the frame) of every pixel read, shape ``(n_reads, ncols)``."""
        return self.starts[:, None] + self.geometry.column_offsets()[None, :]

    def pixel_times(self):
        """Time (s, within the frame) of every pixel read, shape ``(n_reads, ncols)``."""
        return (self.pixel_samples() / self.geometry.pixel_rate) * u.s

    def phantom_samples(self):
        """Sample index of every phantom sample, shape ``(n_reads, phantom_reads)``."""
        c = self.phantom_reads
        return self.starts[:, None] - c + np.arange(c)[None, :]

    def phantom_times(self):
        """Time (s, within the frame) of every phantom sample, shape ``(n_reads, c)``."""
        return (self.phantom_samples() / self.geometry.pixel_rate) * u.s

    def read_of_row(self):
        """Read index of every physical row's *first* read; -1 where a row is never read."""
        first = np.full(self.geometry.nrows, -1, dtype=int)
        order = np.arange(self.n_reads)[::-1]
        first[self._rows[::-1]] = order  # later writes win: the first read stays
        return first

    @property
    def reference_read_indices(self):
        """Indices of the reference reads within a frame."""
        return np.flatnonzero(self._is_ref)

    @property
    def active_read_indices(self):
        """Indices of the active reads within a frame."""
        return np.flatnonzero(~self._is_ref)

    # -- parameters, tables, FITS ---------------------------------------------
    def to_dict(self):
        """Readout parameters as plain values (the ``readout:`` YAML section).

        ``frame_time`` is left out: ``frame_overhead`` states it in samples (a
        window's the other way round: its frame time is taken as given); with an
        explicit ``order``, so are the fields it replaces (``skip``, ``ref_reads``,
        ``ref_mode``).
        """
        out = {f.name: getattr(self, f.name) for f in section_fields("readout")
               if f.instead_of is None and not (self.order and f.name in ORDER_REPLACES)}
        if self.geometry.window is not None:
            del out["frame_overhead"]
            out["frame_time"] = float(self.frame_time.to_value(u.s))
        if out["groups"] is not None:
            out["groups"] = [list(reads) for reads in out["groups"]]
        out["read_times"] = None if self.read_times is None else list(self.read_times)
        return out

    def replace(self, **changes):
        """A copy with some parameters changed (``geometry`` too).

        The frame overhead is kept as samples unless ``frame_time`` is changed (a
        window keeps its frame time: it is taken as given); a frame of the same
        samples at the same pixel rate keeps its frame time exactly, as declared,
        not rounded to whole samples (e.g. ``nframes`` changed).
        """
        params = {"geometry": self.geometry, **self.to_dict()}
        params.update(changes)
        if "frame_time" in changes:
            params.pop("frame_overhead", None) if "frame_overhead" not in changes else None
        new = ReadoutSchedule(**params)
        if ("frame_time" in changes or "frame_overhead" in changes
                or new.frame_time == self.frame_time or new.frame_samples != self.frame_samples
                or new.geometry.pixel_rate != self.geometry.pixel_rate):
            return new
        params.pop("frame_overhead")
        return ReadoutSchedule(**params, frame_time=self.frame_time)

    def __eq__(self, other):
        if not isinstance(other, ReadoutSchedule):
            return NotImplemented
        return bool(
            self.geometry == other.geometry
            and self.to_dict() == other.to_dict()
            and np.isclose(self.frame_time.to_value(u.s), other.frame_time.to_value(u.s))
        )

    __hash__ = None

    def to_table(self):
        """One row per read: ``read row kind start time`` (time in s, within a frame).

        Examples
        --------
        >>> from spherex_reduce import ReadoutSchedule
        >>> t = ReadoutSchedule().to_table()
        >>> t.colnames
        ['read', 'row', 'kind', 'start', 'time']
        >>> t["kind"][0], int(t["row"][0])
        (np.str_('reference'), 0)
        """
        return Table(
            {
                "read": np.arange(self.n_reads),
                "row": self._rows,
                "kind": self.kinds,
                "start": self.starts,
                "time": self.start_times,
            },
            meta={"comments": [self.summary()]},
        )

    def describe_order(self):
        """How the read order is made, as text: ``'S=24, r=32 (distributed)'`` or
        ``'explicit order'``."""
        if self.order is not None:
            return "explicit order"
        refs = ("reference rows once" if self.ref_mode == "none"
                else f"r={self.ref_reads} ({self.ref_mode})")
        return f"S={self.skip}, {refs}"

    def summary(self):
        """One line describing the schedule."""
        g = self.geometry
        return (
            f"{g.nrows}x{g.ncols} array, {plural(g.nchannels, 'channel')} of "
            f"{plural(g.channel_width, 'column')}, "
            f"{self.describe_order()}, c={self.phantom_reads}: "
            f"{self.n_reads} reads/frame ({int(self._is_ref.sum())} reference), frame time "
            f"{self.frame_time.to_value(u.s):.6g} s, N={self.nframes}, "
            f"{self.integration_time.to_value(u.s):.6g} s"
            f"{describe_groups(self.frames_per_group, self.group_gap, self.groups)}"
            f"{describe_read_times(self.read_times)}"
        )

    def to_header(self, header=None):
        """Write the readout keywords into ``header`` (a copy; a new one if None)."""
        h = fits.Header() if header is None else header.copy()
        g = self.geometry.stored_geometry  # the stored image's fields
        window = {} if g.window is None else g.window.fields()
        for f in FIELDS:
            value = (window.get(f.name) if f.section == "window"
                     else getattr(g if f.section == "geometry" else self, f.name))
            if f.name == "scan":
                value = g.scan_label
            elif isinstance(value, u.Quantity):
                value = value.to_value(f.unit)
            if ((f.written_if_set and value == f.default)
                    or (self.order is not None and f.name in ORDER_REPLACES)):
                h.remove(f.keyword, ignore_missing=True)
                continue
            cards = field_cards(f, g.border.to_value() if f.name == "ref_border" else value)
            for key in set(f.keywords) - {c[0] for c in cards}:
                h.remove(key, ignore_missing=True)  # a per-side field: only one form
            for key, card_value, comment in cards:
                h[key] = (card_value, comment)
            if f.name == "nchannels":  # derived, checked on read
                h["CHANW"] = (g.channel_width, "columns per channel")
        return h

    @classmethod
    def from_header(cls, header, table=None, **supplied):
        """Rebuild a schedule from FITS keywords, checked against a ``READOUT`` table.

        Parameters
        ----------
        header : `astropy.io.fits.Header`
            Primary header with the readout keywords.
        table : `astropy.table.Table`, optional
            The ``READOUT`` table (``row kind start``); when given, every read
            must agree with the schedule the keywords describe.
        **supplied
            Geometry or readout parameters (the YAML names, e.g. ``skip=24``)
            used where the header lacks the keyword, for files from other
            electronics.

        Raises
        ------
        FormatError
            A keyword is missing and not supplied, invalid, or disagrees with
            the table; the message names it.
        """
        unknown = set(supplied) - set(FIELD)
        if unknown:
            raise FormatError(
                f"unknown readout parameter(s) {sorted(unknown)}; valid: {sorted(FIELD)}")
        values = {}
        for f in FIELDS:
            value = read_field(header, f)
            if value is not None:
                values[f.name] = value
            elif supplied.get(f.name) is not None:
                values[f.name] = supplied[f.name]
        values = fill_window_geometry(values)  # a window decides NCHAN SCANDIR REFBORD
        # Everything that decides read order and timing is required: guessing the
        # SPHEREx defaults for a foreign file would un-chop it wrongly and silently.
        if values.get("order") == EXPLICIT:  # ROWORDER: the READOUT table lists the rows
            values["order"] = order_from_table(table)
        both = [FIELD[n].keyword for n in ORDER_REPLACES if "order" in values and n in values]
        if both:
            raise FormatError(f"an explicit order (ROWORDER, or readout.order) and "
                              f"{', '.join(both)} are both given: the order replaces them")
        needed = set() if "order" in values else {"skip", "ref_mode"} | (
            {"ref_reads"} if values.get("ref_mode", "none") != "none" else set())
        # a window not yet filled (its full array's pixel rate or its size missing) decides
        # NCHAN SCANDIR REFBORD once they are given: not asked for
        windowed = "window" not in values and any(n in values for n in WINDOW_FIELDS)
        required = [f for f in FIELDS if (f.required is True or f.name in needed)
                    and not (windowed and f.name in WINDOW_DERIVED)]
        absent = [f for f in required if f.name not in values]
        missing = [f.keyword + (" (or ROWORDER)" if f.name in ORDER_REPLACES else "")
                   for f in absent]
        keys = [f"{f.section}.{f.name}" for f in absent]
        for f in FIELDS:
            if f.instead_of and f.name not in values and f.instead_of not in values:
                missing.append(f"{f.keyword} (or {FIELD[f.instead_of].keyword})")
                keys.append(f"{f.section}.{f.name} or "
                            f"{FIELD[f.instead_of].section}.{f.instead_of}")
        if missing:
            window = ("; the window's NCHAN, SCANDIR and REFBORD come from its full array"
                      if windowed else "")
            raise FormatError(
                f"missing readout keyword(s) {', '.join(missing)}: the file does not say how it "
                "was read; supply them in the pipeline config's geometry:/readout: sections: "
                f"{', '.join(keys)}{window}")
        _check_schedule_size(*(values.get(n, 0) for n in ("nrows", "ncols", "nchannels",
                                                          "ref_reads", "ref_border")))
        rkw = {f.name: values[f.name] for f in section_fields("readout")
               if f.name in values and not f.instead_of}
        if "frame_overhead" not in values or any(n in values for n in WINDOW_FIELDS):
            rkw["frame_time"] = values.get("frame_time")  # a window's: required, as given
        try:
            geometry = geometry_of(values)
            sched = cls(geometry, **rkw)
        except ValueError as exc:
            raise FormatError(f"readout keywords describe an invalid schedule: {exc}") from exc
        if "ref_border" not in values:
            log.warning("the file has no reference border keyword (REFBORD, or REFBTOP REFBBOT "
                        "REFBLEFT REFBRIGH) and none was supplied: assuming the default "
                        "ref_border=%s on every side; state geometry.ref_border in the config "
                        "if that is not the file's layout", geometry.ref_border)
        if table is not None:  # first: it names the read-order keyword at fault
            sched.check_table(table)
        if "frame_time" in values and "frame_overhead" in values and not np.isclose(
                values["frame_time"], sched.frame_time.to_value(u.s), rtol=1e-9,
                atol=0.5 / geometry.pixel_rate):
            raise FormatError(
                f"keyword TFRAME={values['frame_time']} disagrees with the frame time "
                f"{sched.frame_time.to_value(u.s)} s implied by FRMOVH and the read order")
        if ("CHANW" in header
                and header_keyword(header, "CHANW", int, 1) != sched.geometry.channel_width):
            raise FormatError(
                f"keyword CHANW={header['CHANW']} disagrees with NCOLS/NCHAN="
                f"{sched.geometry.channel_width}")
        return sched

    def check_table(self, table):
        """Raise `FormatError` naming the first column where ``table`` disagrees."""
        if len(table) != self.n_reads:
            raise FormatError(
                f"READOUT table has {len(table)} reads but the header keywords give "
                f"{self.n_reads} reads per frame (check ROWSKIP, NREFRD, REFMODE, NROWS, REFBORD)")
        for col, expected, hint in [
            ("row", self._rows, "ROWSKIP/NREFRD/REFMODE"),
            ("kind", self.kinds, "NREFRD/REFMODE/REFBORD"),
            ("start", self.starts, "NPHANT/ROWOVH/NCHAN"),
        ]:
            if col not in table.colnames:
                raise FormatError(f"READOUT table lacks column {col!r}")
            got = np.asarray(table[col])
            if col == "kind":
                got = np.char.strip(got.astype(str))
            bad = np.flatnonzero(got != expected)
            if bad.size:
                i = bad[0]
                raise FormatError(
                    f"READOUT column {col!r} disagrees with the header keywords ({hint}) at read "
                    f"{i}: table has {got[i].item()!r}, keywords give {expected[i].item()!r}")


def _check_schedule_size(nrows, ncols, nchannels, ref_reads, ref_border):
    """Refuse sizes whose schedule tables would not fit in memory, before building them.

    A schedule holds a few arrays of one entry per read of a frame (at most
    ``nrows + ref_reads`` reads, plus index arrays of the reference rows,
    ``top + bottom`` of ``ref_border``; `_BYTES_PER_READ` each) and per column
    and channel (`_BYTES_PER_COLUMN` each).  The values may come straight from
    a header or a config: any that is not a finite number counts as 0 here
    (the constructor names it).
    """
    def count(value):
        ok = isinstance(value, (int, float, np.integer, np.floating)) and math.isfinite(value)
        return max(float(value), 0.0) if ok else 0.0

    if isinstance(ref_border, RefBorder):
        ref_border = ref_border.sides()
    border_rows = (count(ref_border.get("top")) + count(ref_border.get("bottom"))
                   if isinstance(ref_border, Mapping) else 2 * count(ref_border))
    reads = count(nrows) + count(ref_reads)
    nbytes = (_BYTES_PER_READ * (reads + border_rows)
              + _BYTES_PER_COLUMN * (count(ncols) + count(nchannels)))
    check_size(nbytes, f"a readout schedule of {reads:.6g} row reads (nrows={nrows}, "
               f"ref_reads={ref_reads}, ncols={ncols}, nchannels={nchannels})")
