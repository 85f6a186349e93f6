"""Read and write exposures as FITS.

Layout (extension names):

``PRIMARY``
    No data; the readout keywords (`ReadoutSchedule.to_header`), ``BUNIT``,
    ``ORDER`` (``READOUT`` or ``PHYSICAL``) and the provenance of every step.
``SCI``
    Pixels: ramps ``(frames, reads, columns)`` or a 2-D image, in the order
    ``ORDER`` says.
``ERR``, ``DQ``
    Standard deviation and data-quality flags (`spherex_reduce.dq`), if any.
``PHANTOM``
    Phantom values, ``(frames, reads, channels)`` or ``(reads, channels)``.
``READOUT``
    One row per read of a frame: ``row kind start time``; cross-checked
    against the header keywords on read.
``REFPIX``, ``REFPHANT``, ``REFDQ``, ``REFREADS``
    Reference reads kept aside by ``unchop`` (pixels, phantoms, flags, and a
    table ``read row time``).

Any other table extension holds a table recorded by a step (e.g. ``REFOFFS``).

Writes go to a temporary file in the target directory, with FITS checksums
and ``NEXTEND`` (the number of extensions) in the primary header, and are
renamed into place only when complete; an existing file is kept unless
``overwrite=True``.

Reads check the file before trusting it: every header must end and every data
block must fit in the file (a truncated file is named as such), ``NEXTEND``
extensions must be present, and ``CHECKSUM``/``DATASUM`` are verified where
present (see `checksum_policy` to read a damaged file anyway).  Integer data
with ``BSCALE``/``BZERO``/``BLANK`` are scaled to floating point on read (the
file is never changed).
"""

import contextlib
import contextvars
import glob
import hashlib
import logging
import math
import mmap
import os
import re
import socket
import tempfile
import warnings
from pathlib import Path

import numpy as np
from astropy import units as u
from astropy.io import fits
from astropy.nddata import StdDevUncertainty
from astropy.table import Table

from .errors import FormatError
from .exposure import Exposure, ReferenceReads, expected_shape
from .limits import check_size
from .schedule import ReadoutSchedule, _card_text, header_keyword

__all__ = ["CheckedFITS", "FrameReader", "atomic_output", "checksum_policy", "is_raw_ramp_file",
           "open_checked", "read", "write"]

log = logging.getLogger(__name__)

_RESERVED = {"PRIMARY", "SCI", "ERR", "DQ", "PHANTOM", "READOUT", "REFPIX", "REFPHANT", "REFDQ",
             "REFREADS"}


class atomic_output:
    """Context manager giving a temporary path that is renamed to ``path`` on success.

    Refuses to start if ``path`` exists and ``overwrite`` is False, or names a
    directory, so nothing is computed only to be thrown away.  On error
    (including an interrupt) the temporary file is removed and an existing
    ``path`` is left untouched.  The temporary file, ``.NAME.HOST-PID.XXXX.tmp``
    in the target directory, carries a tag of the writer's host and its process
    id: temporary files for ``path`` left by a process of this host that no
    longer runs (killed outright) are removed when the next write of ``path``
    starts; those of other hosts (a shared file system) are never touched.

    Examples
    --------
    >>> import tempfile, pathlib
    >>> out = pathlib.Path(tempfile.mkdtemp()) / "a.txt"
    >>> with atomic_output(out) as tmp:
    ...     _ = tmp.write_text("done")
    >>> out.read_text()
    'done'
    """

    def __init__(self, path, overwrite=False):
        text = os.fspath(path)
        self.path = Path(path)
        self.overwrite = overwrite
        if text.endswith(("/", os.sep)) or self.path.is_dir():
            raise IsADirectoryError(f"{text} names a directory; give a file name to write")
        if self.path.exists() and not overwrite:
            raise FileExistsError(
                f"{self.path} exists; not overwriting it (pass overwrite=True / --overwrite)"
            )
        if not self.path.parent.is_dir():
            raise FileNotFoundError(f"output directory {self.path.parent} does not exist")

    #: Tag of this host in temporary names: a process id means something only here.
    HOST = hashlib.sha1(socket.gethostname().encode()).hexdigest()[:8]

    def _remove_stale(self):
        prefix = f".{self.path.name}.{self.HOST}-"
        for old in self.path.parent.glob(f"{glob.escape(prefix)}*.tmp"):
            parts = old.name[len(prefix):-len(".tmp")].split(".")
            if len(parts) != 2 or not parts[0].isdigit() or int(parts[0]) == os.getpid():
                continue  # not ours (e.g. of an output "NAME.1"), or this process's
            try:
                os.kill(int(parts[0]), 0)
            except ProcessLookupError:  # its writer is gone
                with contextlib.suppress(OSError):  # a clean-up: never a reason to fail
                    old.unlink()
            except (OSError, OverflowError):  # alive but not ours, or not a pid
                pass

    def __enter__(self):
        self._remove_stale()
        try:
            fd, tmp = tempfile.mkstemp(prefix=f".{self.path.name}.{self.HOST}-{os.getpid()}.",
                                       suffix=".tmp", dir=self.path.parent)
        except OSError as exc:  # e.g. a read-only file system: say which output
            exc.filename = str(self.path)
            raise
        os.close(fd)
        os.unlink(tmp)
        self.tmp = Path(tmp)
        return self.tmp

    def __exit__(self, exc_type, exc, tb):
        try:
            if exc_type is None:
                if self.path.exists() and not self.overwrite:
                    raise FileExistsError(
                        f"{self.path} appeared while writing; not overwriting it")
                os.replace(self.tmp, self.path)
        finally:
            self.tmp.unlink(missing_ok=True)
        if isinstance(exc, OSError) and exc.errno is not None and (
                exc.filename is None or os.fspath(exc.filename) == str(self.tmp)):
            exc.filename = str(self.path)  # e.g. a full disk: say which output
        return False


