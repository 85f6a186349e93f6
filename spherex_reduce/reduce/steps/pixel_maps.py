"""Calibration values that may differ from pixel to pixel: read noise, gain, dark current.

A step parameter such as ``fit_ramp``'s ``read_noise`` takes one number for
every pixel, a 2-D array (in Python), or the path of a FITS image (in YAML),
of the stored image's shape ``(nrows, ncols)`` (as the file of the pixels
holds them: the geometry's ``nrows`` and ``ncols``), in physical row order.
`PixelMap` holds the checked values, brought into the readout frame that the
steps work in (`~spherex_reduce.core.channel_layout.ChannelLayout.to_readout`:
transposed for ``channels: rows``, the quadrants side by side for
``quadrants``); `PixelMap.rows` gives those of the rows a band of the executor
holds, in the band's order (readout order: the physical row of each read, from
the schedule).  Every step that takes a map gets it from `PixelMap.of`, the
one place where a user's map meets the layout.

Maps are read with astropy (the first image HDU holding data, or the one named
``path[EXTNAME]``), checked (finite, within the parameter's bounds, the stored
image's shape) and held in float64.  A map's unit (its ``BUNIT``, or a
`~astropy.units.Quantity`'s unit) must be the parameter's, or convertible to
it: ADU and electrons with the gain (e⁻/ADU) when one is known (`adu_gain`);
a map without a unit is taken to be in the parameter's unit.

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

A map of a stored image whose outputs are bands of rows is the transpose of
the readout frame's:

>>> rows = DetectorGeometry(2, 4, 2, ref_border=0, channels="rows")
>>> PixelMap.of(np.arange(8.0).reshape(2, 4), "read_noise", rows.frame).values.tolist()
[[0.0, 4.0], [1.0, 5.0], [2.0, 6.0], [3.0, 7.0]]
"""

import re
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from astropy import units as u

from ...core.errors import ConfigError
from ...io.fits_structure import scan_hdus
from ...io.input import parse_unit

__all__ = ["MAP_TYPES", "PixelMap", "adu_gain"]

#: Types a per-pixel parameter accepts: a number, a FITS path (YAML) or an array (Python).
MAP_TYPES = (int, float, str, np.ndarray)

_EXT = re.compile(r"^(?P<path>.*)\[(?P<ext>[^\[\]]+)\]$")


def _read_image(text, name, shape):
    """The 2-D image of the FITS file ``text`` (``path`` or ``path[EXT]``), as float64, and
    its ``BUNIT`` (None when absent or empty); its shape is checked against ``shape`` from
    the header, before its data are read."""
    from astropy.io import fits

    match = _EXT.match(text)
    path, ext = (match["path"], match["ext"]) if match else (text, None)
    if not Path(path).is_file():
        raise ConfigError(f"{name}: no such FITS file: {path}")
    try:
        scan_hdus(path)  # truncated or damaged: our one line, not astropy's warning
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # astropy's guesses: the errors below say it
            with fits.open(path, memmap=False) as hdul:
                if ext is not None:
                    hdu = hdul[int(ext) if ext.isdigit() else ext]
                else:
                    hdu = next((h for h in hdul if h.is_image and h.header.get("NAXIS", 0)),
                               None)
                found = None if hdu is None or not hdu.is_image else tuple(hdu.shape)
                if found == shape:
                    bunit = str(hdu.header.get("BUNIT", "")).strip() or None
                    return np.array(hdu.data, dtype=np.float64), bunit
    except (OSError, KeyError, IndexError, ValueError, TypeError) as err:
        raise ConfigError(f"{name}: cannot read {text}: {err}") from None
    if not found:
        raise ConfigError(f"{name}: {text} holds no image")
    raise ConfigError(f"{name}: a map of shape {found}; the stored image is {shape} "
                      "(rows, columns)")


def adu_gain(unit, header, geometry, gain=None):
    """The gain (e⁻/ADU) relating a map in ADU to one in electrons for an input, or None.

    Parameters
    ----------
    unit : `astropy.units.UnitBase` or None
        The unit of the input's pixels.
    header : `astropy.io.fits.Header` or None
        The input's header: for data in electrons, the ``GAIN`` (or ``GAIN1``
        ...: one per channel) that ``input: gain`` applied to them.
    geometry : `~spherex_reduce.DetectorGeometry`
        The readout frame (its channels are the columns a per-channel gain covers).
    gain : `PixelMap`, optional
        For data in ADU: the step's ``gain`` (electrons per data unit).

    Returns
    -------
    float, `numpy.ndarray` or None
        One number, or an array broadcasting against the readout frame
        ``(nrows, ncols)``; None when no gain is known.

    Examples
    --------
    >>> from astropy import units as u
    >>> from astropy.io import fits
    >>> from spherex_reduce import DetectorGeometry
    >>> from spherex_reduce.reduce.steps.pixel_maps import PixelMap, adu_gain
    >>> g = DetectorGeometry(4, 4, 2, ref_border=0)
    >>> adu_gain(u.electron, fits.Header({"GAIN": 1.5}), g)
    1.5
    >>> adu_gain(u.electron, fits.Header({"GAIN1": 1.5, "GAIN2": 2.0}), g).tolist()
    [1.5, 1.5, 2.0, 2.0]
    >>> adu_gain(u.adu, None, g, PixelMap.of(1.8, "gain", g)), adu_gain(u.electron, None, g)
    (1.8, None)
    """
    if unit is None:
        return None
    if u.adu in unit.bases:
        return None if gain is None else gain.values
    if u.electron not in unit.bases or header is None:
        return None
    if isinstance(header.get("GAIN"), (int, float)) and not isinstance(header["GAIN"], bool):
        return float(header["GAIN"])
    per = [header.get(f"GAIN{i + 1}") for i in range(geometry.nchannels)]
    if all(isinstance(g, (int, float)) and not isinstance(g, bool) for g in per):
        return np.repeat(np.asarray(per, np.float64), geometry.channel_width)
    return None


