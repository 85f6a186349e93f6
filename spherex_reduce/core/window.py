"""A window (subarray, cutout, one output) of a larger array whose readout is described.

A file may hold only part of the array that was read: a lab's corner cutout,
one output of a mosaic's detector.  Its pixels were sampled when the *full*
readout reached them, so `Window` states the full array (`DetectorGeometry`:
size, channels, scan directions, reference border, pixel rate), where the
window starts in it and, through the schedule's ``readout`` fields
(``skip``, ``ref_mode``, ``phantom_reads``, ``row_overhead``), how the full
array is read.  Then:

- row ``r`` of the window is read when full row ``first_row + r`` is, in the
  full readout's order (`window_reads`), and column ``c`` at the sample offset
  of full column ``first_column + c`` within its full channel
  (`Window.column_offsets`): its fast-scan direction and the parity of its
  samples (ACN) are the full channel's;
- the window's geometry (`Window.geometry`) has the file's size, one channel
  if it lies inside one full channel or the full channels it covers, their
  scan directions, and the part of the full array's reference border inside
  it (a corner cutout keeps its top rows and left columns, one output in the
  middle of the array only its top and bottom rows);
- the frame time is taken as given (``readout.frame_time``, required); it
  must be at least the time the full readout takes to end the window's last
  row read (its reads cannot overlap the next frame's).

The fields are the ``window`` section of `spherex_reduce.core.fields.FIELDS`
(YAML ``window:``, FITS ``WINROW WINCOL FULLROWS FULLCOLS FULLCHAN FULLSCAN
FULLBORD``).
"""

from dataclasses import dataclass

import numpy as np

from ._text import plural
from .errors import FormatError
from .fields import FIELD, check_field, section_fields
from .geometry import DetectorGeometry, RefBorder

__all__ = ["WINDOW_DERIVED", "WINDOW_FIELDS", "Window", "default_overhead", "fill_window_geometry",
           "geometry_of", "window_reads"]

#: The fields of a window: ``first_row first_column full_nrows full_ncols full_nchannels
#: full_scan full_ref_border``.
WINDOW_FIELDS = tuple(f.name for f in section_fields("window"))
_REQUIRED = ("first_row", "first_column", "full_nrows", "full_ncols", "full_nchannels")
#: The geometry fields a window decides (from its full array).
WINDOW_DERIVED = ("nchannels", "scan", "ref_border")