def _image(data, name, unit=None):
    hdu = fits.ImageHDU(np.asarray(data), name=name)
    if unit is not None:
        hdu.header["BUNIT"] = _unit_str(unit)
    return hdu


def write(exposure, path, overwrite=False):
    """Write an `Exposure` to a FITS file, atomically and with checksums.

    Parameters
    ----------
    exposure : `Exposure`
        Raw (readout order) or reduced (physical order) exposure.
    path : str or `pathlib.Path`
        Output file.
    overwrite : bool
        Replace an existing file.  Without it an existing file is kept and
        `FileExistsError` is raised.

    Returns
    -------
    path : `pathlib.Path`

    Examples
    --------
    >>> import tempfile, pathlib, numpy as np
    >>> from spherex_reduce import DetectorGeometry, Exposure, ReadoutSchedule, read, write
    >>> s = ReadoutSchedule(DetectorGeometry(12, 8, 2, ref_border=2), skip=3, ref_reads=4,
    ...                     phantom_reads=2, nframes=2)
    >>> e = Exposure.from_arrays(np.ones((2, s.n_reads, 8), "f4"), s,
    ...                          phantom=np.zeros((2, s.n_reads, 2), "f4"))
    >>> out = write(e, pathlib.Path(tempfile.mkdtemp()) / "raw.fits")
    >>> read(out).schedule == s
    True
    """
    path = Path(path)
    header = exposure.schedule.to_header(exposure.header)
    header["ORDER"] = (exposure.order.upper(), "row order of SCI: READOUT or PHYSICAL")
    unit = exposure.unit or u.dimensionless_unscaled
    header["BUNIT"] = (_unit_str(unit), "unit of SCI and ERR")
    hdus = [fits.PrimaryHDU(header=header), _image(exposure.data.data, "SCI", unit)]
    unc = exposure.data.uncertainty
    if unc is not None:
        if not isinstance(unc, StdDevUncertainty):  # (converting costs two passes)
            unc = unc.represent_as(StdDevUncertainty)
        hdus.append(_image(unc.array, "ERR", unit))
    dq = exposure.dq
    if dq is not None:
        hdus.append(_image(dq.astype(np.int32), "DQ"))  # unsigned would need BZERO: no memmap
    if exposure.phantom is not None:
        hdus.append(_image(exposure.phantom, "PHANTOM", unit))
    hdus.append(_table_hdu(exposure.schedule.to_table(), "READOUT"))
    ref = exposure.reference
    if ref is not None:
        hdus.append(_image(ref.data, "REFPIX", unit))
        if ref.phantom is not None:
            hdus.append(_image(ref.phantom, "REFPHANT", unit))
        if ref.dq is not None:
            hdus.append(_image(np.asarray(ref.dq).astype(np.int32), "REFDQ"))
        times = exposure.schedule.start_times[ref.reads]
        hdus.append(_table_hdu(Table({"read": ref.reads, "row": ref.rows, "time": times}),
                               "REFREADS"))
    for name, table in exposure.tables.items():
        if name.upper() in _RESERVED:
            raise ValueError(f"table name {name!r} is reserved for the format")
        hdus.append(_table_hdu(table, name.upper()))
    # a file cut at an HDU boundary is still valid FITS: the count tells it is not whole
    hdus[0].header["NEXTEND"] = (len(hdus) - 1, "number of extensions")
    with atomic_output(path, overwrite) as tmp:
        fits.HDUList(hdus).writeto(tmp, checksum=True)
    return path


def _table_hdu(table, name):
    t = Table(table, copy=False)
    t.meta = {k: v for k, v in t.meta.items() if k != "comments"}
    hdu = fits.table_to_hdu(t)
    hdu.name = name
    return hdu


_VERIFY = contextvars.ContextVar("spherex_reduce_verify_checksum", default=True)


@contextlib.contextmanager
def checksum_policy(verify=True):
    """Set whether reads in this context stop at a checksum mismatch.

    `read` and `FrameReader` verify ``CHECKSUM`` and ``DATASUM`` of every HDU
    that has them.  By default a mismatch is a `FormatError`; inside
    ``checksum_policy(verify=False)`` it is logged as a warning and recorded
    in the header of what is read (``HISTORY`` and the keyword ``SXRCKBAD``
    listing the HDUs), which travels to any file written from it.  The
    command line's ``--ignore-checksum`` sets this for the whole command, so
    that every file it reads (including e.g. a pipeline's dark) follows it.

    Parameters
    ----------
    verify : bool
        False to read files whose checksum does not match.

    Examples
    --------
    >>> from spherex_reduce.fits_format import checksum_policy
    >>> with checksum_policy(verify=False):
    ...     pass  # read(...) here warns instead of failing on a bad checksum
    """
    token = _VERIFY.set(bool(verify))
    try:
        yield
    finally:
        _VERIFY.reset(token)


_BLOCK = 2880
_MAX_HEADER_BLOCKS = 10_000  # 28.8 MB of header cards: far beyond any real file
_SCAN_KEYS = {b"XTENSION", b"EXTNAME", b"BITPIX", b"NAXIS", b"PCOUNT", b"GCOUNT", b"GROUPS",
              b"NEXTEND", b"CHECKSUM", b"DATASUM"}
_STRING = re.compile(r"'((?:[^']|'')*)'")


def _card_value(image):
    """The value of an 80-byte card as text (strings unquoted), or None."""
    if image[8:10] != b"= ":
        return None
    text = image[10:].decode("ascii", "replace").strip()
    if text.startswith("'"):
        m = _STRING.match(text)
        return m.group(1).replace("''", "'").rstrip() if m else text
    return text.split("/", 1)[0].strip()


