"""Read a Roman WFI level-1 file (ASDF, as ``roman_datamodels`` writes it) as one ramp.

A Roman level-1 file (``ScienceRawModel``, the ``wfi_science_raw`` schema of
``rad``) is an ASDF file, not FITS.  It holds the *resultants* of one
exposure and says in its own metadata how they were read; `read_roman` reads
that metadata in its own meaning (none of it is taken as one of this package's
keywords) and returns the `~spherex_reduce.Exposure` a FITS file of the same
ramp would give:

- ``data`` ``(n_resultants, nrows, ncols)`` uint16 in DN, the reference border
  included: the ramp, each resultant one stored frame, in ``adu``
  (``input: gain`` makes it electrons).  It is read in the file's own (science)
  orientation.
- ``meta.exposure.read_pattern`` (the reads averaged into each resultant,
  counted from 1, the first read after the reset): the schedule's ``groups``,
  with the same numbers (read ``n`` is frame ``n``; frame 0, the reset, is never
  stored), so a resultant's time is the mean of its reads times the frame time,
  as romancal's ramp fit takes it.
- ``meta.exposure.frame_time`` (s): the frame time, as given.
- ``meta.instrument.detector`` (``WFI01`` ... ``WFI18``): which rows are read
  first.  Each detector is read row by row in its own frame, 32 outputs of
  ``ncols / 32`` columns side by side, every second output right to left
  (``scan: alternate``); the file stores the science orientation, in which the
  detector's columns are reversed for ``WFI03, 06, ... 18`` (rows still read
  from row 0) and its rows for the others (read from the last row: an explicit
  read ``order``), as romancal's ``frame_read_times`` states.  The
  4-pixel reference border is on every side.
- ``resultantdq`` (optional, per resultant): flags of another system, as the
  ``DQ`` of any foreign file (any bit masks, or ``input: dq_bits``).

The pixel clock is romancal's (4.915263 us a pixel, `ROMAN_PIXEL_RATE`), rows
back to back, the rest of the frame time after the last row: the times of
pixels within a frame are approximate (the guide-window reads between rows are
not modelled); slopes do not depend on them.  ``amp33`` (the 33rd output, a
reference channel read alongside the 32) and ``reference_read`` (a read
subtracted on board from every resultant: slopes are unchanged by it) are not
read.  An array of another size than 4096 x 4096 (a test stand-in) is read as
the same layout scaled: 32 outputs of ``ncols / 32`` columns.

Reading needs ``roman_datamodels`` (``pip install 'spherex_reduce[roman]'``),
imported only when a Roman file is read.
"""

import logging
import os
import re
import warnings
from pathlib import Path

import numpy as np
from astropy import units as u

from ...core.errors import FormatError
from ...core.exposure import Exposure
from ...core.geometry import DetectorGeometry
from ...core.limits import check_size
from ...core.readout.schedule import ReadoutSchedule
from ..header_text import header_text
from ..input import InputOptions, apply_gain
from .flags import file_flags, foreign_bits, note_foreign_dq

__all__ = ["ROMAN_PIXEL_RATE", "is_asdf_file", "read_roman", "roman_schedule"]

log = logging.getLogger(__name__)

#: Pixel rate of a WFI output (Hz): romancal's clock of 4.915263 us a pixel.
ROMAN_PIXEL_RATE = 1 / 4.915263e-6
#: Outputs of a WFI detector (amp33, the reference output, is not one of them).
ROMAN_OUTPUTS = 32
#: Reference pixels on every side of a WFI detector.
ROMAN_BORDER = 4
#: The first bytes of every ASDF file.
_ASDF_MAGIC = b"#ASDF "
_DETECTOR = re.compile(r"WFI(\d{2})")
_INSTALL = "pip install 'spherex_reduce[roman]'"


def is_asdf_file(path):
    """Whether ``path`` is an ASDF file (it starts with ``#ASDF``); False if it cannot be read.

    Examples
    --------
    >>> from spherex_reduce.io.readers.roman_l1 import is_asdf_file
    >>> is_asdf_file("no-such-file.asdf")
    False
    """
    try:
        with open(path, "rb") as f:
            return f.read(len(_ASDF_MAGIC)) == _ASDF_MAGIC
    except (OSError, TypeError, ValueError):
        return False


