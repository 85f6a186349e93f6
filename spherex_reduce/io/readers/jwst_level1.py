"""JWST level-1 files read in their own meaning: `JWSTLevel1`.

A file whose primary header says ``TELESCOP = 'JWST'`` (an ``uncal`` file as
``stdatamodels`` writes it, a ``RampModel``, a dark reference file) is never
read with this package's keywords: its ``NFRAMES`` counts the frames averaged
into a group, its ``FASTAXIS``/``SLOWAXIS`` are signed axis numbers.  Its own
keywords give the schedule:

- **layout**: the SIDECAR ASIC's 4 outputs of 512 columns on the 2048 x 2048
  array (`~spherex_reduce.core.presets.PRESETS` ``SIDECAR``: 100 kHz, a
  4-pixel reference border, alternating fast-scan direction), in the
  detector's orientation.  ``SCI`` is stored in the DMS (science) orientation;
  ``FASTAXIS`` and ``SLOWAXIS`` (+-1: along the stored columns, +-2: along the
  rows; negative: toward decreasing index) say how to bring it to the
  detector's, where the fast scan runs along the rows toward increasing
  column and row 0 is read first.  A subarray (``SUBSTRT1/2``,
  ``SUBSIZE1/2``, in the full array's DMS pixels from 1) is a window of the
  full array: its channels, their scan directions and its reference pixels are
  those of the full array's it covers (`~spherex_reduce.core.window.Window`),
  and ``NOUTPUTS`` = 1 makes it one channel.  Each row read costs its
  columns per output plus 12 pixel times (the JWST frame time is
  ``(columns / outputs + 12) x (rows + 1) x 10 us``); ``TFRAME`` is the frame
  time, taken as given.
- **groups**: ``NGROUPS`` groups (``SCI``'s second-last-but-one axis) of
  ``NFRAMES`` frames averaged, ``GROUPGAP`` frames dropped between groups
  (``frames_per_group`` and ``group_gap``, :ref:`readout-groups`).
- **flags**: ``PIXELDQ`` (every group), ``GROUPDQ`` (each group), or a
  reference file's ``DQ``, in JWST's bits (`JWST_DQ`): ``DO_NOT_USE`` masks,
  ``SATURATED``, ``JUMP_DET`` and ``REFERENCE_PIXEL`` become ours; JWST's
  other bits inform only (JWST's own ramp fit masks ``DO_NOT_USE`` alone)
  unless ``input: dq_bits`` (or ``--dq-bits``) names them, which then mask.
- **unit**: ``BUNIT``, else ``DN`` (ADU): level-1 data are the ASIC's numbers.

The slopes are in the detector orientation; the output header keeps the
file's JWST keywords (not ``DATAMODL`` and ``FILENAME``: it is not that
file), the file's ``FASTAXIS``/``SLOWAXIS`` as ``JWFASTAX``/``JWSLOWAX`` and
the data's first detector column and row (from 1) as ``JWSTRT1``/``JWSTRT2``.
``ERR``, ``ZEROFRAME`` and the tables (``GROUP``,
``INT_TIMES``, ``ASDF``) are not read.  NIRSpec's IRS2 readout (reference
pixels interleaved in the rows) and MIRI are refused in one line; so is a
keyword the schedule needs that the file lacks and the config does not give.
"""

import logging

import numpy as np
from astropy import units as u

from ...core import dq
from ...core.errors import FormatError
from ...core.exposure import Exposure
from ...core.fields import FIELD, FIELDS, header_keyword
from ...core.geometry import DetectorGeometry
from ...core.presets import PRESETS
from ...core.readout.schedule import ReadoutSchedule
from ...core.window import Window
from ..input import InputOptions, scale_columns
from ..layout import integration_shape, is_jwst
from .description import image_shape
from .fits_read import CheckedFITS, Closing
from .flags import DEFAULT_DQ_BITS, current_dq_bits, flag_bits

__all__ = ["JWST_DQ", "JWST_PIXEL", "JWSTLevel1", "detector_view", "dms_keywords", "dms_view",
           "remove_readout_keywords"]

log = logging.getLogger(__name__)

#: The JWST pixel flags read and written here (``stdatamodels.jwst.datamodels.dqflags.pixel``).
JWST_PIXEL = {
    "DO_NOT_USE": 2**0,
    "SATURATED": 2**1,
    "JUMP_DET": 2**2,
    "DROPOUT": 2**3,
    "OUTLIER": 2**4,
    "OTHER_BAD_PIXEL": 2**30,
    "REFERENCE_PIXEL": 2**31,
}