@dataclass(frozen=True)
class Window:
    """Where a window lies in the full array, and the full array's layout.

    Parameters
    ----------
    first_row, first_column : int
        The window's first row and column in the full array (0-based, physical
        order: row 0 is read first, column 0 is the left of full channel 0).
    full : `DetectorGeometry`
        The full array: its size, channels, scan, reference border and pixel
        rate (Hz).

    Examples
    --------
    A 64 x 64 corner of a Roman-like H4RG (32 channels of 128 columns, every
    second channel read right to left):

    >>> from spherex_reduce import DetectorGeometry
    >>> from spherex_reduce.core.window import Window
    >>> full = DetectorGeometry(4096, 4096, 32, scan="alternate", pixel_rate=2e5)
    >>> corner = Window(0, 0, full).geometry(64, 64)
    >>> corner.nchannels, corner.border.sides()
    (1, {'top': 4, 'bottom': 0, 'left': 4, 'right': 0})

    One output in the middle (full channel 3, read right to left) has only
    reference rows, and its column offsets are those of the full channel:

    >>> out = Window(0, 384, full).geometry(4096, 128)
    >>> out.border.sides(), out.scan_directions.tolist(), out.column_offsets()[:3].tolist()
    ({'top': 4, 'bottom': 4, 'left': 0, 'right': 0}, [-1], [127, 126, 125])
    """

    first_row: int
    first_column: int
    full: DetectorGeometry

    def __post_init__(self):
        for name in ("first_row", "first_column"):
            object.__setattr__(self, name, check_field(FIELD[name], getattr(self, name)))
        if not isinstance(self.full, DetectorGeometry) or self.full.window is not None:
            raise ValueError(f"a window's full array must be a DetectorGeometry without a "
                             f"window, got {self.full!r}")

    @classmethod
    def from_fields(cls, values, pixel_rate):
        """A window from the values of its fields (`WINDOW_FIELDS`; ``full_scan`` and
        ``full_ref_border`` may be left out: ``'same'`` and 4) and the pixel rate (Hz).

        Raises
        ------
        ValueError
            A field is missing or invalid; the message names it.

        Examples
        --------
        >>> from spherex_reduce.core.window import Window
        >>> w = Window.from_fields({"first_row": 0, "first_column": 128, "full_nrows": 256,
        ...                         "full_ncols": 256, "full_nchannels": 2}, 1e5)
        >>> w.full.channel_width, w.first_column
        (128, 128)
        """
        missing = [n for n in _REQUIRED if values.get(n) is None]
        if missing:
            raise ValueError(f"a window needs {', '.join(missing)} (keywords "
                             f"{' '.join(FIELD[n].keyword for n in missing)})")
        scan = values.get("full_scan") or "same"
        size = {"nrows": values["full_nrows"], "ncols": values["full_ncols"],
                "nchannels": values["full_nchannels"], "pixel_rate": pixel_rate,
                "ref_border": 4 if values.get("full_ref_border") is None
                else values["full_ref_border"]}
        try:
            full = (DetectorGeometry.from_scan_label(scan, **size) if isinstance(scan, str)
                    else DetectorGeometry(scan=scan, **size))
        except ValueError as exc:
            raise ValueError(f"the full array (full_nrows ... full_ref_border): {exc}") from None
        return cls(values["first_row"], values["first_column"], full)

    def fields(self):
        """The values of the window's fields (YAML and FITS form), a dict."""
        f = self.full
        return {"first_row": self.first_row, "first_column": self.first_column,
                "full_nrows": f.nrows, "full_ncols": f.ncols, "full_nchannels": f.nchannels,
                "full_scan": f.scan_label, "full_ref_border": f.border.to_value()}

    def channels(self, nrows, ncols):
        """The full channels of an ``nrows x ncols`` window: ``(first, count, inside)``,
        ``inside`` True if it lies inside one channel (then ``count`` is 1).

        Raises
        ------
        ValueError
            The window does not fit in the full array, or cuts a channel
            without lying inside it; the message names the window and the
            channel boundaries.
        """
        f, r0, c0 = self.full, self.first_row, self.first_column
        where = (f"the {nrows} x {ncols} window at row {r0}, column {c0} of the "
                 f"{f.nrows} x {f.ncols} full array")
        if r0 + nrows > f.nrows or c0 + ncols > f.ncols:
            raise ValueError(f"{where} does not fit in it (rows {r0}-{r0 + nrows - 1}, "
                             f"columns {c0}-{c0 + ncols - 1})")
        w = f.channel_width
        first, last = c0 // w, (c0 + ncols - 1) // w
        if first == last:
            return first, 1, True
        if c0 % w or (c0 + ncols) % w:
            raise ValueError(
                f"{where} cuts a readout channel: columns {c0}-{c0 + ncols - 1} span full "
                f"channels {first}-{last}, whose boundaries are every {w} columns (0, {w}, "
                f"{2 * w}, ...); a window must lie inside one channel or cover whole channels")
        return first, last - first + 1, False

    def border(self, nrows, ncols):
        """The part of the full array's reference border inside the window, a `RefBorder`."""
        f, b = self.full, self.full.border
        r0, c0 = self.first_row, self.first_column
        return RefBorder(top=_overlap(0, b.top, r0, nrows),
                         bottom=_overlap(f.nrows - b.bottom, f.nrows, r0, nrows),
                         left=_overlap(0, b.left, c0, ncols),
                         right=_overlap(f.ncols - b.right, f.ncols, c0, ncols))

    def derived(self, nrows, ncols):
        """The geometry fields the window decides: ``nchannels``, ``scan`` (a list of
        +1/-1, the covered full channels') and ``ref_border`` (int or dict of sides)."""
        first, count, _ = self.channels(nrows, ncols)
        scan = self.full.scan_directions[first:first + count].tolist()
        return {"nchannels": count, "scan": scan,
                "ref_border": self.border(nrows, ncols).to_value()}

    def geometry(self, nrows, ncols):
        """The `DetectorGeometry` of an ``nrows x ncols`` window (the file's size)."""
        return DetectorGeometry(nrows, ncols, pixel_rate=self.full.pixel_rate, window=self,
                                **self.derived(nrows, ncols))

    def check(self, geometry):
        """Raise ValueError unless ``geometry`` (whose ``window`` is this) has the
        channels, scan directions, reference border and pixel rate the window gives."""
        expected = self.derived(geometry.nrows, geometry.ncols)
        have = {"nchannels": geometry.nchannels, "scan": geometry.scan_directions.tolist(),
                "ref_border": geometry.border.to_value()}
        for name, value in expected.items():
            if have[name] != value:
                raise ValueError(
                    f"{name}={have[name]} disagrees with the window at row {self.first_row}, "
                    f"column {self.first_column} of the {self.full.nrows} x {self.full.ncols} "
                    f"array, which gives {value}: with a window, leave {name} out")
        if geometry.pixel_rate != self.full.pixel_rate:
            raise ValueError(f"pixel_rate={geometry.pixel_rate:g} Hz disagrees with the full "
                             f"array's {self.full.pixel_rate:g} Hz")

    def column_offsets(self, ncols):
        """Sample offset of each of the window's ``ncols`` columns within its full
        channel's row read: the full array's, ``(ncols,)``."""
        return self.full.column_offsets()[self.first_column:self.first_column + ncols]

    def summary(self, nrows, ncols):
        """One line: where the window lies and what it reads."""
        f = self.full
        first, count, inside = self.channels(nrows, ncols)
        chans = (f"inside full channel {first}" if inside
                 else f"full channels {first}-{first + count - 1}")
        return (f"window {nrows}x{ncols} at row {self.first_row}, column "
                f"{self.first_column} of a {f.nrows}x{f.ncols} array ("
                f"{plural(f.nchannels, 'channel')} of {plural(f.channel_width, 'column')}, "
                f"scan {f.scan_label}, reference border {f.border}): {chans}")


