"""Where each output channel lies on the stored image: the one mapping to the readout frame.

Every computation of the package (the schedule, the simulator's engine, the
reduction steps, the executor) works in the *readout frame*: channels are
vertical stripes of ``channel_width`` columns, read in parallel row by row,
each row read of a channel ``channel_width`` samples in its fast-scan
direction.  A file holds the *stored image*, as the lab or mission writes it.
`ChannelLayout` maps the last two axes of any array (frames, ``DQ``, ``ERR``,
4-D integrations) between the two, and back:

``columns``
    Channels are vertical stripes of the stored image (SPHEREx, Roman, JWST
    in detector orientation): the identity.
``rows``
    Channels are horizontal bands of rows, the fast scan running along the
    columns (JWST NIRSpec in its science orientation): the stored image is the
    transpose of the readout frame.
``quadrants``
    Four channels, 2 x 2 quadrants, each read from its first-read corner
    (``outer``: the array's corner, toward the centre, as HST WFC3/IR;
    ``inner``: from the centre), its fast axis along rows or columns.
    Quadrant ``q`` is channel ``q``: 0 holds rows and columns from 0, 1 rows
    from 0 and the last columns, 2 the last rows and columns from 0, 3 the
    last rows and columns.  Each is flipped (and transposed when its fast axis
    runs along columns) so that its first-read pixel is the readout frame's
    ``[0, 0]`` of its channel and its fast axis the frame's axis 1; the four
    stand side by side in the frame.

The reference border is declared on the stored image (`RefBorder`, sides as
users see them); `ChannelLayout.frame_border` gives the readout frame's
reference rows and, for each channel, its reference columns at the start and
the end of the channel.
"""

import functools
from dataclasses import dataclass

import numpy as np
from astropy import units as u

__all__ = ["CHANNEL_LAYOUTS", "FAST_AXES", "FIRST_CORNERS", "ChannelLayout",
           "check_stored_order", "stored_pixel_times"]

#: The arrangements of the channels on the stored image (``channels``).
CHANNEL_LAYOUTS = ("columns", "rows", "quadrants")
#: Where each quadrant's readout starts (``first_corner``; quadrants only).
FIRST_CORNERS = ("outer", "inner")
#: The stored axis a quadrant's fast scan runs along (``fast_axis``; quadrants only).
FAST_AXES = ("rows", "columns")

# Flips (rows, columns) that bring quadrant q's first-read pixel to its [0, 0].
_FLIPS = {"outer": ((False, False), (False, True), (True, False), (True, True)),
          "inner": ((True, True), (True, False), (False, True), (False, False))}