#: JWST's ``DQ`` bits that have a meaning here, and the `spherex_reduce.core.dq` bit each
#: becomes.
JWST_DQ = {JWST_PIXEL["DO_NOT_USE"]: dq.DO_NOT_USE,
           JWST_PIXEL["SATURATED"]: dq.SATURATED,
           JWST_PIXEL["JUMP_DET"]: dq.JUMP,
           JWST_PIXEL["REFERENCE_PIXEL"]: dq.REFERENCE}
#: The instruments on SIDECAR-read H2RGs.
H2RG_INSTRUMENTS = ("NIRCAM", "NIRISS", "NIRSPEC", "FGS")
#: Pixel times of overhead per row read (the JWST frame time's ``+ 12``).
ROW_OVERHEAD = 12
_SIDECAR = PRESETS["SIDECAR"]
FULL = _SIDECAR["nrows"]
#: Our schedule values that are the same for every JWST H2RG file: rows read once, in
#: order, no reference reads, no phantom samples.
_FIXED = {"channels": "columns", "skip": 1, "ref_reads": 0, "ref_mode": "none",
          "phantom_reads": 0, "row_overhead": ROW_OVERHEAD}
#: The JWST keyword each readout value comes from (for the messages).
_SOURCE = {"nframes": "NGROUPS", "frames_per_group": "NFRAMES", "group_gap": "GROUPGAP",
           "frame_time": "TFRAME"}


def detector_view(array, fast, slow):
    """A view of ``array`` (``(..., rows, columns)`` in the DMS orientation) in the
    detector's: fast scan along the rows toward increasing column, row 0 read first.

    Parameters
    ----------
    array : `numpy.ndarray`
    fast, slow : int
        ``FASTAXIS`` and ``SLOWAXIS``: 1 (columns, i.e. FITS axis 1) or 2 (rows),
        negative when the readout runs toward decreasing index.

    Examples
    --------
    NIRSpec's NRS1 (``FASTAXIS = 2``, ``SLOWAXIS = 1``) is the transpose;
    NIRCam's NRCA1 (-1, 2) is flipped left to right:

    >>> import numpy as np
    >>> from spherex_reduce.io.readers.jwst_level1 import detector_view
    >>> a = np.arange(6).reshape(2, 3)
    >>> detector_view(a, 2, 1).tolist(), detector_view(a, -1, 2).tolist()
    ([[0, 3], [1, 4], [2, 5]], [[2, 1, 0], [5, 4, 3]])
    """
    out = np.swapaxes(array, -1, -2) if abs(fast) == 2 else array
    if fast < 0:
        out = out[..., :, ::-1]
    if slow < 0:
        out = out[..., ::-1, :]
    return out


def remove_readout_keywords(header):
    """Remove from ``header`` (in place) every keyword of this package's readout (its
    `~spherex_reduce.core.fields.FIELDS`, ``CHANW``, ``ORDER``): in a JWST header the same
    names mean other things (``NFRAMES`` the frames per group, ``FASTAXIS`` an axis).

    Examples
    --------
    >>> from astropy.io import fits
    >>> from spherex_reduce.io.readers.jwst_level1 import remove_readout_keywords
    >>> h = fits.Header({"NFRAMES": 4, "FASTAXIS": "columns", "TELESCOP": "JWST"})
    >>> remove_readout_keywords(h)
    >>> list(h)
    ['TELESCOP']
    """
    for key in (*(k for f in FIELDS for k in f.keywords), "CHANW", "ORDER"):
        header.remove(key, ignore_missing=True, remove_all=True)


def dms_view(array, fast, slow):
    """``array`` in the detector orientation brought back to the DMS one: the inverse of
    `detector_view` (what a JWST product of a JWST input is written in).

    Examples
    --------
    >>> import numpy as np
    >>> from spherex_reduce.io.readers.jwst_level1 import detector_view, dms_view
    >>> a = np.arange(6).reshape(2, 3)
    >>> all(np.array_equal(dms_view(detector_view(a, f, s), f, s), a)
    ...     for f, s in ((1, 2), (-1, 2), (1, -2), (2, 1), (-2, -1), (2, -1)))
    True
    """
    out = array[..., ::-1, :] if slow < 0 else array
    if fast < 0:
        out = out[..., :, ::-1]
    return np.swapaxes(out, -1, -2) if abs(fast) == 2 else out


