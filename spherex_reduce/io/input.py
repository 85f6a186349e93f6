"""What a file needs before the steps: the ``input:`` section of a pipeline config.

`InputOptions` holds the section, validated: the unit of files that lack
``BUNIT`` or spell ADU another way, the gain (e⁻ per ADU) that turns ADU into
electrons, how many frames to drop at the start of every ramp, whether config
keywords fill or override the file's, which bits of a foreign ``DQ`` mask, and
whether a file's reads are its ``SCI`` extensions (``reads: extensions``).

The readers (`~spherex_reduce.io.read` and `~spherex_reduce.io.FrameReader`,
hence a `~spherex_reduce.Pipeline` streaming a file) apply it as the data are
read, with the functions here, so a file reduced streamed and the same file
read first and reduced in memory give the same numbers bit for bit.  An
exposure already in memory is never changed by it: it was read with it.
"""

import math
import re
from dataclasses import dataclass

import numpy as np
from astropy import units as u

from ..core.errors import ConfigError, FormatError
from ..core.fields import FIELD, check_sides, field_cards, read_field
from ..core.parameters import Parameter, validate_parameters
from .readers.flags import check_dq_bits

__all__ = ["INPUT_PARAMETERS", "InputOptions", "apply_gain", "parse_unit"]

#: the ``input:`` section's keys (``gain`` may also be a list, one number per channel)
INPUT_PARAMETERS = (
    Parameter("unit", None, (str, type(None)),
              "BUNIT when the file lacks it (ADU, DN, counts, electron, e-, any case)"),
    Parameter("gain", None, (float, list, type(None)),
              "e- per ADU, one number or one per channel: the data become electrons",
              minimum=0, exclusive_minimum=True),
    Parameter("drop_first_reads", 0, (int,),
              "frames to ignore at the start of every ramp", minimum=0),
    Parameter("header", "fill", (str,),
              "fill: config keys supply what the file lacks; override: they replace the file's",
              choices=("fill", "override")),
    Parameter("dq_bits", None, (int, type(None)),
              "bits of a foreign DQ that mask (default: every bit)"),
    Parameter("reads", None, (str, type(None)),
              "extensions: a file's reads are its SCI extensions (HST _raw), read in the "
              "order of their SAMPTIME (default: one SCI, or the primary HDU)",
              choices=(None, "extensions")),
)
_GAIN = Parameter("gain", None, (float,), "", minimum=0, exclusive_minimum=True)
#: spellings of ADU in files from other software (case-insensitive, whole words)
_ADU = re.compile(r"\b(adu|dn|counts?)\b", re.IGNORECASE)
#: spellings of the electron: ``ELECTRONS`` (HST), ``e-`` (labs), any case
_ELECTRON = re.compile(r"\belectrons?\b|(?<![\w.])e-(?![\w.])", re.IGNORECASE)
#: per second written ``/S`` (``DN/S``, ``ELECTRONS/S``): astropy's ``S`` is the siemens
_PER_SECOND = re.compile(r"/\s*S\b")


def parse_unit(text):
    """An astropy unit from a ``BUNIT`` text; ADU, DN and counts (any case) are ``adu``
    (astropy's own ``DN`` is a different unit: here it means the same as ADU), and
    electrons, ``ELECTRONS`` (HST) and ``e-`` are ``electron``; ``/S`` is per second
    (not astropy's siemens).

    Raises
    ------
    ValueError
        Not a unit astropy understands.

    Examples
    --------
    >>> from spherex_reduce.io.input import parse_unit
    >>> parse_unit("DN / s"), parse_unit("ADU"), parse_unit("electron")
    (Unit("adu / s"), Unit("adu"), Unit("electron"))
    >>> parse_unit("ELECTRONS/S"), parse_unit("DN/S"), parse_unit("COUNTS"), parse_unit("e-")
    (Unit("electron / s"), Unit("adu / s"), Unit("adu"), Unit("electron"))
    """
    text = _ELECTRON.sub("electron", _ADU.sub("adu", str(text).strip()))
    text = _PER_SECOND.sub("/ s", text)
    return u.Unit(text, parse_strict="raise")