@dataclass(frozen=True)
class ChannelLayout:
    """The mapping between a stored image ``(..., nrows, ncols)`` and the readout frame.

    Parameters
    ----------
    nrows, ncols : int
        Shape of the stored image (pixels).
    channels : {'columns', 'rows', 'quadrants'}
        How the output channels lie on the stored image (see the module).
    first_corner : {'outer', 'inner'}
        For quadrants: the corner each quadrant is read from.
    fast_axis : {'rows', 'columns'}
        For quadrants: the fast scan runs along a row (``rows``) or a column.

    Raises
    ------
    ValueError
        Quadrants on an odd number of rows or columns, or ``first_corner`` /
        ``fast_axis`` given for a layout that is not quadrants.

    Examples
    --------
    A 4 x 6 image in quadrants read from their outer corners, along rows:

    >>> import numpy as np
    >>> from spherex_reduce.core.channel_layout import ChannelLayout
    >>> lay = ChannelLayout(4, 6, "quadrants")
    >>> image = np.arange(24).reshape(4, 6)
    >>> frame = lay.to_readout(image)
    >>> frame.shape, frame[0].tolist()
    ((2, 12), [0, 1, 2, 5, 4, 3, 18, 19, 20, 23, 22, 21])
    >>> bool((lay.to_stored(frame) == image).all())
    True
    """

    nrows: int
    ncols: int
    channels: str = "columns"
    first_corner: str = "outer"
    fast_axis: str = "rows"

    def __post_init__(self):
        for name, allowed in (("channels", CHANNEL_LAYOUTS), ("first_corner", FIRST_CORNERS),
                              ("fast_axis", FAST_AXES)):
            if getattr(self, name) not in allowed:
                raise ValueError(f"{name} must be one of {allowed}, got "
                                 f"{getattr(self, name)!r}")
        if self.channels != "quadrants" and (self.first_corner, self.fast_axis) != (
                "outer", "rows"):
            raise ValueError(f"first_corner and fast_axis describe quadrants; with channels: "
                             f"{self.channels} leave them out (the fast scan of "
                             f"{self.channels} runs along "
                             f"{'rows' if self.channels == 'columns' else 'columns'})")
        if self.channels == "quadrants" and (self.nrows % 2 or self.ncols % 2):
            raise ValueError(f"channels: quadrants needs an even number of rows and columns, "
                             f"got {self.nrows} x {self.ncols}")

    @property
    def identity(self):
        """True when the stored image is the readout frame (``channels: columns``)."""
        return self.channels == "columns"

    @property
    def frame_shape(self):
        """``(rows, columns)`` of the readout frame."""
        if self.channels == "columns":
            return self.nrows, self.ncols
        if self.channels == "rows":
            return self.ncols, self.nrows
        h, w = self.nrows // 2, self.ncols // 2
        return (h, 4 * w) if self.fast_axis == "rows" else (w, 4 * h)

    def _quadrant_views(self, image):
        """The four quadrants of a stored image as frame-oriented views."""
        h, w = self.nrows // 2, self.ncols // 2
        parts = (image[..., :h, :w], image[..., :h, w:], image[..., h:, :w],
                 image[..., h:, w:])
        out = []
        for part, (flip_rows, flip_cols) in zip(parts, _FLIPS[self.first_corner],
                                                strict=True):
            part = part[..., ::-1, :] if flip_rows else part
            part = part[..., :, ::-1] if flip_cols else part
            out.append(part if self.fast_axis == "rows" else np.swapaxes(part, -1, -2))
        return out

    def to_readout(self, image):
        """The readout frame of a stored image ``(..., nrows, ncols)``.

        A view for ``columns`` and ``rows``; a new array for quadrants (the
        four are placed side by side).  None stays None.
        """
        if image is None or self.identity:
            return image
        image = np.asarray(image)
        self._check(image.shape[-2:], (self.nrows, self.ncols), "stored image")
        if self.channels == "rows":
            return np.swapaxes(image, -1, -2)
        return np.concatenate(self._quadrant_views(image), axis=-1)

    def to_stored(self, frame):
        """The stored image of a readout frame: the inverse of `to_readout`.

        A view for ``columns`` and ``rows``; a new array for quadrants.  None
        stays None.
        """
        if frame is None or self.identity:
            return frame
        frame = np.asarray(frame)
        self._check(frame.shape[-2:], self.frame_shape, "readout frame")
        if self.channels == "rows":
            return np.swapaxes(frame, -1, -2)
        out = np.empty((*frame.shape[:-2], self.nrows, self.ncols), frame.dtype)
        width = self.frame_shape[1] // 4
        for q, view in enumerate(self._quadrant_views(out)):
            view[...] = frame[..., q * width:(q + 1) * width]
        return out

    def summary(self):
        """One line: the stored image, how its channels lie, and the readout frame.

        Examples
        --------
        >>> from spherex_reduce.core.channel_layout import ChannelLayout
        >>> text = ChannelLayout(1024, 1024, "quadrants").summary()
        >>> text.split(", channels: ")[1].split("; ")
        ['quadrants read from the outer corner along rows', 'readout frame 512 x 2048']
        """
        how = {"columns": "columns", "rows": "rows, read along the columns",
               "quadrants": f"quadrants read from the {self.first_corner} corner along "
                            f"{self.fast_axis}"}[self.channels]
        return (f"stored image {self.nrows} x {self.ncols}, channels: {how}; readout frame "
                f"{self.frame_shape[0]} x {self.frame_shape[1]}")

    @staticmethod
    def _check(got, expected, what):
        if tuple(got) != tuple(expected):
            raise ValueError(f"the {what} must be {expected[0]} x {expected[1]} on its last "
                             f"two axes, got {got[0]} x {got[1]}")

    def frame_border(self, border):
        """The readout frame's reference pixels for a border declared on the stored image.

        Parameters
        ----------
        border : `~spherex_reduce.RefBorder`
            Reference border of the stored image.

        Returns
        -------
        frame : dict
            ``top bottom left right`` of the readout frame: its reference rows
            (from row 0 and at the end) and the reference columns at the
            array's left and right edges.
        channel : tuple of int
            ``(start, end)``: reference columns at the start and at the end of
            every channel of the readout frame (quadrants; else ``(0, 0)``).

        Raises
        ------
        ValueError
            Quadrants whose border differs on opposite sides: the rows read in
            parallel would be reference in some channels and not in others.

        Examples
        --------
        >>> from spherex_reduce import RefBorder
        >>> from spherex_reduce.core.channel_layout import ChannelLayout
        >>> ChannelLayout(16, 16, "quadrants").frame_border(RefBorder.of(5))
        ({'top': 5, 'bottom': 0, 'left': 0, 'right': 0}, (5, 0))
        >>> ChannelLayout(16, 8, "rows").frame_border(RefBorder.of({"top": 4, "left": 2}))
        ({'top': 2, 'bottom': 0, 'left': 4, 'right': 0}, (0, 0))
        """
        b = border
        if self.channels == "columns":
            return b.sides(), (0, 0)
        if self.channels == "rows":
            return {"top": b.left, "bottom": b.right, "left": b.top, "right": b.bottom}, (0, 0)
        if b.top != b.bottom or b.left != b.right:
            raise ValueError(f"channels: quadrants needs the same reference border on opposite "
                             f"sides (top = bottom, left = right), got {b}: each quadrant "
                             "reads its rows in parallel with the others")
        along, across = (b.top, b.left) if self.fast_axis == "rows" else (b.left, b.top)
        if self.first_corner == "outer":
            return {"top": along, "bottom": 0, "left": 0, "right": 0}, (across, 0)
        return {"top": 0, "bottom": along, "left": 0, "right": 0}, (0, across)

    def stored_rows_of(self, first, stop):
        """The stored rows that hold readout-frame rows ``first:stop``, and where each
        frame pixel of that band is among them.

        Returns
        -------
        rows : `numpy.ndarray`
            Stored rows to read, ascending.
        take : tuple of `numpy.ndarray`
            Index ``(i, j)`` into the array ``stored[rows]`` giving the frame
            band ``(stop - first, frame columns)``.

        The arrays are read-only and cached: a reader reads the same band of
        every frame.

        Examples
        --------
        >>> from spherex_reduce.core.channel_layout import ChannelLayout
        >>> rows, take = ChannelLayout(8, 4, "quadrants").stored_rows_of(0, 1)
        >>> rows.tolist()
        [0, 7]
        """
        return _band_index(self, first, stop)

    def stored_coordinates(self, i, j):
        """Stored ``(row, column)`` of readout-frame pixels ``(i, j)`` (integer arrays).

        Examples
        --------
        >>> from spherex_reduce.core.channel_layout import ChannelLayout
        >>> ChannelLayout(4, 6, "quadrants").stored_coordinates(0, 11)
        (np.int64(3), np.int64(3))
        """
        i, j = np.asarray(i), np.asarray(j)
        if self.channels == "columns":
            return i, j
        if self.channels == "rows":
            return j, i
        h, w = self.nrows // 2, self.ncols // 2
        width = self.frame_shape[1] // 4
        q, k = np.divmod(j, width)
        r, c = (i, k) if self.fast_axis == "rows" else (k, i)
        flips = np.array(_FLIPS[self.first_corner])
        r = np.where(flips[q, 0], h - 1 - r, r)
        c = np.where(flips[q, 1], w - 1 - c, c)
        return r + h * (q // 2), c + w * (q % 2)

    def frame_coordinates(self, r, c):
        """Readout-frame ``(i, j)`` of stored pixels ``(r, c)`` (integer arrays): the
        inverse of `stored_coordinates`.

        Examples
        --------
        >>> import numpy as np
        >>> from spherex_reduce.core.channel_layout import ChannelLayout
        >>> lay = ChannelLayout(4, 6, "quadrants", "inner", "columns")
        >>> i, j = lay.frame_coordinates(*np.indices((4, 6)))
        >>> r, c = lay.stored_coordinates(i, j)
        >>> bool((r == np.indices((4, 6))[0]).all() and (c == np.indices((4, 6))[1]).all())
        True
        """
        r, c = np.asarray(r), np.asarray(c)
        if self.channels == "columns":
            return r, c
        if self.channels == "rows":
            return c, r
        h, w = self.nrows // 2, self.ncols // 2
        q = 2 * (r >= h) + (c >= w)
        r, c = r - h * (q // 2), c - w * (q % 2)
        flips = np.array(_FLIPS[self.first_corner])
        r = np.where(flips[q, 0], h - 1 - r, r)
        c = np.where(flips[q, 1], w - 1 - c, c)
        i, k = (r, c) if self.fast_axis == "rows" else (c, r)
        return i, k + q * (self.frame_shape[1] // 4)


def stored_pixel_times(schedule, frame=0):
    """When every pixel of the stored image is sampled in stored frame ``frame``.

    Parameters
    ----------
    schedule : `~spherex_reduce.ReadoutSchedule`
        Its geometry is the readout frame; the times are mapped to the stored
        image (`~spherex_reduce.DetectorGeometry.layout`).
    frame : int
        Stored frame (from 0): its start (``schedule.frame_starts``) is added.

    Returns
    -------
    `~astropy.units.Quantity`
        ``(nrows, ncols)`` of the stored image, in s from the start of the
        exposure: the first read of each pixel's row in that frame.

    Examples
    --------
    Quadrants read from their outer corners: the four corners are read first,
    together.

    >>> from spherex_reduce import DetectorGeometry, ReadoutSchedule
    >>> from spherex_reduce.core.channel_layout import stored_pixel_times
    >>> g = DetectorGeometry(4, 4, 4, ref_border=0, channels="quadrants")
    >>> s = ReadoutSchedule(g, skip=1, ref_mode="none", phantom_reads=0, row_overhead=0,
    ...                     nframes=1, frame_time=1.0)
    >>> (stored_pixel_times(s).to_value("s") * 1e5).astype(int).tolist()
    [[0, 1, 1, 0], [2, 3, 3, 2], [2, 3, 3, 2], [0, 1, 1, 0]]
    """
    g = schedule.geometry
    samples = schedule.pixel_samples()[schedule.read_of_row()]
    times = schedule.frame_starts[frame] + (samples / g.pixel_rate) * u.s
    return g.layout.to_stored(times.to_value(u.s)) * u.s


def check_stored_order(schedule, order):
    """Refuse ramps in readout order of a layout that is not ``columns`` unless every row
    is read once, in order (``skip: 1``, ``ref_mode: none``): only then is a read of
    the readout frame a row of the stored image.

    Raises
    ------
    ValueError
        Naming the layout and what the schedule reads.

    Examples
    --------
    >>> from spherex_reduce import DetectorGeometry, ReadoutSchedule
    >>> from spherex_reduce.core.channel_layout import check_stored_order
    >>> g = DetectorGeometry(8, 8, 2, ref_border=0, channels="rows")
    >>> try:
    ...     check_stored_order(ReadoutSchedule(g, skip=2, ref_mode="none"), "readout")
    ... except ValueError as exc:
    ...     print(str(exc).split(";")[-1])
     this schedule reads rows [0, 2, 4, 6, 1, 3, 5, 7]
    """
    g = schedule.geometry
    if g.layout.identity or order != "readout":
        return
    rows = np.asarray(schedule.rows)
    if not np.array_equal(rows, np.arange(g.nrows)):
        shown = rows[:8].tolist() if rows.size > 8 else rows.tolist()
        raise ValueError(f"channels: {g.layout.channels} stores images: its ramps in readout "
                         "order must read every row once, in order (skip: 1, ref_mode: "
                         f"none); this schedule reads rows {shown}")


@functools.lru_cache(maxsize=32)  # a reader asks for each band once per frame
def _band_index(layout, first, stop):
    """`ChannelLayout.stored_rows_of`, computed once per layout and band (read-only arrays,
    shared between calls)."""
    i, j = np.meshgrid(np.arange(first, stop), np.arange(layout.frame_shape[1]), indexing="ij")
    stored_row, column = layout.stored_coordinates(i, j)
    rows, position = np.unique(stored_row, return_inverse=True)
    out = rows, (position.reshape(i.shape), column)
    for a in (rows, *out[1]):
        a.setflags(write=False)
    return out