def _overlap(start, stop, first, n):
    """Pixels of ``[start, stop)`` within ``[first, first + n)``."""
    return max(0, min(stop, first + n) - max(start, first))


def _scan_label(scan, n):
    """A scan (mode, list of +1/-1 or SCANDIR string) of ``n`` channels as ``+``/``-``."""
    if scan == "same":
        return "+" * n
    if scan == "alternate":
        return "".join("+-"[i % 2] for i in range(n))
    return scan if isinstance(scan, str) else "".join("+" if d > 0 else "-" for d in scan)


def window_reads(geometry, rows, is_ref):
    """The reads of a frame that fall in the window: ``(rows, is_ref, index)``.

    ``rows`` and ``is_ref`` are the full readout's order (physical rows of
    the full array, one per read); the result keeps the reads of the window's
    rows, as rows of the window, and ``index`` is each one's read index in
    the full readout (its start time follows from it).  Without a window,
    every read, ``index = arange(n_reads)``.

    Examples
    --------
    >>> import numpy as np
    >>> from spherex_reduce import DetectorGeometry
    >>> from spherex_reduce.core.window import Window, window_reads
    >>> g = Window(2, 0, DetectorGeometry(8, 8, 1, ref_border=0)).geometry(3, 8)
    >>> rows = np.array([0, 4, 1, 5, 2, 6, 3, 7])      # skip 4 over 8 rows
    >>> [a.tolist() for a in window_reads(g, rows, np.zeros(8, bool))]
    [[2, 0, 1], [False, False, False], [1, 4, 6]]
    """
    window = geometry.window
    if window is None:
        return rows, is_ref, np.arange(rows.size)
    r0 = window.first_row
    keep = (rows >= r0) & (rows < r0 + geometry.nrows)
    return rows[keep] - r0, is_ref[keep], np.flatnonzero(keep)