def dms_keywords(header, shape):
    """The JWST keywords of a JWST input that its reader turned into ours, in JWST's
    meaning again: ``FASTAXIS``, ``SLOWAXIS`` and the subarray (``SUBSTRT1/2``,
    ``SUBSIZE1/2``, DMS pixels from 1) of data of ``shape`` (rows, columns, detector
    orientation), or an empty dict for a header without ``JWFASTAX`` (not a JWST input).

    Examples
    --------
    >>> from astropy.io import fits
    >>> from spherex_reduce.io.readers.jwst_level1 import dms_keywords
    >>> h = fits.Header({"JWFASTAX": 2, "JWSLOWAX": 1, "JWSTRT1": 1, "JWSTRT2": 3})
    >>> dms_keywords(h, (64, 32))  # NRS1: the transpose
    {'FASTAXIS': 2, 'SLOWAXIS': 1, 'SUBSTRT1': 3, 'SUBSTRT2': 1, 'SUBSIZE1': 64, 'SUBSIZE2': 32}
    """
    if "JWFASTAX" not in header:
        return {}
    fast, slow = int(header["JWFASTAX"]), int(header["JWSLOWAX"])
    (y0, x0), (ny, nx) = (int(header["JWSTRT2"]) - 1, int(header["JWSTRT1"]) - 1), shape
    if slow < 0:
        y0 = FULL - y0 - ny
    if fast < 0:
        x0 = FULL - x0 - nx
    if abs(fast) == 2:
        (x0, nx), (y0, ny) = (y0, ny), (x0, nx)
    return {"FASTAXIS": fast, "SLOWAXIS": slow, "SUBSTRT1": x0 + 1, "SUBSTRT2": y0 + 1,
            "SUBSIZE1": nx, "SUBSIZE2": ny}


def _detector_window(fast, slow, start, size):
    """``(first_row, first_column), (rows, columns)`` in the detector orientation of a
    subarray at DMS ``start`` (x, y from 0) of ``size`` (x, y)."""
    (x0, y0), (nx, ny) = start, size
    if abs(fast) == 2:
        (x0, nx), (y0, ny) = (y0, ny), (x0, nx)
    if fast < 0:
        x0 = FULL - x0 - nx
    if slow < 0:
        y0 = FULL - y0 - ny
    return (y0, x0), (ny, nx)


def _value(schedule, name):
    """A field's value of ``schedule`` in a comparable form."""
    g = schedule.geometry
    value = getattr(g if FIELD[name].section == "geometry" else schedule, name)
    if name == "ref_border":
        return g.border.sides()
    if isinstance(value, u.Quantity):
        return float(value.to_value(FIELD[name].unit))
    return tuple(value) if isinstance(value, (list, tuple, np.ndarray)) else value


def _build(values):
    geometry = DetectorGeometry(**{k: v for k, v in values.items()
                                   if FIELD[k].section == "geometry"})
    return ReadoutSchedule(geometry, **{k: v for k, v in values.items()
                                        if FIELD[k].section == "readout"})