@dataclass(frozen=True)
class InputOptions:
    """The ``input:`` section of a pipeline config, validated (see `from_config`)."""

    unit: str | None = None
    gain: float | tuple | None = None
    drop_first_reads: int = 0
    header: str = "fill"
    dq_bits: int | None = None
    reads: str | None = None

    @classmethod
    def from_config(cls, section, path="input"):
        """Validate an ``input:`` mapping (None: all defaults).

        Raises
        ------
        ConfigError
            An unknown key or a bad value; one line naming its YAML path.

        Examples
        --------
        >>> from spherex_reduce.io.input import InputOptions
        >>> InputOptions.from_config({"unit": "DN", "gain": [1.5, 2]}).gain
        (1.5, 2.0)
        >>> InputOptions.from_config({"gain": 0})
        Traceback (most recent call last):
        ...
        spherex_reduce.core.errors.ConfigError: input.gain: must be > 0, got 0.0
        """
        if isinstance(section, cls):
            return section
        values = validate_parameters(section, INPUT_PARAMETERS, path)
        if values["unit"] is not None:
            try:
                parse_unit(values["unit"])
            except ValueError:
                raise ConfigError(f"{path}.unit: {values['unit']!r} is not a unit astropy "
                                  "understands (or ADU, DN, counts, ELECTRONS, e-)") from None
        gain = values["gain"]
        if isinstance(gain, list):
            if not gain:
                raise ConfigError(f"{path}.gain: expected a number or one number per channel, "
                                  "got an empty list")
            gain = tuple(_GAIN.check(g, f"{path}.gain[{i}]") for i, g in enumerate(gain))
        values["gain"] = gain
        if values["dq_bits"] is not None:
            check_dq_bits(values["dq_bits"], f"{path}.dq_bits")
        return cls(**values)

    def to_config(self):
        """The section as plain YAML values: every key, ``reads`` only when set (a config
        without it keeps the hash, ``SXRCONF``, it had before the key existed)."""
        gain = list(self.gain) if isinstance(self.gain, tuple) else self.gain
        out = {"unit": self.unit, "gain": gain, "drop_first_reads": self.drop_first_reads,
               "header": self.header, "dq_bits": self.dq_bits}
        return out if self.reads is None else {**out, "reads": self.reads}

    def check_channels(self, nchannels, path="input"):
        """A gain per channel must give one number for each of ``nchannels``."""
        if isinstance(self.gain, tuple) and len(self.gain) != nchannels:
            raise ConfigError(f"{path}.gain: {len(self.gain)} values for {nchannels} readout "
                              "channels; give one number or one per channel")

    # -- applied by the readers ----------------------------------------------------
    def reconcile(self, header, supplied, name, notes):
        """The header to read the schedule from, given the config's ``supplied`` values.

        ``fill``: a keyword the file has and the config gives differently is
        refused (`FormatError` naming both).  ``override``: the file's keyword
        is replaced in ``header`` (changed in place) by the config's, recorded
        in ``HISTORY`` and appended to ``notes`` (a list: the warnings the
        reader logs once the file is accepted, so that a file refused later
        gets its error alone).  Returns the keys that the file states by
        another keyword only, for `check_derived`.
        """
        derived = []  # keys the file states only by another keyword (TFRAME / FRMOVH)
        for key, value in supplied.items():
            field = FIELD.get(key)
            if value is None or field is None:
                continue
            have = read_field(header, field)
            dropped = 0  # a file this package wrote after dropping reads: the ramp had more
            if key in ("nframes", "groups") and have is not None and "NDROPRD" in header:
                dropped = int(header["NDROPRD"])
            partners = [f.keyword for f in _partners(field) if f.keyword in header]
            if have is None and partners:
                if self.header == "fill":
                    derived.append(key)
                    continue
                self._override(header, "/".join(partners), "given", value, name, notes)
            if self.header == "override":
                for kw in partners:  # the config's value alone states it
                    header.remove(kw, ignore_missing=True)
            if have is None or _same(field, have, _before_drop(key, value, dropped)):
                continue
            shown = field.keyword if field.side_keywords is None else \
                "/".join((field.keyword, *field.side_keywords))
            if dropped:
                shown = f"{shown} (+ NDROPRD {dropped} reads dropped)"
            if self.header == "fill":
                raise FormatError(
                    f"{name}: keyword {shown} is {have} in the file but {key} is {value} in the "
                    "config; fix the config, or set input.header: override to use the config's")
            self._override(header, shown, have, value, name, notes)
            for kw in field.keywords:
                header.remove(kw, ignore_missing=True)
            for kw, v, comment in field_cards(field, value):
                header[kw] = (v, comment)
        return derived

    def check_derived(self, schedule, derived, supplied, name):
        """``fill``: the schedule's value of each ``derived`` key (stated in the file by
        another keyword, e.g. ``FRMOVH`` for ``frame_time``) must be the config's."""
        for key in derived:
            have = getattr(schedule, key)
            have = have.to_value(u.s) if isinstance(have, u.Quantity) else have
            if not _same(FIELD[key], float(have), supplied[key]):
                shown = "/".join(f.keyword for f in _partners(FIELD[key]))
                raise FormatError(
                    f"{name}: keyword {shown} gives {key} = {have:.6g} in the file but {key} "
                    f"is {supplied[key]} in the config; fix the config, or set input.header: "
                    "override to use the config's")

    @staticmethod
    def _override(header, keyword, have, value, name, notes):
        notes.append(f"{name}: keyword {keyword} = {have} replaced by the config's {value} "
                     "(input.header: override)")
        header.add_history(f"input.header override: {keyword} {have} -> {value} (config)")

    def unit_of(self, text, header, name, notes):
        """The data's unit from the file's ``BUNIT`` text (None: absent) and ``unit``
        (an override is appended to ``notes``, as by `reconcile`).

        ``unit`` is that of raw data: a file written by a pipeline (``SXRCONF``)
        keeps its own.
        """
        mine = None if self.unit is None or "SXRCONF" in header else parse_unit(self.unit)
        if text is None:
            return mine if mine is not None else u.electron
        try:
            have = parse_unit(text)
        except ValueError:
            if mine is None or self.header == "fill":
                hint = "set input.unit" if mine is None else "set input.header: override"
                raise FormatError(f"keyword BUNIT={text!r} is not a unit astropy understands; "
                                  f"{hint} to give the unit") from None
            have = None
        if mine is None or have == mine:
            return have
        if self.header == "fill":
            raise FormatError(f"{name}: keyword BUNIT is {text!r} in the file but unit is "
                              f"{self.unit!r} in the config; fix the config, or set "
                              "input.header: override to use the config's")
        self._override(header, "BUNIT", repr(text), repr(self.unit), name, notes)
        return mine

    def frames(self, header, schedule, ramp, name):
        """Frames dropped at the start of every ramp: ``(dropped, kept schedule)``.

        A file that records ``NDROPRD`` (written after its first reads were
        dropped) is not dropped again.
        """
        n = self.drop_first_reads
        done = header.get("NDROPRD")
        if done is not None:
            if n and done != n:
                raise FormatError(f"{name}: keyword NDROPRD is {done} (first reads already "
                                  f"dropped) but input.drop_first_reads is {n}")
            return 0, schedule
        if not n:
            return 0, schedule
        if not ramp:
            raise FormatError(f"{name}: input.drop_first_reads is {n} but the file holds an "
                              "image, not ramps: there are no reads to drop")
        if schedule.nframes - n < 2:
            raise FormatError(f"{name}: input.drop_first_reads is {n} but the file has "
                              f"NFRAMES={schedule.nframes}: at least 2 frames must remain")
        changes = {"nframes": schedule.nframes - n}
        if schedule.groups is not None:  # the groups kept, at the reads they were
            changes["groups"] = schedule.groups[n:]
        if schedule.read_times is not None:  # the reads kept, at their times
            changes["read_times"] = schedule.read_times[n:]
        kept = schedule.replace(**changes)
        for name in changes:
            for key, value, comment in field_cards(FIELD[name], getattr(kept, name)):
                header[key] = (value, comment)
        header["NDROPRD"] = (n, "frames dropped at the start of every ramp")
        header.add_history(f"input: the first {n} frame(s) of every ramp dropped (not fitted)")
        return n, kept

    def gains(self, unit, header, nchannels, name, notes):
        """The gain per channel ``(nchannels,)`` to apply (None: none) and the new unit
        (an override is appended to ``notes``, as by `reconcile`).

        A file in electrons whose header records the same gain (``GAIN`` or
        ``GAIN1 ...``: written after it was applied) is left as it is.
        """
        if self.gain is None:
            return None, unit
        self.check_channels(nchannels)
        per = np.broadcast_to(np.asarray(self.gain, float), (nchannels,))
        cards = _gain_cards(self.gain)
        if u.adu not in unit.bases:
            if all(header.get(k) == v for k, v, _ in cards):
                return None, unit  # already applied
            raise FormatError(f"{name}: input.gain converts ADU to electrons but the data are in "
                              f"{unit}; set input.unit (e.g. adu) if they are in ADU")
        for key, value, _ in cards:
            have = header.get(key)
            if have is not None and have != value:
                if self.header == "fill":
                    raise FormatError(
                        f"{name}: keyword {key} is {have} in the file but gain is {value} in "
                        "the config; fix the config, or set input.header: override to use "
                        "the config's")
                self._override(header, key, have, value, name, notes)
        for key, value, comment in cards:
            header[key] = (value, comment)
        header.add_history(f"input: data multiplied by the gain {list(per)} e-/ADU "
                           "(per channel)")
        return per, unit * u.electron / u.adu