def _in_unit(arr, given, unit, gain, name, label):
    """``arr`` (a map in ``given``) in ``unit``: the same numbers when it has no unit or the
    parameter's unit is not known, else converted (ADU and electrons with ``gain``, e⁻/ADU).
    """
    if given is None or unit is None or given == unit or given == u.one:
        return arr  # no unit (a bare number, a FITS map without BUNIT): the parameter's
    per_adu = u.electron / u.adu
    for factor, g in ((u.one, 1.0), (per_adu, gain),
                      (per_adu ** -1, None if gain is None else 1.0 / np.asarray(gain))):
        try:
            scale = (given * factor).to(unit)
        except u.UnitConversionError:
            continue
        if g is None:
            raise ConfigError(f"{name}: {label} is in {given}, the data in {unit}, and no "
                              "gain (e-/ADU) is known to convert it: give the map in "
                              f"{unit}")
        return arr * scale * g
    raise ConfigError(f"{name}: {label} is in {given}, not in a unit of the data ({unit})")


@dataclass(frozen=True, eq=False)
class PixelMap:
    """One calibration value per pixel, or one for all.

    Attributes
    ----------
    values : float or `numpy.ndarray`
        A number, or float64 ``(rows, columns)`` of the readout frame, in
        physical row order (the unit of the parameter: e.g. read noise in the
        unit of the pixels).
    label : str
        How it was given (the number, the file, or ``'array'``), for provenance.
    """

    values: object
    label: str

    @classmethod
    def of(cls, value, name, geometry, *, unit=None, gain=None, minimum=None, positive=False,
           allow_nan=False):
        """The map of a parameter's ``value`` for an array of ``geometry``.

        Parameters
        ----------
        value : float, str, `numpy.ndarray` or `~astropy.units.Quantity`
            One number, a FITS image path (``path`` or ``path[EXT]``) or an
            array ``(nrows, ncols)`` of the stored image (in the orientation
            the files hold the pixels).
        name : str
            The parameter, for messages (``fit_ramp.read_noise``).
        geometry : `~spherex_reduce.DetectorGeometry`
            The readout frame (a schedule's geometry) or the stored image; a map
            has the stored image's shape and is brought to the readout frame.
        unit : `astropy.units.UnitBase`, optional
            The parameter's unit.  A map with a unit (a FITS ``BUNIT``, a
            Quantity's) is converted to it; None: the map's numbers are taken
            as they are.
        gain : float or `numpy.ndarray`, optional
            e⁻/ADU (`adu_gain`), to convert a map between ADU and electrons.
        minimum : float, optional
            Smallest allowed value.
        positive : bool
            Values must be > 0 (e.g. a gain).
        allow_nan : bool
            A map may hold NaN (a pixel without a value, as a master dark's
            that no input could give); infinities are still refused.

        Raises
        ------
        ConfigError
            A file that cannot be read, a wrong shape, a unit that is not the
            parameter's (nor converted to it), a value that is not finite or
            out of bounds: one line naming ``name``.
        """
        if isinstance(value, PixelMap):
            return value
        label, given = "array", None
        stored = (geometry.stored_geometry.nrows, geometry.stored_geometry.ncols)
        if isinstance(value, (str, Path)):
            label = str(value)
            arr, bunit = _read_image(str(value), name, stored)
            if bunit is not None:
                try:
                    given = parse_unit(bunit)
                except ValueError:
                    raise ConfigError(f"{name}: {label} has BUNIT {bunit!r}, not a unit "
                                      "astropy understands") from None
        else:
            given = getattr(value, "unit", None)
            arr = np.asarray(getattr(value, "value", value), dtype=np.float64)
            if arr.ndim == 0:
                label = f"{float(arr):g}"
        if arr.ndim not in (0, 2):
            raise ConfigError(f"{name}: a number or a 2-D map, got an array of shape {arr.shape}")
        if arr.ndim == 2 and arr.shape != stored:
            raise ConfigError(f"{name}: a map of shape {arr.shape}; the stored image is "
                              f"{stored} (rows, columns)")
        if not (np.isfinite(arr) | (allow_nan & np.isnan(arr))).all():
            raise ConfigError(f"{name}: {label} holds values that are not finite")
        if allow_nan and arr.size and np.isnan(arr).all():
            raise ConfigError(f"{name}: {label} holds no value (every one NaN)")
        if arr.ndim == 2:
            arr = np.ascontiguousarray(geometry.layout.to_readout(arr))
        arr = _in_unit(arr, given, unit, gain, name, label)
        if arr.ndim == 1:  # a number converted with a gain per column
            arr = np.broadcast_to(arr, (geometry.frame.nrows, geometry.frame.ncols))
        low = float(np.nanmin(arr))
        if minimum is not None and low < minimum:
            raise ConfigError(f"{name}: {label} must be >= {minimum:g}, has {low:g}")
        if positive and low <= 0:
            raise ConfigError(f"{name}: {label} must be > 0, has {low:g}")
        values = float(arr) if arr.ndim == 0 else arr
        if arr.ndim == 2 and (arr == arr.flat[0]).all():  # (never with a NaN)
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
            nan = int(np.isnan(v).sum())
            return (f"{self.label} {v.shape[0]}x{v.shape[1]} map, median {np.nanmedian(v):.4g}, "
                    f"range {np.nanmin(v):.4g}-{np.nanmax(v):.4g}"
                    + (f", {nan} NaN" if nan else ""))
        return self.label