def default_overhead(geometry, frame_overhead, default):
    """The frame overhead (samples) when no frame time is given: ``frame_overhead``,
    else ``default``.

    A window needs its frame time (raises ValueError), ``frame_overhead`` given
    or not: the overhead would count from the end of the window's last row read,
    not the full array's, and time the frame by the window's rows alone.
    """
    if geometry.window is not None:
        given = "" if frame_overhead is None else (
            f"; frame_overhead={frame_overhead} alone would time a frame by the window's own "
            "rows, not the full array's")
        raise ValueError("a window needs readout.frame_time (TFRAME), the full readout's "
                         f"frame time: it is taken as given, not derived{given}")
    return default if frame_overhead is None else frame_overhead


def fill_window_geometry(values):
    """Field values (from a header and a config) with the window's geometry filled in.

    When ``values`` has window fields (`WINDOW_FIELDS`), ``nchannels``,
    ``scan`` and ``ref_border`` are derived from the window (one given as
    well must agree) and ``values['window']`` is the `Window`; otherwise
    ``values`` is returned as it is.  Without ``nrows``, ``ncols`` or
    ``pixel_rate`` nothing is filled (the caller names what is missing).

    Raises
    ------
    FormatError
        A window field is missing or invalid, the window does not fit or cuts
        a channel, or a given geometry value disagrees; the message names it.
    """
    if all(values.get(n) is None for n in WINDOW_FIELDS):
        return values
    if any(values.get(n) is None for n in ("nrows", "ncols", "pixel_rate")):
        return values
    try:
        window = Window.from_fields(values, values["pixel_rate"])
        derived = window.derived(values["nrows"], values["ncols"])
    except ValueError as exc:
        raise FormatError(f"window: {exc}") from None
    derived["scan"] = _scan_label(derived["scan"], derived["nchannels"])  # as SCANDIR
    out = dict(values, window=window, **derived)
    for name in WINDOW_DERIVED:
        have = values.get(name)
        if have is None:
            continue
        try:
            have = (_scan_label(have, derived["nchannels"]) if name == "scan"
                    else RefBorder.of(have).to_value() if name == "ref_border" else have)
        except (TypeError, ValueError):
            pass  # unreadable: reported as disagreeing below
        if have != derived[name]:
            raise FormatError(
                f"{FIELD[name].keyword}/{name} is {values[name]} but the window gives "
                f"{derived[name]}: with a window, the channels, scan and reference border "
                "come from the full array's (window: section)")
    return out



def geometry_of(values):
    """The `DetectorGeometry` of geometry field values (from a header, a config or both),
    after `fill_window_geometry`: every geometry field present is passed on (the channel
    layout and preset too), ``scan`` as its ``SCANDIR`` text, the window if any.

    Raises
    ------
    ValueError
        An invalid value or combination (e.g. a layout other than columns with a window).

    Examples
    --------
    >>> from spherex_reduce.core.window import geometry_of
    >>> geometry_of({"nrows": 16, "ncols": 16, "nchannels": 2, "scan": "+-"}).scan_label
    '+-'
    """
    kwargs = {f.name: values[f.name] for f in section_fields("geometry")
              if f.name in values and f.name != "scan"}
    return DetectorGeometry.from_scan_label(values.get("scan", "same"),
                                            window=values.get("window"), **kwargs)