def _partners(field):
    """Fields that state the same quantity another way (``frame_overhead``, ``frame_time``)."""
    if field.instead_of:
        return [FIELD[field.instead_of]]
    return [f for f in FIELD.values() if f.instead_of == field.name]


def _before_drop(key, value, dropped):
    """The config's ``value`` of ``key`` for a file whose first ``dropped`` frames were
    dropped when it was written (``NDROPRD``)."""
    if not dropped:
        return value
    return value - dropped if key == "nframes" else value[dropped:]


def _same(field, have, value):
    if field.to_text is not None:  # groups: lists of reads (tuples from Python)
        try:
            return [list(g) for g in have] == [list(g) for g in value]
        except TypeError:
            return False
    if field.side_keywords is not None:
        return check_sides(field, have) == check_sides(field, value)
    if isinstance(have, float) or isinstance(value, float):
        try:
            return math.isclose(float(have), float(value), rel_tol=1e-9)
        except (TypeError, ValueError):
            return False
    return have == value


def _gain_cards(gain):
    if isinstance(gain, tuple):
        return [(f"GAIN{i + 1}", g, f"e-/ADU applied to channel {i + 1}")
                for i, g in enumerate(gain)]
    return [("GAIN", gain, "e-/ADU applied to the data")]


def scale_columns(per_channel, geometry, dtype):
    """The gain of every column, ``(ncols,)`` in ``dtype``, from one per channel (or None)."""
    if per_channel is None:
        return None
    return per_channel[geometry.channel_of_column()].astype(dtype)


def apply_gain(values, per_channel, geometry):
    """``values`` (``(..., columns)``, floating point) multiplied in place by the gain of
    each column's channel (``per_channel`` from `InputOptions.gains`; None: unchanged).
    The readers of bands use it, with the arithmetic of a whole read, bit for bit."""
    if per_channel is not None:
        values *= scale_columns(per_channel, geometry, values.dtype)
    return values


def apply_input(d, data, err, mask, phantom):
    """The arrays of a file described by `describe` with its first frames dropped and its
    gain applied (``input:``); the readers of bands (`FrameReader`) do the same."""
    drop = d.drop
    if drop:
        data, err, mask, phantom = (None if a is None else a[drop:]
                                    for a in (data, err, mask, phantom))
    gain = d.gain
    if gain is not None:
        geometry = d.kept.geometry
        if data is not None:
            data = data * scale_columns(gain, geometry, data.dtype)
        if err is not None:
            err = err * scale_columns(gain, geometry, err.dtype)
        if phantom is not None:
            phantom = phantom * gain.astype(phantom.dtype)
    return data, err, mask, phantom
