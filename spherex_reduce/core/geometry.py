"""Detector layout: rows, columns, readout channels and the reference border."""

import dataclasses
from dataclasses import dataclass

import numpy as np

from .channel_layout import ChannelLayout
from .fields import FIELD, SIDES, check_field, check_sides, section_fields, table_dataclass
from .limits import check_size
from .presets import apply_preset, check_preset

__all__ = ["DetectorGeometry", "RefBorder"]


@dataclass(frozen=True)
class RefBorder:
    """Widths in pixels of the reference border on each side of the array.

    ``top`` is the reference rows from row 0 (the first rows of the array,
    read first); ``bottom`` the last rows; ``left`` the columns from column 0
    (left of the first channel); ``right`` the last columns (right of the
    last channel).  In an image shown with row 0 at the bottom
    (``imshow(origin="lower")``, ds9), ``top`` appears at the bottom.

    Examples
    --------
    >>> from spherex_reduce import RefBorder
    >>> b = RefBorder.of({"top": 4, "left": 4})
    >>> b, b.uniform, b.rows
    (RefBorder(top=4, bottom=0, left=4, right=0), None, 4)
    >>> RefBorder.of(4).to_value(), str(b)
    (4, '{top: 4, bottom: 0, left: 4, right: 0}')
    """

    top: int = 0
    bottom: int = 0
    left: int = 0
    right: int = 0

    def __post_init__(self):
        for side, value in check_sides(FIELD["ref_border"], self.sides()).items():
            object.__setattr__(self, side, value)

    @classmethod
    def of(cls, value):
        """A `RefBorder` from one width (every side), a mapping of sides, or a `RefBorder`."""
        if isinstance(value, RefBorder):
            return value
        return cls(**check_sides(FIELD["ref_border"], value))

    def sides(self):
        """The widths as a dict of ``top bottom left right``."""
        return {side: getattr(self, side) for side in SIDES}

    @property
    def uniform(self):
        """The width if every side has it, else None."""
        return self.top if len(set(self.sides().values())) == 1 else None

    @property
    def rows(self):
        """Reference rows: ``top + bottom``."""
        return self.top + self.bottom

    @property
    def columns(self):
        """Side reference columns: ``left + right``."""
        return self.left + self.right

    def to_value(self):
        """The YAML value: one number if every side is equal, else a dict of sides."""
        return self.sides() if self.uniform is None else self.uniform

    def __str__(self):
        value = self.to_value()
        if isinstance(value, int):
            return str(value)
        return "{" + ", ".join(f"{k}: {v}" for k, v in value.items()) + "}"

_SCAN_MODES = ("same", "alternate")