class JWSTLevel1(Closing):
    """A JWST level-1 file (``TELESCOP = 'JWST'``), opened and checked (`CheckedFITS`).

    Use it as a context manager.  ``integrations`` is the number of a 4-D
    ``SCI`` (None for a 3-D one, e.g. a dark reference file); `exposure` reads
    one integration's ramps in the detector orientation, its schedule from the
    file's own keywords (see the module).

    Parameters
    ----------
    path : str or `pathlib.Path`
    verify_checksum : bool, optional
        As for `~spherex_reduce.io.read`.

    Raises
    ------
    FormatError
        Not a JWST file of an H2RG instrument, no ``SCI`` of 3 or 4 dimensions, IRS2.
    """

    def __init__(self, path, verify_checksum=None):
        self.path, self._file = path, CheckedFITS(path, verify_checksum)
        self._warned = set()
        try:
            self._check()
        except BaseException:
            self._file.close()
            raise

    def _check(self):
        hdul, path = self._file.hdul, self.path
        header = hdul[0].header
        if not is_jwst(header):
            raise FormatError(f"{path}: not a JWST file (TELESCOP is not 'JWST')")
        instrument = str(header.get("INSTRUME", "")).strip().upper()
        if instrument not in H2RG_INSTRUMENTS:
            raise FormatError(f"{path}: INSTRUME={instrument or None!r}: only the JWST H2RG "
                              f"instruments ({', '.join(H2RG_INSTRUMENTS)}) are read")
        pattern = str(header.get("READPATT", "")).strip().upper()
        if "IRS2" in pattern:
            raise FormatError(f"{path}: READPATT={pattern!r}: NIRSpec's IRS2 readout "
                              "interleaves reference pixels in the rows, which is not read; "
                              "reduce a file in a traditional readout pattern")
        names = [h.name for h in hdul]
        if "SCI" not in names:
            raise FormatError(f"{path}: a JWST file without a SCI extension")
        self.sci = hdul["SCI"]
        shape = image_shape(self.sci)
        if len(shape) not in (3, 4):
            raise FormatError(f"{path}: SCI has shape {shape}: a JWST level-1 file holds ramps "
                              "(groups, rows, columns) or integrations of them (4-D)")
        self.shape = shape
        self.integrations = shape[0] if len(shape) == 4 else None
        if self.integrations is not None and "NINTS" in header and int(
                header_keyword(header, "NINTS", int, 1)) < shape[0]:
            raise FormatError(f"{path}: SCI holds {shape[0]} integrations but NINTS = "
                              f"{header['NINTS']}")

    def close(self):
        """Close the file."""
        self._file.close()

    # -- the schedule ----------------------------------------------------------------
    def _orientation(self, header):
        path = self.path
        axes = []
        for key in ("FASTAXIS", "SLOWAXIS"):
            if key not in header:
                raise FormatError(f"{path}: keyword {key} is missing: the detector orientation "
                                  "of a JWST file (FASTAXIS, SLOWAXIS) cannot be known without it")
            value = header_keyword(header, key, int)
            if value not in (1, -1, 2, -2):
                raise FormatError(f"{path}: keyword {key} = {value}: JWST's readout axes are "
                                  "+-1 or +-2")
            axes.append(value)
        if abs(axes[0]) == abs(axes[1]):
            raise FormatError(f"{path}: FASTAXIS = {axes[0]} and SLOWAXIS = {axes[1]} name the "
                              "same axis")
        return tuple(axes)

    def _window(self, header, fast, slow, stored):
        """The subarray's start and size in the detector orientation."""
        path = self.path
        ny, nx = stored
        keys = ("SUBSTRT1", "SUBSTRT2", "SUBSIZE1", "SUBSIZE2")
        if not any(k in header for k in keys) and (ny, nx) == (FULL, FULL):
            start, size = (0, 0), (FULL, FULL)
        else:
            missing = [k for k in keys if k not in header]
            if missing:
                raise FormatError(f"{path}: keyword(s) {', '.join(missing)} missing: where the "
                                  f"{ny} x {nx} subarray lies on the {FULL} x {FULL} array "
                                  "cannot be known")
            x0, y0, sx, sy = (header_keyword(header, k, int, 1) for k in keys)
            if (sy, sx) != (ny, nx):
                raise FormatError(f"{path}: SCI is {ny} x {nx} (rows x columns) but SUBSIZE2 x "
                                  f"SUBSIZE1 is {sy} x {sx}")
            if x0 - 1 + sx > FULL or y0 - 1 + sy > FULL:
                raise FormatError(f"{path}: the subarray (SUBSTRT1/2 = {x0}, {y0}, SUBSIZE1/2 = "
                                  f"{sx}, {sy}) does not fit the {FULL} x {FULL} array")
            start, size = (x0 - 1, y0 - 1), (sx, sy)
        return _detector_window(fast, slow, start, size)

    def _geometry(self, header, first, size):
        full = DetectorGeometry(**{k: v for k, v in _SIDECAR.items() if FIELD[k].section
                                   == "geometry"})
        g = Window(*first, full).geometry(*size)
        outputs = header_keyword(header, "NOUTPUTS", int, 1, default=g.nchannels)
        values = {"nrows": size[0], "ncols": size[1], "nchannels": g.nchannels,
                  "ref_border": g.border.sides(), "scan": list(g.scan),
                  "pixel_rate": full.pixel_rate}
        if outputs != g.nchannels:
            if outputs != 1:
                raise FormatError(f"{self.path}: NOUTPUTS = {outputs}, but the subarray (rows "
                                  f"{first[0]}-{first[0] + size[0] - 1}, columns {first[1]}-"
                                  f"{first[1] + size[1] - 1} on the detector) covers "
                                  f"{g.nchannels} of the SIDECAR's outputs of 512 columns")
            values.update(nchannels=1, scan=[1])  # one output: FASTAXIS's direction
        return values

    def _readout(self, header, ngroups):
        path = self.path
        found = {"nframes": ngroups}
        if "NGROUPS" in header and header_keyword(header, "NGROUPS", int, 1) != ngroups:
            raise FormatError(f"{path}: SCI holds {ngroups} groups but NGROUPS = "
                              f"{header['NGROUPS']}")
        for name, key in _SOURCE.items():
            if name != "nframes" and key in header:
                kind = float if name == "frame_time" else int
                found[name] = header_keyword(header, key, kind, positive=kind is float,
                                             minimum=0 if kind is int else None)
        if "frames_per_group" in found and found["frames_per_group"] < 1:
            raise FormatError(f"{path}: keyword NFRAMES = {found['frames_per_group']}: a group "
                              "averages at least one frame")
        if {"frame_time", "frames_per_group", "group_gap"} <= set(found) and "TGROUP" in header:
            tgroup = header_keyword(header, "TGROUP", float, positive=True)
            expected = (found["frames_per_group"] + found["group_gap"]) * found["frame_time"]
            if not np.isclose(tgroup, expected, rtol=1e-4, atol=1e-4):
                raise FormatError(f"{path}: TGROUP = {tgroup} s but (NFRAMES + GROUPGAP) x "
                                  f"TFRAME = {expected:.6g} s")
        return found

    def schedule(self, supplied, options, notes):
        """The file's schedule (the config's ``supplied`` values fill what it lacks, or with
        ``input: header: override`` replace what it says) and the orientation
        ``(FASTAXIS, SLOWAXIS)``."""
        path, header = self.path, self._file.hdul[0].header
        stray = [k for k, v in supplied.items() if v is not None and k not in FIELD]
        if stray:
            raise FormatError(f"unknown readout parameter(s) {sorted(stray)}")
        fast, slow = self._orientation(header)
        first, size = self._window(header, fast, slow, self.shape[-2:])
        found = {**self._geometry(header, first, size), **_FIXED,
                 **self._readout(header, self.shape[-3])}
        foreign = [f"{FIELD[k].section}.{k}" for k, v in supplied.items()
                   if v is not None and k not in found and k not in _SOURCE]
        if foreign:
            raise FormatError(f"{path}: {', '.join(sorted(foreign))} does not apply to a JWST "
                              "file, whose layout comes from its header (FASTAXIS, SLOWAXIS, "
                              "SUBSTRT1/2, SUBSIZE1/2, NOUTPUTS): remove it from the config")
        given = {k: v for k, v in supplied.items() if v is not None}
        lacking = [n for n in _SOURCE if n not in found and n not in given]
        if lacking:
            raise FormatError(f"{path}: keyword(s) {', '.join(_SOURCE[n] for n in lacking)} "
                              "missing from the JWST file: give readout."
                              f"{', readout.'.join(lacking)} in the config")
        try:
            mine = _build({**found, **{k: v for k, v in given.items() if k not in found}})
            theirs = _build({**found, **given})
        except ValueError as exc:
            raise FormatError(f"{path}: the JWST file's readout is not a valid schedule: "
                              f"{exc}") from None
        for name in given:
            if name not in found or _value(mine, name) == _value(theirs, name):
                continue
            have = _value(mine, name)
            have = f"{have:.10g}" if isinstance(have, float) else have
            key = _SOURCE.get(name, "the layout (FASTAXIS, SUBSTRT, NOUTPUTS)")
            shown = f"{FIELD[name].section}.{name}"
            if options.header == "fill":
                raise FormatError(f"{path}: {key} gives {name} = {have} but "
                                  f"{shown} is {given[name]} in the config; remove it from "
                                  "the config (a JWST file states it), or set input.header: "
                                  "override to use the config's")
            notes.append(f"{path}: {name} = {have} from {key} replaced by the "
                         f"config's {given[name]} (input.header: override)")
        return (theirs if options.header == "override" else mine), (fast, slow), first

    # -- the pixels ------------------------------------------------------------------
    def _flags(self, integration, bits, view):
        """Our flags of one integration ``(groups, rows, columns)`` (uint32, detector
        orientation), or None if the file has none."""
        hdul, path = self._file.hdul, self.path
        names = [h.name for h in hdul]
        parts = []
        for name in ("PIXELDQ", "GROUPDQ", "DQ"):
            if name not in names or hdul[name].header.get("NAXIS", 0) == 0:
                continue
            stored = self._file.physical(hdul[name], flags=True, index=(
                integration if len(image_shape(hdul[name])) == 4 else None))
            if stored.shape[-2:] != tuple(self.shape[-2:]) or stored.ndim > 3 or (
                    stored.ndim == 3 and stored.shape[0] != self.shape[-3]):
                raise FormatError(f"{path}: {name} has shape {image_shape(hdul[name])}, SCI "
                                  f"{self.shape}: JWST's flags are one image (PIXELDQ, DQ) or "
                                  "one per group (GROUPDQ)")
            stored = flag_bits(stored, path)
            ours = np.zeros(stored.shape, dq.DQ_TYPE)
            for jbit, bit in JWST_DQ.items():
                if jbit > np.iinfo(stored.dtype).max:  # GROUPDQ is uint8
                    continue
                ours[(stored & np.asarray(jbit, stored.dtype)) != 0] |= bit
            if bits is not None:
                ours[(stored & np.asarray(bits).astype(stored.dtype)) != 0] |= dq.DO_NOT_USE
            parts.append(ours)
        if not parts:
            return None
        flags = np.zeros(self.shape[-3:], dq.DQ_TYPE)
        for part in parts:
            flags |= part
        return np.ascontiguousarray(view(flags))

    def exposure(self, dq_bits=None, input=None, integration=None, **supplied):
        """Integration ``integration`` (from 0; None for a 3-D ``SCI``) as an
        `~spherex_reduce.Exposure` of ramps in the detector orientation.

        ``dq_bits`` (or ``input``'s): JWST bits that also mask (as
        ``DO_NOT_USE``); ``input``: the ``input:`` section; ``supplied``: the
        config's ``geometry:``/``readout:`` values (see `schedule`).
        """
        options = InputOptions.from_config(input)
        path = self.path
        integration_shape(self.shape, integration, path)
        notes = []
        schedule, (fast, slow), first = self.schedule(supplied, options, notes)
        header = self._file.hdul[0].header.copy()
        remove_readout_keywords(header)  # the file's keywords are JWST's: never read as ours
        for key in ("CHECKSUM", "DATASUM", "NEXTEND", "DATAMODL", "FILENAME"):
            header.remove(key, ignore_missing=True)
        header["JWFASTAX"] = (fast, "JWST input's FASTAXIS; data: detector's")
        header["JWSLOWAX"] = (slow, "JWST input's SLOWAXIS; data: detector's")
        header["JWSTRT1"] = (first[1] + 1, "first detector column of the data (from 1)")
        header["JWSTRT2"] = (first[0] + 1, "first detector row of the data (from 1)")
        header.add_history("read as a JWST level-1 file: NGROUPS -> NFRAMES, NFRAMES -> "
                           "NFRGRP, GROUPGAP -> NFRGAP; DMS orientation -> detector's")
        self._file.note_bad_checksums(header)
        bunit = self.sci.header.get("BUNIT", self._file.hdul[0].header.get("BUNIT", "DN"))
        unit = options.unit_of(str(bunit), header, path, notes)
        drop, kept = options.frames(header, schedule, True, path)
        gain, unit = options.gains(unit, header, schedule.geometry.nchannels, path, notes)
        if integration is not None:
            header["SXRINT"] = (integration, "integration of the input's 4-D SCI (from 0)")
        bits = dq_bits if dq_bits is not None else options.dq_bits
        if bits is None and current_dq_bits() != DEFAULT_DQ_BITS:
            bits = current_dq_bits()

        def view(a):
            return detector_view(a, fast, slow)

        data = np.ascontiguousarray(view(self._file.physical(self.sci, index=integration)))
        flags = self._flags(integration, bits, view)
        if drop:
            data = data[drop:]
            flags = None if flags is None else flags[drop:]
        if gain is not None:
            data = data * scale_columns(gain, kept.geometry, data.dtype)
        header = kept.to_header(header)
        exposure = Exposure.from_arrays(data, kept, unit=unit, mask=flags, header=header,
                                        order="readout")
        for note in notes:
            if note not in self._warned:
                self._warned.add(note)
                log.warning("%s", note)
        return exposure