def _hdu_label(index, cards):
    name = cards.get("EXTNAME") or ("PRIMARY" if index == 0 else None)
    return f"HDU {index} ({name!r})" if name else f"HDU {index}"


def _card_int(cards, key, default, path, index, minimum=0):
    text = cards.get(key)
    if text is None:
        if default is None:
            raise FormatError(f"{path}: {_hdu_label(index, cards)} lacks the keyword {key}")
        return default
    if not re.fullmatch(r"[+-]?\d+", text) or not minimum <= int(text) < 2**62:
        raise FormatError(f"{path}: {_hdu_label(index, cards)} has {key} = {text!r}, not an "
                          f"integer >= {minimum}")
    return int(text)


def _scan(path):
    """The HDUs of a plain FITS file from its bytes: ``[{name, header, data, nbytes, cards}]``.

    ``header`` and ``data`` are byte offsets, ``nbytes`` the data size without
    padding.  Only headers are read.  A gzip-, bzip2- or xz-compressed file is
    checked the same way while it is decompressed (one pass, nothing kept), and
    then None is returned, as for a file that is not FITS at all (astropy
    unpacks the first, and names the problem of the second).

    Raises
    ------
    FormatError
        A header has no ``END`` card, a structural keyword is invalid, the
        file (decompressed) ends before a header or data block it announces
        ("truncated"), or a compressed stream is damaged.
    """
    with open(path, "rb") as fh:
        magic = fh.read(9)
        if magic == b"SIMPLE  =":
            fh.seek(0)
            return _scan_stream(fh, path, os.path.getsize(path))
    opener = _DECOMPRESSORS.get(next((m for m in _DECOMPRESSORS if magic.startswith(m)), None))
    if opener is None:
        return None
    try:
        with opener(path) as fh:
            if fh.read(9) == b"SIMPLE  =":
                _scan_stream(_Rewound(fh, b"SIMPLE  ="), path, None)
    except (EOFError, OSError, ValueError) as exc:
        if isinstance(exc, FormatError):
            raise
        raise FormatError(f"{path}: the compressed data are damaged or truncated ({exc})") \
            from exc
    return None


def _open_xz(path):
    import lzma

    return lzma.open(path)


def _open_bz2(path):
    import bz2

    return bz2.open(path)


def _open_gzip(path):
    import gzip

    return gzip.open(path)


_DECOMPRESSORS = {b"\x1f\x8b": _open_gzip, b"BZh": _open_bz2, b"\xfd7zXZ\x00": _open_xz}


class _Rewound:
    """A forward-only stream with ``head`` (already read) put back in front."""

    def __init__(self, fh, head):
        self.fh, self.head = fh, head

    def read(self, n):
        out, self.head = self.head[:n], self.head[n:]
        return out + self.fh.read(n - len(out)) if n > len(out) else out


def _skip(fh, nbytes):
    """Read ``nbytes`` forward, keeping nothing; the number of bytes there were."""
    done = 0
    while done < nbytes:
        got = len(fh.read(min(1 << 20, nbytes - done)))
        if not got:
            break
        done += got
    return done