def roman_schedule(shape, read_pattern, frame_time, detector, name="file"):
    """The schedule of a Roman WFI level-1 ramp, from the file's own metadata.

    Parameters
    ----------
    shape : tuple of int
        ``data``'s shape ``(n_resultants, nrows, ncols)``.
    read_pattern : list of list of int
        ``meta.exposure.read_pattern``: the reads (from 1) of each resultant.
    frame_time : float
        ``meta.exposure.frame_time`` (s).
    detector : str
        ``meta.instrument.detector``, ``'WFI01'`` ... ``'WFI18'``.
    name : str
        Names the file in messages.

    Returns
    -------
    `~spherex_reduce.ReadoutSchedule`
        In the file's orientation: rows read from the last one (an explicit
        ``order``) unless the detector number is a multiple of 3.

    Raises
    ------
    FormatError
        A value that is missing, of the wrong kind or inconsistent with the
        data; one line naming the metadata entry.

    Examples
    --------
    >>> from spherex_reduce.io.readers.roman_l1 import roman_schedule
    >>> s = roman_schedule((3, 64, 64), [[1], [2, 3], [4, 5, 6, 7]], 3.04, "WFI03")
    >>> s.frame_starts.round(2), s.geometry.channel_width, s.rows[:2].tolist()
    (<Quantity [ 3.04,  7.6 , 16.72] s>, 2, [0, 1])
    >>> roman_schedule((3, 64, 64), [[1], [2, 3], [4, 5, 6, 7]], 3.04, "WFI01").rows[:2]
    array([63, 62])
    """
    if len(shape) != 3:
        raise FormatError(f"{name}: data has shape {tuple(shape)}; a Roman level-1 ramp is 3-D "
                          "(resultants, rows, columns)")
    nres, nrows, ncols = (int(n) for n in shape)
    if ncols % ROMAN_OUTPUTS:
        raise FormatError(f"{name}: data has {ncols} columns, not a multiple of the "
                          f"{ROMAN_OUTPUTS} outputs of a WFI detector")
    match = _DETECTOR.fullmatch(str(detector).strip())
    if match is None or not 1 <= int(match.group(1)) <= 18:
        raise FormatError(f"{name}: meta.instrument.detector is {detector!r}, not one of "
                          "WFI01 ... WFI18: which rows are read first depends on it")
    if isinstance(frame_time, bool) or not isinstance(frame_time, (int, float, np.number)) \
            or not np.isfinite(frame_time) or frame_time <= 0:
        raise FormatError(f"{name}: meta.exposure.frame_time is {frame_time!r}, not a time "
                          "> 0 (s)")
    groups = _pattern(read_pattern, name)
    if len(groups) != nres:
        raise FormatError(f"{name}: meta.exposure.read_pattern lists {len(groups)} resultants "
                          f"but data holds {nres}")
    # rows read from the last in the science orientation unless the columns are reversed
    order = None if int(match.group(1)) % 3 == 0 else list(range(nrows - 1, -1, -1))
    try:
        geometry = DetectorGeometry(nrows, ncols, ROMAN_OUTPUTS, ref_border=ROMAN_BORDER,
                                    scan="alternate", pixel_rate=ROMAN_PIXEL_RATE)
        rows = {"skip": 1, "ref_mode": "none"} if order is None else {"order": order}
        return ReadoutSchedule(geometry, phantom_reads=0, row_overhead=0, nframes=nres,
                               frame_time=float(frame_time), groups=groups, **rows)
    except ValueError as exc:
        raise FormatError(f"{name}: the Roman ramp's layout is not one this package can "
                          f"read: {exc}") from None


def _pattern(read_pattern, name):
    """``read_pattern`` as lists of int (checked by the schedule)."""
    try:
        groups = [[int(r) if isinstance(r, (int, np.integer)) and not isinstance(r, bool)
                   else None for r in reads] for reads in read_pattern]
    except TypeError:  # not lists
        groups = None
    if not groups or any(None in g or not g for g in groups):
        raise FormatError(f"{name}: meta.exposure.read_pattern must be a list of lists of "
                          f"read numbers, one list per resultant; got {_short(read_pattern)}")
    return groups


