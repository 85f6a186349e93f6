"""Calibration values that may differ from pixel to pixel: read noise, gain, dark current.

A step parameter such as ``fit_ramp``'s ``read_noise`` takes one number for
every pixel, a 2-D array (in Python), or the path of a FITS image (in YAML),
of the array's shape ``(nrows, ncols)`` in physical order.  `PixelMap` holds
the checked values; `PixelMap.rows` gives those of the rows a band of the
executor holds, in the band's order (readout order: the physical row of each
read, from the schedule).

Maps are read with astropy (the first image HDU holding data, or the one named
``path[EXTNAME]``), checked (finite, within the parameter's bounds, the array's
shape) and held in float64.

Examples
--------
>>> import numpy as np
>>> from spherex_reduce import DetectorGeometry, ReadoutSchedule
>>> from spherex_reduce.reduce.steps.pixel_maps import PixelMap
>>> s = ReadoutSchedule(DetectorGeometry(4, 2, 1, ref_border=0), skip=2, ref_mode="none",
...                     phantom_reads=0, nframes=2)
>>> m = PixelMap.of(np.arange(8.0).reshape(4, 2), "read_noise", s.geometry)
>>> s.rows.tolist()  # skip 2: rows 0, 2, 1, 3 in the order read
[0, 2, 1, 3]
>>> m.rows([0, 1], "readout", s).tolist()  # the first two reads: rows 0 and 2
[[0.0, 1.0], [4.0, 5.0]]
>>> PixelMap.of(5, "read_noise", s.geometry).rows([0, 1], "readout", s)
5.0
"""

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ...core.errors import ConfigError

__all__ = ["MAP_TYPES", "PixelMap"]

#: Types a per-pixel parameter accepts: a number, a FITS path (YAML) or an array (Python).
MAP_TYPES = (int, float, str, np.ndarray)

_EXT = re.compile(r"^(?P<path>.*)\[(?P<ext>[^\[\]]+)\]$")


def _read_image(text, name, shape):
    """The 2-D image of the FITS file ``text`` (``path`` or ``path[EXT]``), as float64;
    its shape is checked against ``shape`` from the header, before its data are read."""
    from astropy.io import fits

    match = _EXT.match(text)
    path, ext = (match["path"], match["ext"]) if match else (text, None)
    if not Path(path).is_file():
        raise ConfigError(f"{name}: no such FITS file: {path}")
    try:
        with fits.open(path, memmap=False) as hdul:
            if ext is not None:
                hdu = hdul[int(ext) if ext.isdigit() else ext]
            else:
                hdu = next((h for h in hdul if h.is_image and h.header.get("NAXIS", 0)),
                           None)
            found = None if hdu is None or not hdu.is_image else tuple(hdu.shape)
            if found == shape:
                return np.array(hdu.data, dtype=np.float64)
    except (OSError, KeyError, IndexError, ValueError) as err:
        raise ConfigError(f"{name}: cannot read {text}: {err}") from None
    if not found:
        raise ConfigError(f"{name}: {text} holds no image")
    raise ConfigError(f"{name}: a map of shape {found}; the array is {shape} "
                      "(rows, columns, physical order)")


@dataclass(frozen=True, eq=False)
class PixelMap:
    """One calibration value per pixel, or one for all.

    Attributes
    ----------
    values : float or `numpy.ndarray`
        A number, or float64 ``(nrows, ncols)`` in physical order (the data
        unit of the parameter: e.g. read noise in the unit of the pixels).
    label : str
        How it was given (the number, the file, or ``'array'``), for provenance.
    """

    values: object
    label: str

    @classmethod
    def of(cls, value, name, geometry, *, minimum=None, positive=False):
        """The map of a parameter's ``value`` for an array of ``geometry``.

        Parameters
        ----------
        value : float, str, `numpy.ndarray` or `~astropy.units.Quantity`
            One number, a FITS image path (``path`` or ``path[EXT]``) or an
            array ``(nrows, ncols)``.  A Quantity gives its value (the caller
            states the unit in the parameter's documentation).
        name : str
            The parameter, for messages (``fit_ramp.read_noise``).
        geometry : `~spherex_reduce.DetectorGeometry`
        minimum : float, optional
            Smallest allowed value.
        positive : bool
            Values must be > 0 (e.g. a gain).

        Raises
        ------
        ConfigError
            A file that cannot be read, a wrong shape, a value that is not
            finite or out of bounds: one line naming ``name``.
        """
        if isinstance(value, PixelMap):
            return value
        label = "array"
        if isinstance(value, (str, Path)):
            label = str(value)
            arr = _read_image(str(value), name, (geometry.nrows, geometry.ncols))
        else:
            arr = np.asarray(getattr(value, "value", value), dtype=np.float64)
            if arr.ndim == 0:
                label = f"{float(arr):g}"
        if arr.ndim not in (0, 2):
            raise ConfigError(f"{name}: a number or a 2-D map, got an array of shape {arr.shape}")
        shape = (geometry.nrows, geometry.ncols)
        if arr.ndim == 2 and arr.shape != shape:
            raise ConfigError(f"{name}: a map of shape {arr.shape}; the array is {shape} "
                              "(rows, columns, physical order)")
        if not np.isfinite(arr).all():
            raise ConfigError(f"{name}: {label} holds values that are not finite")
        low = float(arr.min())
        if minimum is not None and low < minimum:
            raise ConfigError(f"{name}: {label} must be >= {minimum:g}, has {low:g}")
        if positive and low <= 0:
            raise ConfigError(f"{name}: {label} must be > 0, has {low:g}")
        values = float(arr) if arr.ndim == 0 else arr
        if arr.ndim == 2 and (arr == arr.flat[0]).all():
            values = float(arr.flat[0])  # a uniform map is a number: the fast paths apply
        return cls(values, label)

    @property
    def per_pixel(self):
        """Whether the values differ from pixel to pixel."""
        return isinstance(self.values, np.ndarray)

    def rows(self, index, order, schedule):
        """The values of the rows ``index`` of a band: a number, or ``(len(index), ncols)``.

        ``index`` are read indices within a frame (``order='readout'``) or
        physical rows (``'physical'``).
        """
        if not self.per_pixel:
            return self.values
        index = np.asarray(index)
        rows = schedule.rows[index] if order == "readout" else index
        return self.values[rows]

    def __str__(self):
        if self.per_pixel:
            v = self.values
            return (f"{self.label} {v.shape[0]}x{v.shape[1]} map, median {np.median(v):.4g}, "
                    f"range {v.min():.4g}-{v.max():.4g}")
        return self.label