def _scan_stream(fh, path, size):
    """`_scan` of a stream: seekable with its ``size`` known (a plain file), or read
    forward only (``size`` None: decompressed)."""
    hdus = []
    pos = 0
    seekable = size is not None
    where = "the file ends" if seekable else "the file, decompressed, ends"
    while True:
        if seekable:
            fh.seek(pos)
        first = fh.read(_BLOCK)
        if not first:
            break
        if len(hdus) and not first.startswith(b"XTENSION"):
            if first.strip(b"\0 ") or (not seekable and fh.read(1 << 16).strip(b"\0 ")):
                raise FormatError(f"{path}: the bytes after its last HDU (byte {pos}) are not "
                                  "a FITS extension: the file is damaged")
            break
        cards, start, block, nblocks = {}, pos, first, 0
        while True:
            index = len(hdus)
            if len(block) < _BLOCK:
                named = re.search(rb"EXTNAME = '([^']*)'", block)
                label = _hdu_label(index, {"EXTNAME": named.group(1).decode(
                    "ascii", "replace").strip()} if named else {})
                raise FormatError(f"{path} is truncated: {label} needs at least "
                                  f"{pos + _BLOCK} bytes for its header, {where} after "
                                  f"{pos + len(block)}")
            pos += _BLOCK
            nblocks += 1
            end = False
            for i in range(0, _BLOCK, 80):
                key = block[i : i + 8].rstrip()
                if key == b"END":
                    end = True
                    break
                if key in _SCAN_KEYS or key.startswith(b"NAXIS"):
                    value = _card_value(block[i : i + 80])
                    if value is not None:
                        cards.setdefault(key.decode(), value)
            if end:
                break
            if nblocks >= _MAX_HEADER_BLOCKS:
                raise FormatError(f"{path}: {_hdu_label(index, cards)} has no END card in "
                                  f"its first {_MAX_HEADER_BLOCKS * _BLOCK} bytes")
            block = fh.read(_BLOCK)
        bitpix = _card_int(cards, "BITPIX", None, path, index, minimum=-64)
        if bitpix not in (8, 16, 32, 64, -32, -64):
            raise FormatError(f"{path}: {_hdu_label(index, cards)} has BITPIX = {bitpix}, "
                              "not one of 8, 16, 32, 64, -32, -64")
        naxis = _card_int(cards, "NAXIS", None, path, index)
        if naxis > 999:
            raise FormatError(f"{path}: {_hdu_label(index, cards)} has NAXIS = {naxis} > 999")
        axes = [_card_int(cards, f"NAXIS{i}", None, path, index) for i in range(1, naxis + 1)]
        if cards.get("GROUPS") == "T" and axes and axes[0] == 0:
            axes = axes[1:]  # random groups
        count = 0
        if axes:
            count = 1
            for n in axes:
                count *= n
        pcount = _card_int(cards, "PCOUNT", 0, path, index)
        gcount = _card_int(cards, "GCOUNT", 1, path, index)
        nbytes = abs(bitpix) // 8 * gcount * (pcount + count) if naxis else 0
        padded = -(-nbytes // _BLOCK) * _BLOCK  # the standard's padding is part of it
        there = (size - pos) if seekable else _skip(fh, padded)
        if there < padded:
            raise FormatError(f"{path} is truncated: {_hdu_label(index, cards)} needs "
                              f"{pos + padded} bytes, {where} after {pos + max(there, 0)}")
        hdus.append({"name": cards.get("EXTNAME") or ("PRIMARY" if index == 0 else
                                                      f"HDU {index}"),
                     "header": start, "data": pos, "nbytes": nbytes, "cards": cards})
        pos += padded
    if hdus:
        nextend = hdus[0]["cards"].get("NEXTEND")
        if nextend is not None:
            want = _card_int(hdus[0]["cards"], "NEXTEND", None, path, 0)
            if want > len(hdus) - 1:
                raise FormatError(f"{path} is truncated: its primary header announces NEXTEND = "
                                  f"{want} extensions, the file ends after {len(hdus) - 1}")
    return hdus


def _fold(total):
    """32-bit ones'-complement sum (end-around carry) of a non-negative integer sum."""
    while total >> 32:
        total = (total & 0xFFFFFFFF) + (total >> 32)
    return total


class _DataSum:
    """Running FITS ones'-complement sum of big-endian 32-bit words (``DATASUM``).

    The FITS checksum algorithm (FITS standard 4.0, appendix J).  `add` takes
    whole words as they are on disk: a big-endian array or bytes whose length
    is a multiple of 4.  numpy sums each piece in 64-bit integers (no carry is
    lost below 2**32 words, 16 GB, per piece); `value` folds the total.
    """

    __slots__ = ("total",)

    def __init__(self):
        self.total = 0

    def add(self, raw):
        self.total += int(np.add.reduce(np.frombuffer(raw, ">u4"), dtype=np.uint64))

    @property
    def value(self):
        return _fold(self.total)


def _word_sum(fh, start, nbytes, chunk=1 << 20):
    """Ones'-complement sum of the big-endian 32-bit words of bytes ``start:start+nbytes``.

    Summed by `_DataSum` a chunk at a time.  A tail shorter than a word is
    padded with zeros, as the file's padding would be.  The chunks are read
    into one reused buffer (``readinto``): memory stays at one chunk, the sum
    runs from the cache, and no page of the file is mapped (faster than a
    memory map by ~30 %, measured).
    """
    raw = memoryview(np.zeros(chunk // 4 + 1, ">u4")).cast("B")  # aligned, room to pad
    total, left = _DataSum(), nbytes
    fh.seek(start)
    while left:
        n = got = min(chunk, left)
        while got:
            k = fh.readinto(raw[n - got : n])
            if not k:
                raise FormatError(f"{fh.name}: the file ends inside an HDU")  # (scanned before)
            got -= k
        if n % 4:  # the last bytes of the data: pad the word with zeros
            raw[n : n + 4 - n % 4] = bytes(4 - n % 4)
        total.add(raw[: n + (-n) % 4])
        left -= n
    return total.value


def _verify(path, hdus):
    """Names of the HDUs whose ``DATASUM`` or ``CHECKSUM`` does not match their bytes."""
    wanted = [h for h in hdus if "DATASUM" in h["cards"] or "CHECKSUM" in h["cards"]]
    bad = []
    with open(path, "rb", buffering=0) as fh:
        for h in wanted:
            datasum = _word_sum(fh, h["data"], h["nbytes"])
            declared = h["cards"].get("DATASUM")
            ok = declared is None or (declared.strip().isdigit() and int(declared) == datasum)
            if ok and "CHECKSUM" in h["cards"]:
                # header words plus the data's sum: all ones (-0) when nothing changed
                ok = _fold(_word_sum(fh, h["header"], h["data"] - h["header"]) + datasum) \
                    == 0xFFFFFFFF
            if not ok:
                bad.append(h["name"])
    return bad


def _open(path, memmap, verify=None):
    """Open a FITS file read-only after checking its structure and checksums.

    Returns ``(hdul, bad, plain)``: the astropy HDU list, the names of HDUs
    whose checksum failed (only when ``verify`` is False: else that is an
    error), and whether the file is plain FITS on disk (not gzip etc., which
    astropy unpacks: those are never memory-mapped).  ``verify=None`` follows
    `checksum_policy`.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no such file: {path}")
    verify = _VERIFY.get() if verify is None else verify
    hdus = _scan(path)
    bad = _verify(path, hdus) if hdus else []
    if bad:
        msg = (f"{path}: the checksum of HDU(s) {', '.join(bad)} does not match the bytes "
               "(CHECKSUM/DATASUM): the file is damaged or was changed after writing")
        if verify:
            raise FormatError(f"{msg}; to read it anyway, pass --ignore-checksum "
                              "(verify_checksum=False)")
        log.warning("%s; read anyway (checksum verification off)", msg)
    plain = hdus is not None
    try:
        hdul = fits.open(path, memmap=memmap and plain, mode="readonly")
    except OSError as exc:
        raise FormatError(f"{path} is not a readable FITS file: {exc}") from exc
    try:
        for hdu in hdul:
            _check_cards(hdu, path)
    except BaseException:
        hdul.close()
        raise
    return hdul, bad, plain


def _check_cards(hdu, path):
    """Every card of ``hdu``'s header parses and holds no infinite or NaN number."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # astropy's notes on non-standard cards
        for card in hdu.header.cards:
            try:
                value = card.value
            except Exception as exc:  # VerifyError: e.g. "X = NAN", "X = 1E9999x"
                raise FormatError(f"{path}: HDU {hdu.name!r} has the unreadable header card "
                                  f"{card.keyword} = {_card_text(card)}") from exc
            if isinstance(value, float) and not math.isfinite(value):
                raise FormatError(f"{path}: HDU {hdu.name!r} has the header card "
                                  f"{card.keyword} = {value}, not a finite number")


def _note_bad_checksums(header, bad, path):
    """Record in ``header`` (in place) that HDUs ``bad`` of ``path`` failed their checksum."""
    if not bad:
        return
    previous = str(header.get("SXRCKBAD", "")).strip()
    header["SXRCKBAD"] = (",".join(filter(None, [previous, *bad]))[:68],
                          "input HDUs whose checksum failed, read anyway")
    header.add_history(f"checksum of {', '.join(bad)} in {Path(path).name} did not match; "
                       "read anyway (checksum verification off)")


def _describe(hdul, path, supplied, bad=()):
    """Validate an open file; return what every reader needs (no pixel data loaded)."""
    names = [h.name for h in hdul]
    header = hdul[0].header.copy()
    if "SCI" in names:
        sci = hdul["SCI"]
    elif hdul[0].header.get("NAXIS", 0) > 0:
        sci = hdul[0]
    else:
        raise FormatError(f"{path} has no SCI extension and no primary data")
    shape = tuple(sci.header[f"NAXIS{i}"] for i in range(sci.header["NAXIS"], 0, -1))
    table = Table.read(hdul["READOUT"]) if "READOUT" in names else None
    schedule = ReadoutSchedule.from_header(header, table, **supplied)
    order = header_keyword(header, "ORDER", str, default="READOUT").strip().lower()
    if order not in ("readout", "physical"):
        raise FormatError(f"keyword ORDER must be READOUT or PHYSICAL, got {order!r}")
    _check_shape(shape, schedule, order, "SCI")
    if "PHANTOM" in names:
        pshape = tuple(hdul["PHANTOM"].shape)
        frames_reads = expected_shape(schedule, order, len(shape) == 3)[:-1]
        expected = (*frames_reads, schedule.geometry.nchannels)
        if pshape != expected:
            raise FormatError(
                f"PHANTOM has shape {pshape}, the schedule gives {expected} "
                "(frames, reads, channels): check NFRAMES, NCHAN and the read order keywords"
            )
    elif schedule.phantom_reads and order == "readout":
        raise FormatError(f"NPHANT={schedule.phantom_reads} but the file has no PHANTOM extension")
    unit = _unit(header_keyword(header if "BUNIT" in header else sci.header, "BUNIT", str,
                                default="electron"))
    for key in ("CHECKSUM", "DATASUM", "ORDER", "NEXTEND"):
        header.remove(key, ignore_missing=True)
    _note_bad_checksums(header, bad, path)
    return {"names": names, "header": header, "sci": sci, "shape": shape,
            "schedule": schedule, "order": order, "unit": unit}


def _readonly(*arrays):
    for array in arrays:
        if array is not None:  # the file's own pages: a step must never write into them
            array.setflags(write=False)


class CheckedFITS:
    """A FITS file opened read-only by `open_checked`, after the checks `read` makes.

    Use it as a context manager (the file is closed on exit).

    Attributes
    ----------
    path : `pathlib.Path`
    hdul : `astropy.io.fits.HDUList`
        The file's HDUs, read-only (memory-mapped for plain FITS on disk).
    bad : list of str
        Names of the HDUs whose checksum failed; only ever non-empty when the
        file was opened with checksum verification off.
    """

    def __init__(self, path, verify_checksum=None, memmap=True):
        self.path, self._name = Path(path), path  # messages name the path as given
        self.hdul, self.bad, self._plain = _open(path, memmap, verify_checksum)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def close(self):
        """Close the file (arrays already returned stay valid)."""
        self.hdul.close()

    def exposure(self, **supplied):
        """The `Exposure` of a file in this package's format, as `read` returns it.

        ``supplied`` are the readout parameters `read` takes.
        """
        return _exposure(self.hdul, self._name, self.bad, self._plain, supplied)

    def physical(self, hdu):
        """The data of image HDU ``hdu`` in physical values (``BSCALE``/``BZERO``
        applied, ``BLANK`` as NaN; as stored if unscaled), or None if it has none."""
        return _physical(hdu, self._name, self._plain)

    def note_bad_checksums(self, header):
        """Record in ``header`` (changed in place) which HDUs failed their checksum:
        ``SXRCKBAD`` and a ``HISTORY`` card, as `read` does; nothing if none did."""
        _note_bad_checksums(header, self.bad, self._name)


def open_checked(path, verify_checksum=None):
    """Open any FITS file read-only after checking it as `read` does, without reading it.

    The structure is scanned first (a truncated file is named as such),
    ``CHECKSUM``/``DATASUM`` are verified and every header card must parse
    to a finite value.  Use this to read files that may or may not be in this
    package's format.

    Parameters
    ----------
    path : str or `pathlib.Path`
        FITS file (plain, or compressed as astropy reads it); never changed.
    verify_checksum : bool, optional
        As for `read`: a checksum mismatch is an error (True) or only noted
        in `CheckedFITS.bad` (False).  Default: `checksum_policy`.

    Returns
    -------
    `CheckedFITS`
        A context manager holding the open HDU list.

    Raises
    ------
    FileNotFoundError
        No file at ``path``.
    FormatError
        The file is truncated, not FITS, has a bad checksum (when verified)
        or a header card that does not parse.

    Examples
    --------
    >>> import tempfile, pathlib, numpy as np
    >>> from astropy.io import fits
    >>> from spherex_reduce.fits_format import open_checked
    >>> path = pathlib.Path(tempfile.mkdtemp()) / "img.fits"
    >>> hdu = fits.PrimaryHDU(np.array([[0, 1], [2, 3]], dtype=np.int16))
    >>> hdu.header["BSCALE"], hdu.header["BZERO"] = 0.5, 10.0
    >>> hdu.writeto(path, checksum=True)
    >>> with open_checked(path) as f:
    ...     data = f.physical(f.hdul[0])
    >>> data.tolist(), f.bad
    ([[10.0, 10.5], [11.0, 11.5]], [])
    """
    return CheckedFITS(path, verify_checksum)


def read(path, verify_checksum=None, **supplied):
    """Read an exposure written by `write` (or raw data from other electronics).

    Parameters
    ----------
    path : str or `pathlib.Path`
        FITS file.  It is opened read-only (memory-mapped) and never changed;
        the arrays of the returned exposure are read-only.  Integer data with
        ``BSCALE``/``BZERO``/``BLANK`` are scaled to floating point
        (``float32`` for 8- and 16-bit data, else ``float64``; ``BLANK`` is
        NaN) in memory.
    verify_checksum : bool, optional
        Whether a ``CHECKSUM``/``DATASUM`` mismatch is an error (True), or a
        logged warning recorded in the returned header (False: ``HISTORY``
        and ``SXRCKBAD``).  Default: `checksum_policy` (True).
    **supplied
        Geometry and readout parameters (``nrows``, ``skip``, ``frame_time``
        ...) used where the header lacks them, e.g. from a pipeline config's
        ``geometry:`` and ``readout:`` sections.

    Returns
    -------
    exposure : `Exposure`

    Raises
    ------
    FormatError
        The file is truncated or damaged (checksum), lacks ``SCI``, a keyword
        is missing or invalid, or the header, the ``READOUT`` table and the
        array shapes disagree; the message names the keyword or dimension.
    ResourceError
        Scaled data would not fit in memory once in floating point.

    Examples
    --------
    Unsigned 16-bit data (stored with ``BZERO = 32768``) come back as floats:

    >>> import tempfile, pathlib, numpy as np
    >>> from spherex_reduce import Exposure, ReadoutSchedule, DetectorGeometry, read, write
    >>> s = ReadoutSchedule(DetectorGeometry(8, 8, 2, ref_border=0), ref_mode="none",
    ...                     phantom_reads=0, nframes=2)
    >>> counts = np.arange(2 * 8 * 8, dtype=np.uint16).reshape(2, 8, 8) + 60000
    >>> out = write(Exposure.from_arrays(counts, s), pathlib.Path(tempfile.mkdtemp()) / "u.fits")
    >>> e = read(out)
    >>> e.data.data.dtype, float(e.data.data.max())
    (dtype('float32'), 60127.0)
    """
    with CheckedFITS(path, verify_checksum) as f:
        return f.exposure(**supplied)


def _exposure(hdul, path, bad, plain, supplied):
    """The `Exposure` in an HDU list opened by `_open` (which the caller closes)."""
    d = _describe(hdul, path, supplied, bad)
    names = d["names"]

    def image(name, flags=False):
        return _physical(hdul[name], path, plain, flags) if name in names else None

    data = _physical(d["sci"], path, plain)
    err, mask, phantom = image("ERR"), image("DQ", flags=True), image("PHANTOM")
    reference = None
    if "REFPIX" in names:
        rt = Table.read(hdul["REFREADS"])
        refdq = image("REFDQ", flags=True)
        reference = ReferenceReads(
            data=image("REFPIX"), rows=np.asarray(rt["row"]), reads=np.asarray(rt["read"]),
            phantom=image("REFPHANT"),
            dq=None if refdq is None else refdq.astype(np.uint16),
        )
        _readonly(reference.data, reference.phantom)
    tables = {
        h.name: Table.read(h)
        for h in hdul
        if isinstance(h, fits.BinTableHDU) and h.name not in _RESERVED
    }
    _readonly(data, err, mask, phantom)
    return Exposure.from_arrays(data, d["schedule"], unit=d["unit"], uncertainty=err, mask=mask,
                                phantom=phantom, header=d["header"], order=d["order"],
                                reference=reference, tables=tables)


_FLOAT_FOR = {8: "f4", 16: "f4", 32: "f8", 64: "f8", -32: "f4", -64: "f8"}


def _scaling(hdu, path):
    """``(bscale, bzero, blank)`` of an image HDU, checked, or None if its values are stored
    as they are."""
    h = hdu.header
    if not any(key in h for key in ("BSCALE", "BZERO", "BLANK")):
        return None
    try:
        bscale = header_keyword(h, "BSCALE", float, default=1.0)
        bzero = header_keyword(h, "BZERO", float, default=0.0)
        blank = header_keyword(h, "BLANK", int, default=None) if h["BITPIX"] > 0 else None
    except FormatError as exc:
        raise FormatError(f"{path}: HDU {hdu.name!r}: {exc}") from exc
    if bscale == 0:
        raise FormatError(f"{path}: HDU {hdu.name!r} has BSCALE = 0")
    if bscale == 1 and bzero == 0 and blank is None:
        return None
    return bscale, bzero, blank


def _to_physical(stored, scale, dtype):
    """``BZERO + BSCALE * stored`` (``BLANK`` -> NaN) as a new array of ``dtype``."""
    bscale, bzero, blank = scale
    out = stored.astype(dtype)
    if out.dtype.kind in "iu":  # flags: integer offsets only (checked by the caller)
        out += int(bzero)
        return out
    if bscale != 1:
        out *= bscale
    if bzero:
        out += bzero
    if blank is not None:
        out[stored == blank] = np.nan
    return out


def _physical(hdu, path, plain, flags=False):
    """The data of an image HDU in physical values.

    Unscaled data come as astropy gives them (memory-mapped if the file is).
    Scaled data are converted here from the stored values (astropy refuses
    to scale a memory-mapped image): floating point, or 64-bit integers for
    flags (``DQ``), whose ``BSCALE`` must be 1 and ``BZERO`` whole.
    """
    if hdu.header.get("NAXIS", 0) == 0:
        return None
    scale = _scaling(hdu, path)
    if scale is None:
        return hdu.data
    bitpix = hdu.header["BITPIX"]
    if flags:
        if bitpix < 0 or scale[0] != 1 or scale[1] != int(scale[1]):
            raise FormatError(f"{path}: HDU {hdu.name!r} holds flags, which must be integers; "
                              f"it has BITPIX = {bitpix}, BSCALE = {scale[0]}, "
                              f"BZERO = {scale[1]}")
        dtype = np.dtype("i8")
    else:
        dtype = np.dtype(_FLOAT_FOR[bitpix])
    shape = tuple(hdu.shape)
    check_size(int(np.prod(shape, dtype=float)) * dtype.itemsize,
               f"HDU {hdu.name!r} of {path} {shape} scaled to {dtype}")
    if not plain or isinstance(hdu, fits.CompImageHDU):  # astropy unpacks and scales
        return np.asarray(hdu.data).astype(dtype)
    stored = np.memmap(path, dtype=_FITS_DTYPES[bitpix], mode="r",
                       offset=hdu.fileinfo()["datLoc"], shape=shape)
    try:
        return _to_physical(stored, scale, dtype)
    finally:
        del stored


def is_raw_ramp_file(path):
    """True for a file whose SCI is 3-D ramps in readout order (headers only are read).

    A file that cannot be read gives False: the ordinary reader, `read`, then
    gives the proper error.

    Examples
    --------
    >>> from spherex_reduce.fits_format import is_raw_ramp_file
    >>> is_raw_ramp_file("no-such-file.fits")
    False
    """
    try:
        if not Path(path).is_file():
            return False
        _scan(path)  # truncated or damaged: not astropy's guess, read's error
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            with fits.open(path, memmap=False) as hdul:
                names = [h.name for h in hdul]
                sci = hdul["SCI"] if "SCI" in names else hdul[0]
                order = str(hdul[0].header.get("ORDER", "READOUT")).strip().upper()
                return (sci.header.get("NAXIS") == 3 and order == "READOUT"
                        and "DQ" not in names and "ERR" not in names)
    except (OSError, KeyError, IndexError, ValueError):  # FormatError is a ValueError
        return False


class FrameReader:
    """Read a raw ramp file one frame at a time, without mapping the whole file.

    Used by `~spherex_reduce.Pipeline` to reduce ramps frame by frame in
    memory near one frame.  Use as a context manager.

    Parameters
    ----------
    path : str or `pathlib.Path`
        A file of ramps ``(frames, reads, columns)`` in readout order.  It is
        checked as by `read` (structure, checksums, keywords) when opened.
        Scaled integer data come as floating point frames (`frame`).
    verify_checksum : bool, optional
        As for `read`.
    **supplied
        As for `read`.

    Attributes
    ----------
    schedule : `ReadoutSchedule`
        The full exposure's schedule.
    header : `astropy.io.fits.Header`
    """

    def __init__(self, path, verify_checksum=None, **supplied):
        self.path = Path(path)
        self._map = None
        self._hdul, bad, plain = _open(path, memmap=False, verify=verify_checksum)
        try:
            d = _describe(self._hdul, path, supplied, bad)
            if len(d["shape"]) != 3 or d["order"] != "readout" or "DQ" in d["names"] \
                    or "ERR" in d["names"]:
                raise FormatError(f"{path} is not a raw ramp file in readout order")
            self._d = d
            self.schedule, self.header, self.unit = d["schedule"], d["header"], d["unit"]
            self._phantom = (np.asarray(_physical(self._hdul["PHANTOM"], path, plain))
                             if "PHANTOM" in d["names"] else None)
            self._scale = _scaling(d["sci"], path)
            self._tables = {h.name: Table.read(h) for h in self._hdul
                            if isinstance(h, fits.BinTableHDU) and h.name not in _RESERVED}
            self._map = _map_frames(d["sci"], path) if plain else None
        except Exception:
            self._hdul.close()
            raise
        #: tables of the file (e.g. ``PROVENANCE``), phantom values ``(frames, reads,
        #: channels)`` or None, and the type the pixels are stored as
        self.tables, self.phantom = self._tables, self._phantom
        self.stored_dtype = None if self._map is None else self._map[2]

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False

    def close(self):
        """Close the file."""
        if self._map is not None:
            mm, _, _, fd = self._map
            os.close(fd)
            try:
                mm.close()
            except BufferError:  # a frame view is still alive (e.g. in a traceback):
                pass  # the map closes when it is collected
            self._map = None
        self._hdul.close()

    @property
    def nframes(self):
        """Number of frames in the file."""
        return self.schedule.nframes

    def frame(self, k):
        """Frame ``k`` as a one-frame `Exposure` (schedule with ``nframes=1``)."""
        if self._map is None:  # compressed: astropy unpacks (and scales) the section
            data = np.asarray(self._d["sci"].section[k : k + 1])
            if data.dtype.kind in "iu":
                data = data.astype(_FLOAT_FOR[self._d["sci"].header["BITPIX"]])
        else:
            data = self._mapped_frame(k)
        phantom = None if self._phantom is None else self._phantom[k : k + 1]
        return Exposure.from_arrays(data, self.schedule.replace(nframes=1), unit=self.unit,
                                    phantom=phantom, header=self.header, tables=self._tables)


    @property
    def has_phantom(self):
        """Whether the file has phantom values."""
        return self._phantom is not None

    def fusable(self):
        """Whether `raw` gives floating-point pixels and phantom values (what the fused
        path needs)."""
        dtype = self._map[2] if self._map is not None else None
        return (dtype is not None and dtype.kind == "f" and self._scale is None
                and (self._phantom is None or self._phantom.dtype.kind == "f"))

    def raw(self, k):
        """Frame ``k`` as it is in the file, without copying it.

        Returns ``(pixels, phantom, release)``: pixels ``(reads, columns)``,
        possibly big-endian and read-only (a view of the memory-mapped file);
        phantom values ``(reads, channels)`` or None; and ``release()``, to
        call once the pixels have been used (frees the file's pages in this
        process).  The pixels are stored values: `fusable` says whether they
        are the physical values (floating point, not scaled).
        """
        mm, offset, dtype, _ = self._map
        shape = self._d["shape"][1:]
        count = int(np.prod(shape))
        start = offset + k * count * dtype.itemsize
        view = np.frombuffer(mm, dtype=dtype, count=count, offset=start).reshape(shape)
        phantom = None if self._phantom is None else self._phantom[k]
        return view, phantom, lambda: self._release(start, count * dtype.itemsize)

    def reads(self, k, first, stop):
        """Reads ``first:stop`` of frame ``k`` as they are in the file (a copy).

        Read with ``pread``: no page of the memory map is touched, and several
        threads may read at once.  Only for files whose data are not scaled
        (`fusable`).

        Returns
        -------
        `numpy.ndarray`
            ``(stop - first, columns)``, possibly big-endian.
        """
        mm, offset, dtype, fd = self._map
        nreads, ncols = self._d["shape"][1:]
        pos = offset + (k * nreads + first) * ncols * dtype.itemsize
        if not hasattr(os, "preadv"):  # (Windows) from the map, then release its pages
            count = (stop - first) * ncols
            buf = np.frombuffer(mm, dtype, count=count, offset=pos).reshape(-1, ncols).copy()
            self._release(pos, count * dtype.itemsize)
            return buf
        buf = np.empty((stop - first, ncols), dtype)
        view = memoryview(buf).cast("B")
        done = 0
        while done < view.nbytes:
            got = os.preadv(fd, [view[done:]], pos + done)
            if got <= 0:
                raise FormatError(f"{self.path}: the file ends inside frame {k}")
            done += got
        return buf

    def _release(self, start, nbytes):
        mm = self._map[0] if self._map is not None else None
        if mm is None or not hasattr(mm, "madvise"):
            return
        page = start - start % mmap.PAGESIZE
        length = (start + nbytes - page) // mmap.PAGESIZE * mmap.PAGESIZE
        if length:
            mm.madvise(mmap.MADV_DONTNEED, page, length)

    def _mapped_frame(self, k):
        """Frame ``k`` copied from the mapped file into a native-endian array.

        The file's pages are then released from this process (``MADV_DONTNEED``):
        they stay in the page cache, but the resident memory stays near one frame.
        """
        view, _, release = self.raw(k)
        if self._scale is None:
            data = view.astype(view.dtype.newbyteorder("="))
        else:  # BZERO + BSCALE * stored, in floating point
            data = _to_physical(view, self._scale, _FLOAT_FOR[self._d["sci"].header["BITPIX"]])
        del view
        release()
        return data[None]


_FITS_DTYPES = {8: "u1", 16: ">i2", 32: ">i4", 64: ">i8", -32: ">f4", -64: ">f8"}


def _map_frames(hdu, path):
    """``(mmap, data offset, dtype, file descriptor)`` of an image HDU stored as it is on
    disk, or None (tile-compressed: read by sections).  ``dtype`` is the stored type:
    scaling (`_scaling`) is the caller's.  The descriptor (kept open, the map's own
    file) serves `pread`.

    Reading frames from a memory map and converting them to native byte order
    in one pass is ~2x faster than astropy's section reads followed by
    arithmetic on big-endian arrays.
    """
    h = hdu.header
    dtype = _FITS_DTYPES.get(h.get("BITPIX"))
    if dtype is None or isinstance(hdu, fits.CompImageHDU):  # astropy decompresses those
        return None
    dtype = np.dtype(dtype)
    start = hdu.fileinfo()["datLoc"]
    nbytes = int(np.prod(hdu.shape)) * dtype.itemsize
    fd = os.open(path, os.O_RDONLY | getattr(os, "O_BINARY", 0))
    try:
        # a plain FITS file on disk (not .gz, .bz2 or .zip, which astropy unpacks)
        if os.read(fd, 9) != b"SIMPLE  =" or os.fstat(fd).st_size < start + nbytes:
            os.close(fd)
            return None
        mm = mmap.mmap(fd, 0, access=mmap.ACCESS_READ)
    except BaseException:
        os.close(fd)
        raise
    return mm, start, dtype, fd


def _unit_str(unit):
    """Units in astropy's generic format ('electron / s'): 'electron' is not a FITS unit."""
    return "" if unit == u.one else unit.to_string()


def _unit(value):
    try:
        return u.Unit(str(value).strip(), parse_strict="raise")
    except ValueError as exc:
        raise FormatError(f"keyword BUNIT={value!r} is not a unit astropy understands") from exc


def _check_shape(shape, schedule, order, name):
    if len(shape) not in (2, 3):
        raise FormatError(f"{name} must be 2-D or 3-D, got shape {shape}")
    expected = expected_shape(schedule, order, len(shape) == 3)
    if shape == expected:
        return
    labels = ["frames (NFRAMES)"] if len(shape) == 3 else []
    labels += ["reads (NROWS, REFBORD, NREFRD, REFMODE)" if order == "readout" else
               "rows (NROWS)", "columns (NCOLS)"]
    for axis, (got, want, label) in enumerate(zip(shape, expected, labels, strict=True)):
        if got != want:
            raise FormatError(
                f"{name} has shape {shape} but the header keywords give {expected}: axis {axis}, "
                f"{label}, is {got}, expected {want}"
            )