def _short(value, limit=60):
    text = repr(value)
    return text if len(text) <= limit else text[:limit] + "..."


def _open_model(path):
    """The file opened by roman_datamodels, and the warnings it gave while opening."""
    try:
        from roman_datamodels import datamodels
    except ImportError:
        raise FormatError(f"{path} is an ASDF file (Roman level 1); reading it needs "
                          f"roman_datamodels: {_INSTALL}") from None
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            model = datamodels.open(os.fspath(path))
        except Exception as exc:  # asdf and the schemas raise many kinds
            text = str(exc).strip().splitlines()
            raise FormatError(f"{path} is an ASDF file roman_datamodels cannot open as a Roman "
                              f"data model: {text[0] if text else type(exc).__name__}"
                              ) from None
    return model, sorted({str(w.message).splitlines()[0] for w in caught if str(w.message)})


def _array(model, key, path):
    """``model[key]`` read into memory, or None if the file has none."""
    try:
        node = model[key] if key in model else None
    except Exception:  # a damaged tree
        node = None
    if node is None:
        return None
    shape = getattr(node, "shape", None)
    if shape is None:
        raise FormatError(f"{path}: {key} is not an array")
    check_size(8.0 * np.prod(shape, dtype=float), f"{key} {tuple(shape)} of {path}")
    try:
        return np.array(node)
    except Exception as exc:  # a block cut short, a bad compression stream
        raise FormatError(f"{path}: {key} cannot be read: {exc}") from None


def _meta(model, dotted, path):
    """A metadata entry by its dotted path, or a one-line error naming it."""
    node = model
    for part in dotted.split("."):
        try:
            node = node[part]
        except Exception:
            raise FormatError(f"{path}: the file has no {dotted}: a Roman level-1 file states "
                              "it") from None
    return node


def read_roman(path, input=None, dq_bits=None, **supplied):
    """Read a Roman WFI level-1 ASDF file (``ScienceRawModel``) as one ramp.

    How the file's metadata are read is in the module's description.

    Parameters
    ----------
    path : str or `pathlib.Path`
        The ASDF file; never changed.
    input : dict or `~spherex_reduce.io.input.InputOptions`, optional
        As for `~spherex_reduce.io.read`: ``gain`` (e-/DN), ``drop_first_reads``
        (resultants left out), ``dq_bits`` (bits of ``resultantdq`` that mask),
        ``unit`` and ``header`` (``fill``: a config value that disagrees with
        the file is refused; ``override``: it replaces the file's).
    dq_bits : int, optional
        As for `~spherex_reduce.io.read` (default: ``input``'s, else every bit).
    **supplied
        ``geometry:``/``readout:`` values of a pipeline config: compared with
        the file's as ``input: header`` says (a Roman file needs none).

    Returns
    -------
    `~spherex_reduce.Exposure`
        Ramps in ``adu`` (float32), in physical (stored) row order.

    Raises
    ------
    FormatError
        ``roman_datamodels`` is not installed (naming the extra to install),
        the file is not a Roman level-1 file, or its metadata are missing,
        inconsistent or disagree with the config; one line.

    Examples
    --------
    >>> import tempfile, pathlib
    >>> from spherex_reduce.io.readers.roman_l1 import read_roman
    >>> read_roman(pathlib.Path(tempfile.mkdtemp()) / "none.asdf")
    Traceback (most recent call last):
    ...
    FileNotFoundError: no such file: ...none.asdf
    """
    options = InputOptions.from_config(input)
    if not Path(path).is_file():
        raise FileNotFoundError(f"no such file: {path}")
    if options.reads is not None:
        raise FormatError(f"{path}: input.reads is {options.reads}, but a Roman level-1 file "
                          "holds its resultants as one 3-D array; leave input.reads out")
    model, warned = _open_model(path)
    try:
        kind = type(model).__name__
        if kind != "ScienceRawModel":
            raise FormatError(f"{path} is a Roman {kind}, not a level-1 ScienceRawModel: this "
                              "package reduces level-1 ramps (resultants)")
        data = _array(model, "data", path)
        if data is None or data.ndim != 3 or data.dtype.kind not in "iu":
            raise FormatError(f"{path}: data must be a 3-D integer array of resultants, got "
                              f"{'none' if data is None else f'{data.dtype} {data.shape}'}")
        base = roman_schedule(data.shape, _meta(model, "meta.exposure.read_pattern", path),
                              _meta(model, "meta.exposure.frame_time", path),
                              _meta(model, "meta.instrument.detector", path), path)
        nres = _meta(model, "meta.exposure.nresultants", path)
        if nres != data.shape[0]:
            raise FormatError(f"{path}: meta.exposure.nresultants is {nres!r} but data holds "
                              f"{data.shape[0]} resultants")
        flags = _array(model, "resultantdq", path)
        described = _described(model, path, base)
    finally:
        model.close()
    for text in warned:
        log.warning("%s: roman_datamodels: %s", path, text)
    return _exposure(path, data, flags, base, described, options, dq_bits, supplied)


