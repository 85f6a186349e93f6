"""Detector layout: rows, columns, readout channels and the reference border."""

import numpy as np

from .fields import check_field, section_fields, table_dataclass
from .limits import check_size

__all__ = ["DetectorGeometry"]

_SCAN_MODES = ("same", "alternate")


@table_dataclass("geometry")
class DetectorGeometry:
    """Layout of an HxRG array read by parallel output channels.

    Channels are vertical stripes of ``ncols // nchannels`` columns, all read
    at once, row by row.  A border of ``ref_border`` reference pixels (not
    sensitive to light) surrounds the array: that many rows at the start and at
    the end of the array and that many columns at the left of the first channel
    and the right of the last.  The defaults are the SPHEREx H2RG (2048 x 2048,
    32 channels of 64 columns, 4-pixel border, 100 kHz).

    Parameters
    ----------
    nrows, ncols : int
        Array size in pixels (rows are read in time; columns across channels).
    nchannels : int
        Number of output channels; must divide ``ncols``.
    ref_border : int
        Width in pixels of the reference border; 0 for a subarray without one.
    scan : {'same', 'alternate'} or sequence of {+1, -1}
        Fast-scan direction of each channel: ``'same'`` reads every channel
        left to right, ``'alternate'`` reverses every second channel (as JWST
        and Roman do), or give one direction per channel.
    pixel_rate : float
        Pixel sample rate of each channel in Hz.

    Examples
    --------
    >>> from spherex_reduce import DetectorGeometry
    >>> g = DetectorGeometry()              # SPHEREx
    >>> g.channel_width, g.n_active_rows
    (64, 2040)
    >>> jwst = DetectorGeometry(nchannels=4, scan="alternate")
    >>> jwst.channel_width, jwst.scan_directions.tolist()
    (512, [1, -1, 1, -1])
    """

    # The fields, their defaults and checks: `spherex_reduce.fields.FIELDS` ("geometry").

    def __post_init__(self):
        maxima = {"nchannels": lambda: self.ncols,  # bounds that depend on checked fields
                  "ref_border": lambda: max((min(self.nrows, self.ncols) - 1) // 2, 0)}
        for f in section_fields("geometry"):
            maximum = maxima[f.name]() if f.name in maxima else None
            object.__setattr__(self, f.name, check_field(f, getattr(self, f.name), maximum))
        if self.ncols % self.nchannels:
            raise ValueError(
                f"nchannels x channel width must equal ncols: ncols={self.ncols} is not a "
                f"multiple of nchannels={self.nchannels}"
            )
        check_size(self.nchannels * 16.0, f"{self.nchannels} readout channels")
        object.__setattr__(self, "_directions", self._parse_scan(self.scan))

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
    def channel_width(self):
        """Columns per channel."""
        return self.ncols // self.nchannels

    @property
    def n_active_rows(self):
        """Rows that are not reference rows."""
        return self.nrows - 2 * self.ref_border

    @property
    def reference_rows(self):
        """Physical reference rows: the first ``ref_border``, then the last ones."""
        b = self.ref_border
        return np.concatenate([np.arange(b), np.arange(self.nrows - b, self.nrows)]).astype(int)

    @property
    def active_rows(self):
        """Physical rows that see light, in physical order."""
        return np.arange(self.ref_border, self.nrows - self.ref_border)

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

    def channel_of_column(self):
        """Channel index (0-based) of each column, shape ``(ncols,)``."""
        return np.arange(self.ncols) // self.channel_width

    def column_offsets(self):
        """Sample offset of each column within its channel's row read, shape ``(ncols,)``.

        Column ``j`` of a channel read left to right is sampled ``j`` samples
        after the channel's first pixel; read right to left,
        ``width - 1 - j`` samples after.
        """
        width = self.channel_width
        j = np.tile(np.arange(width), self.nchannels)
        reverse = np.repeat(self.scan_directions < 0, width)
        return np.where(reverse, width - 1 - j, j)

    def reference_column_mask(self):
        """True for the side reference columns (left of channel 1, right of the last)."""
        mask = np.zeros(self.ncols, dtype=bool)
        b = self.ref_border
        if b:
            mask[:b] = True
            mask[-b:] = True
        return mask

    def to_dict(self):
        """The constructor arguments, as plain Python values."""
        values = {f.name: getattr(self, f.name) for f in section_fields("geometry")}
        if not isinstance(self.scan, str):
            values["scan"] = list(self.scan)
        return values

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