@table_dataclass("geometry")
class DetectorGeometry:
    """Layout of an HxRG array read by parallel output channels.

    Channels are vertical stripes of ``ncols // nchannels`` columns, all read
    at once, row by row.  A border of reference pixels (not sensitive to
    light) surrounds the array: ``ref_border.top`` rows at the start of the
    array (from row 0), ``bottom`` rows at its end, ``left`` columns at the
    left of the first channel (from column 0) and ``right`` columns at the
    right of the last (see `RefBorder`).  The defaults are the SPHEREx H2RG
    (2048 x 2048, 32 channels of 64 columns, 4-pixel border on every side,
    100 kHz).

    Parameters
    ----------
    nrows, ncols : int
        Array size in pixels (rows are read in time; columns across channels).
    nchannels : int
        Number of output channels; must divide ``ncols``.
    ref_border : int, dict or `RefBorder`
        Width in pixels of the reference border: one number for every side (0
        for a subarray without one), or per side, e.g. ``{"top": 4, "left":
        4}`` (sides left out are 0).  Stored as an int when every side is
        equal, else as a `RefBorder`; :attr:`border` is always a `RefBorder`.
    scan : {'same', 'alternate'} or sequence of {+1, -1}
        Fast-scan direction of each channel: ``'same'`` reads every channel
        left to right, ``'alternate'`` reverses every second channel (as JWST
        and Roman do), or give one direction per channel.
    pixel_rate : float
        Pixel sample rate of each channel in Hz.
    channels : {'columns', 'rows', 'quadrants'}
        How the channels lie on the stored image (the file's pixels, as the
        lab or mission writes them; `~spherex_reduce.core.channel_layout`):
        vertical stripes (the default), horizontal bands read along the
        columns, or 2 x 2 quadrants (``nchannels`` 4).  The sizes and the
        border above are those of the stored image; every readout quantity
        (`channel_width`, `column_offsets`, reference rows and columns ...) is
        that of the readout frame, `frame`, which the schedule works in.
    first_corner : {'outer', 'inner'}
        Quadrants: each is read from the array's corner toward the centre
        (``outer``, as WFC3/IR) or from the centre.
    fast_axis : {'rows', 'columns'}
        Quadrants: the fast scan runs along a row or along a column.
    preset : str, optional
        The name of the `~spherex_reduce.core.presets.PRESETS` entry the other
        values were taken from (recorded in the FITS header as ``GEOPRSET``);
        `from_preset` fills them in.
    channel_border : tuple of int, keyword-only
        A readout frame's reference columns ``(start, end)`` of every channel
        (set on `frame` for quadrants read from a corner; 0 otherwise).
    stored : DetectorGeometry, keyword-only
        On a readout `frame`: the geometry of the stored image it maps to.
    window : `~spherex_reduce.core.window.Window`, optional (keyword only)
        The array is a window of a larger one, whose readout gives its pixel
        times; ``nchannels``, ``scan`` and ``ref_border`` must then be the
        window's (`Window.geometry <spherex_reduce.core.window.Window.geometry>`
        builds it).

    Examples
    --------
    >>> from spherex_reduce import DetectorGeometry
    >>> g = DetectorGeometry()              # SPHEREx
    >>> g.channel_width, g.n_active_rows
    (64, 2040)
    >>> jwst = DetectorGeometry(nchannels=4, scan="alternate")
    >>> jwst.channel_width, jwst.scan_directions.tolist()
    (512, [1, -1, 1, -1])
    >>> corner = DetectorGeometry(40, 40, 1, ref_border={"top": 4, "left": 4})
    >>> corner.reference_rows.tolist(), corner.n_active_rows
    ([0, 1, 2, 3], 36)
    """

    window: object = dataclasses.field(default=None, kw_only=True, repr=False)
    channel_border: tuple = dataclasses.field(default=(0, 0), kw_only=True)
    stored: object = dataclasses.field(default=None, kw_only=True, repr=False)
    # Then the fields, their defaults and checks: `spherex_reduce.core.fields.FIELDS`
    # ("geometry").

    def __post_init__(self):
        maxima = {"nchannels": lambda: self.ncols,  # bounds that depend on checked fields
                  "ref_border": lambda: max((min(self.nrows, self.ncols) - 1) // 2, 0)}
        if self.stored is not None:  # a readout frame: its border was checked as stored
            maxima.pop("ref_border")
        for f in section_fields("geometry"):
            value = getattr(self, f.name)
            if f.side_keywords:
                value = RefBorder.of(value)
                value = value if value.uniform is None else value.uniform
            if not isinstance(value, RefBorder):
                maximum = maxima[f.name]() if f.name in maxima else None
                value = check_field(f, value, maximum)
            object.__setattr__(self, f.name, value)
        border = RefBorder.of(self.ref_border)
        if border.rows >= self.nrows or border.columns >= self.ncols:
            raise ValueError(f"ref_border {border} leaves no active row or column of the "
                             f"{self.nrows} x {self.ncols} array: top + bottom must be < nrows "
                             "and left + right < ncols")
        object.__setattr__(self, "_border", border)
        if self.preset is not None:
            check_preset(self.preset)
        check_size(self.nchannels * 16.0, f"{self.nchannels} readout channels")
        if self.stored is None:  # a stored image: its layout gives its readout frame
            layout = ChannelLayout(self.nrows, self.ncols, self.channels, self.first_corner,
                                   self.fast_axis)
            object.__setattr__(self, "_layout", layout)
        frame = self.stored is not None or self._layout.identity
        object.__setattr__(self, "_frame", self if frame else self._readout_frame())
        if self._frame is self and self.ncols % self.nchannels:
            raise ValueError(
                f"nchannels x channel width must equal ncols: ncols={self.ncols} is not a "
                f"multiple of nchannels={self.nchannels}"
            )
        start, end = (int(v) for v in self.channel_border)
        if min(start, end) < 0 or start + end >= self.channel_width:
            raise ValueError(f"channel_border {self.channel_border} leaves no active column "
                             f"in channels of {self.channel_width} columns")
        object.__setattr__(self, "channel_border", (start, end))
        object.__setattr__(self, "_directions", self._parse_scan(self.scan))
        if self.window is not None:
            self.window.check(self)

    def _readout_frame(self):
        """The readout-frame geometry of a stored image whose channels are not columns."""
        lay = self._layout
        if self.window is not None:
            raise ValueError(f"a window of a larger array is read as stripes of columns: "
                             f"channels: {lay.channels} is not supported with a window")
        if lay.channels == "quadrants" and (self.nchannels != 4 or self.scan != "same"):
            raise ValueError(f"channels: quadrants reads 4 channels, each in the direction its "
                             f"first_corner gives: nchannels must be 4 (got {self.nchannels}) "
                             f"and scan 'same' (got {self.scan!r})")
        if lay.channels == "rows" and self.nrows % self.nchannels:
            raise ValueError(f"channels: rows needs nrows a multiple of nchannels: "
                             f"nrows={self.nrows}, nchannels={self.nchannels}")
        sides, per_channel = lay.frame_border(self._border)
        nrows, ncols = lay.frame_shape
        return DetectorGeometry(nrows, ncols, self.nchannels, RefBorder(**sides), self.scan,
                                self.pixel_rate, self.channels, self.first_corner,
                                self.fast_axis, self.preset, channel_border=per_channel,
                                stored=self)

    def _parse_scan(self, scan):
        if isinstance(scan, str):
            if scan not in _SCAN_MODES:
                raise ValueError(
                    f"scan must be one of {_SCAN_MODES} or a list of +1/-1 per channel, "
                    f"got {scan!r}"
                )
            if scan == "same":
                return (1,) * self.nchannels
            return tuple(1 if i % 2 == 0 else -1 for i in range(self.nchannels))
        directions = tuple(int(d) for d in scan)
        if len(directions) != self.nchannels or set(directions) - {1, -1}:
            raise ValueError(
                f"scan as a list needs one +1 or -1 for each of the {self.nchannels} channels, "
                f"got {list(scan)!r}"
            )
        object.__setattr__(self, "scan", directions)
        return directions

    # -- derived quantities -------------------------------------------------
    @property
    def frame(self):
        """The readout frame's geometry: ``self`` when channels are columns (or ``self``
        is a frame), else the frame's geometry, whose `stored` is ``self`` (its layout
        fields say which layout it is the frame of)."""
        return self._frame

    @property
    def stored_geometry(self):
        """The geometry of the stored image: `stored` for a readout frame, else ``self``."""
        return self if self.stored is None else self.stored

    @property
    def layout(self):
        """The `~spherex_reduce.core.channel_layout.ChannelLayout` between the stored
        image and the readout frame."""
        return self.stored_geometry._layout

    @property
    def channel_width(self):
        """Columns per channel of the readout frame."""
        return self._frame.ncols // self.nchannels

    @property
    def border(self):
        """The reference border per side, a `RefBorder` (whatever form ``ref_border`` has)."""
        return self._border

    @property
    def n_active_rows(self):
        """Rows that are not reference rows."""
        return self.nrows - self._border.rows

    @property
    def top_rows(self):
        """Physical reference rows at the top: the first ``top`` rows, from row 0."""
        return np.arange(self._border.top)

    @property
    def bottom_rows(self):
        """Physical reference rows at the bottom: the last ``bottom`` rows."""
        return np.arange(self.nrows - self._border.bottom, self.nrows)

    @property
    def reference_rows(self):
        """Physical reference rows: the top ones, then the bottom ones (declared sides only)."""
        return np.concatenate([self.top_rows, self.bottom_rows]).astype(int)

    @property
    def active_rows(self):
        """Physical rows that see light, in physical order."""
        return np.arange(self._border.top, self.nrows - self._border.bottom)

    @property
    def scan_directions(self):
        """Fast-scan direction of each channel (+1 left to right, -1 right to left)."""
        return np.array(self._directions, dtype=int)

    @property
    def scan_label(self):
        """The ``SCANDIR`` FITS value: 'same', 'alternate' or a string of + and -."""
        if isinstance(self.scan, str):
            return self.scan
        return "".join("+" if d > 0 else "-" for d in self._directions)

    @property
    def read_width(self):
        """Pixels of a row read in each channel: the channel width, or for a window the
        full array's."""
        return self.channel_width if self.window is None else self.window.full.channel_width

    def channel_of_column(self):
        """Channel index (0-based) of each column, shape ``(ncols,)``."""
        return np.arange(self.ncols) // self.channel_width

    def column_offsets(self):
        """Sample offset of each column within its channel's row read, shape ``(ncols,)``.

        Column ``j`` of a channel read left to right is sampled ``j`` samples
        after the channel's first pixel; read right to left,
        ``width - 1 - j`` samples after.  A window's columns have the offsets of
        the full array's columns they are.
        """
        if self.window is not None:
            return self.window.column_offsets(self.ncols)
        width = self.channel_width
        j = np.tile(np.arange(width), self.nchannels)
        reverse = np.repeat(self.scan_directions < 0, width)
        return np.where(reverse, width - 1 - j, j)

    def reference_column_mask(self):
        """True for the reference columns: ``left`` from column 0, ``right`` at the end, and
        `channel_border` at the start and end of every channel."""
        mask = np.zeros(self.ncols, dtype=bool)
        mask[:self._border.left] = True
        mask[self.ncols - self._border.right:] = True
        start, end = self.channel_border
        within = np.arange(self.ncols) % (self.ncols // self.nchannels)
        mask |= (within < start) | (within >= self.ncols // self.nchannels - end)
        return mask

    def reference_pixel_mask(self):
        """True for the reference pixels of a physical-order image ``(nrows, ncols)``: the
        reference rows and the side reference columns (statistics leave them out).

        Examples
        --------
        >>> from spherex_reduce import DetectorGeometry
        >>> m = DetectorGeometry(8, 8, 1, ref_border={"top": 2, "left": 1}).reference_pixel_mask()
        >>> int(m.sum()), bool(m[0, 5]), bool(m[5, 0]), bool(m[5, 5])
        (22, True, True, False)
        """
        if self._frame is not self:  # the frame's mask, in the stored orientation
            return self._layout.to_stored(self._frame.reference_pixel_mask())
        mask = np.zeros((self.nrows, self.ncols), dtype=bool)
        mask[self.reference_rows] = True
        mask[:, self.reference_column_mask()] = True
        return mask

    def to_dict(self):
        """The constructor arguments of the stored image's geometry, as plain Python values
        (a readout `frame` gives those of its `stored`)."""
        if self.stored is not None:
            return self.stored.to_dict()
        values = {f.name: getattr(self, f.name) for f in section_fields("geometry")}
        values["ref_border"] = self._border.to_value()
        if not isinstance(self.scan, str):
            values["scan"] = list(self.scan)
        return values

    @classmethod
    def from_preset(cls, preset, **overrides):
        """The geometry of a named layout (`~spherex_reduce.core.presets.PRESETS`), some of
        its values overridden.

        Raises
        ------
        ValueError
            An unknown preset (naming the known ones) or an invalid value.

        Examples
        --------
        >>> from spherex_reduce import DetectorGeometry
        >>> g = DetectorGeometry.from_preset("WFC3-IR")
        >>> g.channels, g.frame.nrows, g.frame.ncols, g.frame.channel_border
        ('quadrants', 512, 2048, (5, 0))
        """
        return cls(**apply_preset({**overrides, "preset": preset}))

    @classmethod
    def from_scan_label(cls, label, **kwargs):
        """Build from a ``SCANDIR`` value (the inverse of :attr:`scan_label`).

        Raises
        ------
        ValueError
            ``label`` is neither a scan mode nor a string of ``+`` and ``-``
            (any other character used to be read as ``-``).

        Examples
        --------
        >>> from spherex_reduce import DetectorGeometry
        >>> g = DetectorGeometry.from_scan_label("+-", nrows=8, ncols=8, nchannels=2, ref_border=0)
        >>> g.scan_directions.tolist()
        [1, -1]
        """
        if label in _SCAN_MODES:
            return cls(scan=label, **kwargs)
        if not isinstance(label, str) or not label or set(label) - {"+", "-"}:
            raise ValueError(f"SCANDIR must be 'same', 'alternate' or one '+' or '-' per "
                             f"channel, got {label!r}")
        return cls(scan=[1 if ch == "+" else -1 for ch in label], **kwargs)