def _described(model, path, schedule):
    """The header cards that say where the ramp came from (the file's own words)."""
    detector = str(model["meta"]["instrument"]["detector"])
    cards = [("TELESCOP", "ROMAN", "Roman Space Telescope"),
             ("INSTRUME", "WFI", "Wide Field Instrument"),
             ("DETECTOR", detector, "WFI detector (meta.instrument.detector)")]
    for key, dotted, comment in (("MATABLE", "ma_table_name", "multi-accumulation table"),
                                 ("MATABNUM", "ma_table_number", "multi-accumulation table")):
        try:
            value = model["meta"]["exposure"][dotted]
        except Exception:
            continue
        if isinstance(value, (str, int)) and not isinstance(value, bool):
            cards.append((key, header_text(str(value))[:68] if isinstance(value, str) else value,
                          comment))
    history = (f"ramp of the Roman level-1 file {header_text(Path(path).name)}: "
               f"{schedule.nframes} resultants, read pattern as groups "
               f"(reads from 1), frame time {schedule.frame_time.to_value(u.s):g} s")
    return cards, history


def _exposure(path, data, stored_flags, base, described, options, dq_bits, supplied):
    """The exposure of the file's arrays, with the ``input:`` section and config applied."""
    header = base.to_header()
    header.remove("FRMOVH", ignore_missing=True)  # TFRAME states it exactly
    cards, history = described
    for key, value, comment in cards:
        header[key] = (value, comment)
    header.add_history(history)
    notes = []
    derived = options.reconcile(header, supplied, path, notes)
    table = base.to_table() if base.order is not None else None
    try:
        schedule = ReadoutSchedule.from_header(
            header, table, **{k: v for k, v in supplied.items() if k not in derived})
    except FormatError as exc:
        raise FormatError(f"{path}: {exc} (a Roman file states its own layout: the config "
                          "needs no geometry: or readout: section)") from None
    options.check_derived(schedule, derived, supplied, path)
    unit = options.unit_of("DN", header, path, notes)
    drop, kept = options.frames(header, schedule, True, path)
    gain, unit = options.gains(unit, header, schedule.geometry.nchannels, path, notes)
    check_size(4.0 * data.size, f"the resultants of {path} {data.shape} as float32")
    values = apply_gain(data[drop:].astype(np.float32), gain, schedule.geometry)
    mask = None
    if stored_flags is not None:
        if stored_flags.shape != data.shape:
            raise FormatError(f"{path}: resultantdq has shape {stored_flags.shape}, data "
                              f"{data.shape}: one flag per pixel of every resultant")
        bits = foreign_bits(options.dq_bits if dq_bits is None else dq_bits)
        mask = file_flags(stored_flags[drop:], values.shape, kept, "physical", bits, path)
        note_foreign_dq(header, bits, path)
    for array in (values, mask):
        if array is not None and array.flags.writeable:
            array.setflags(write=False)
    result = Exposure.from_arrays(values, kept, unit=unit, mask=mask, header=header,
                                  order="physical")
    for note in notes:
        log.warning("%s", note)
    return result
