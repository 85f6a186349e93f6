"""The noise streams of a raw exposure in time order, and the fit of their PSDs.

`reference_timestream` and `phantom_timestream` read the reference pixels and
the phantom values of a raw exposure in time order; `fit_raw_noise` fits the
noise model of `spherex_reduce.analysis.temporal` to their PSDs.

The streams, and the pixels each one holds (which pixels are reference pixels
comes from the geometry alone: `~spherex_reduce.DetectorGeometry.reference_column_mask`
and `~spherex_reduce.DetectorGeometry.reference_pixel_mask`):

- ``border columns``: per row read, the mean of the side reference columns of
  each side (every read, reference rows included: all reference pixels);
- ``re-read rows``: every pixel of the reads of reference rows (rows whose
  pixels are all reference pixels), at the pixel rate;
- ``phantom``: the phantom values (samples of no pixel) of each channel.

No stream holds a light-sensitive pixel: their values (a bright star, a hot
pixel, the dark current) never enter a noise fit.

Streams read out of a raw exposure are not sampled at the pixel rate: a
phantom value is the mean of ``c`` consecutive samples, taken once per row read
(every ``row_samples`` samples), and a reference-column value likewise the mean
of a side's reference columns.  Their PSD is the pixel-rate PSD filtered
by the ``c``-sample box and aliased into the row rate;
`aliased_basis` gives the three model terms of such a stream, so the fit
returns the coefficients of the underlying 100 kHz process directly.
"""

import warnings
from typing import NamedTuple

import numpy as np
from astropy import units as u
from astropy.table import Table
from astropy.utils.exceptions import AstropyUserWarning

from ..core.errors import SpherexReduceError
from ..core.exposure import Exposure
from ..reduce.steps.reference.noise_models import NEGATIVE_SIGMAS
from .temporal import PARAMS, aliased_basis, fit_noise_model, temporal_psd

__all__ = ["StreamPixels", "Timestream", "detrend_frames", "fit_raw_noise", "keep_some",
           "left_out_samples", "phantom_timestream", "reference_timestream"]


# -- streams of a raw exposure ----------------------------------------------------------
class Timestream(NamedTuple):
    """Values of a stream with the sample index of each value (in pixel-rate samples)."""

    #: ``(..., nframes, n)``: streams first (channels), then frames, then time within a frame
    values: np.ndarray
    #: ``(nframes, n)``: sample index from the start of the exposure (the value's first sample)
    samples: np.ndarray
    #: samples averaged into each value (``c`` for phantoms)
    nbox: int
    #: the pixel rate (Hz)
    sample_rate: float
    #: spacing (samples) of the averaged samples, or of the values of a burst
    stride: int = 1
    #: per stream (first axis), the mean over its values of ``nbox`` / the samples averaged
    #: into each, where pixels are left out (``leave_out``): the factor of its white level;
    #: empty: 1
    white: tuple = ()


def _raw(exposure):
    if not exposure.is_ramp or exposure.order != "readout":
        raise SpherexReduceError(
            "noise streams come from a raw exposure: ramps (frames × reads × columns) in "
            f"readout order; got {'ramps' if exposure.is_ramp else 'an image'} in "
            f"{exposure.order} order: give the raw file (the one that was reduced), whose "
            "reference pixels and phantom values are read over time"
        )
    if exposure.schedule.nframes < 3:
        raise SpherexReduceError("noise streams need at least 3 frames (a line is removed "
                                 "from every position across frames)")


class StreamPixels(NamedTuple):
    """What the reference and phantom streams of a raw exposure read: its reference columns
    at every read, every column of its reference rows' reads and its phantom values.

    A full-size dark's are a few tens of MB: a dark read band by band of reads
    (`~spherex_reduce.analysis.characterize.streams.dark_streams`) gathers them
    without holding the dark whole; `of` takes them from an exposure in memory.
    `reference_timestream` and `phantom_timestream` take either.

    Examples
    --------
    >>> from spherex_reduce.io.examples import example_raw_exposure
    >>> from spherex_reduce.analysis.timestreams import StreamPixels
    >>> px = StreamPixels.of(example_raw_exposure())
    >>> px.column_values.shape[-1] == px.columns.size, px.read_values.shape[1] == px.reads.size
    (True, True)
    """

    #: the `~spherex_reduce.ReadoutSchedule` of the exposure
    schedule: object
    #: the reference columns (`~spherex_reduce.DetectorGeometry.reference_column_mask`),
    #: ascending
    columns: np.ndarray
    #: ``(nframes, n_reads, columns.size)``: their values at every read
    column_values: np.ndarray
    #: the reads of reference rows (`reference_row_reads`)
    reads: np.ndarray
    #: ``(nframes, reads.size, ncols)``: every column of those reads
    read_values: np.ndarray
    #: ``(nframes, n_reads, nchannels)`` or None
    phantom: np.ndarray | None = None

    @classmethod
    def of(cls, exposure):
        """The stream pixels of a raw exposure (ramps in readout order) in memory."""
        _raw(exposure)
        s = exposure.schedule
        data = np.asarray(exposure.data.data)
        columns = np.flatnonzero(s.geometry.reference_column_mask())
        reads = reference_row_reads(s)
        return cls(s, columns, data[:, :, columns], reads, data[:, reads],
                   None if exposure.phantom is None else np.asarray(exposure.phantom))


def _pixels(exposure):
    """`StreamPixels` of an exposure (checked: raw ramps in readout order), or as given."""
    return exposure if isinstance(exposure, StreamPixels) else StreamPixels.of(exposure)


def detrend_frames(values):
    """Remove a straight line across frames (axis -2) at every position; float64 copy.

    Returns the residual scaled by ``sqrt(N / (N - 2))`` so that noise that is
    independent from frame to frame keeps its variance.  A pixel's bias and
    dark current (a straight line in time) are removed with it.

    Examples
    --------
    >>> import numpy as np
    >>> from spherex_reduce.analysis.timestreams import detrend_frames
    >>> ramp = 100.0 + 5.0 * np.arange(4.0)[:, None] + np.array([[1.0], [-1.0], [-1.0], [1.0]])
    >>> detrend_frames(ramp).ravel().round(3).tolist()
    [1.414, -1.414, -1.414, 1.414]
    """
    v = np.asarray(values, dtype=np.float64)
    n = v.shape[-2]
    t = np.arange(n, dtype=float) - (n - 1) / 2
    mean = v.mean(axis=-2, keepdims=True)
    slope = np.tensordot(t, v, axes=([0], [v.ndim - 2])) / np.sum(t**2)
    res = v - mean  # then in place: no third copy of a dark's streams
    res -= t[:, None] * slope[..., None, :]
    res *= np.sqrt(n / (n - 2))
    return res


def _frame_samples(schedule, within):
    within = np.asarray(within, dtype=np.int64)
    frames = np.arange(schedule.nframes, dtype=np.int64) * schedule.frame_samples
    return frames.reshape((-1,) + (1,) * within.ndim) + within[None, ...]


def _side_columns(geometry):
    """The side reference columns averaged into the ``'columns'`` stream, one array per side.

    A side is a run of adjacent reference columns of one channel
    (`~spherex_reduce.DetectorGeometry.reference_column_mask`, the one source
    of which columns are reference columns).  Every side gives the same number
    of columns, the narrowest side's: those farthest from the light-sensitive
    columns (the first ones of a side left of them, the last ones of a side
    right of them).
    """
    mask = geometry.reference_column_mask()
    cols = np.flatnonzero(mask)
    if cols.size == 0:
        return []
    channel = geometry.channel_of_column()
    breaks = np.flatnonzero((np.diff(cols) != 1) | (np.diff(channel[cols]) != 0)) + 1
    runs = np.split(cols, breaks)
    width = min(r.size for r in runs)
    right_of_light = [r[0] > 0 and channel[r[0] - 1] == channel[r[0]] and not mask[r[0] - 1]
                      for r in runs]
    return [r[-width:] if right else r[:width] for r, right in zip(runs, right_of_light,
                                                                   strict=True)]


def reference_row_reads(schedule):
    """Indices of the reads of a frame whose row is reference pixels only.

    Which pixels are reference pixels comes from
    `~spherex_reduce.DetectorGeometry.reference_pixel_mask` (a row all of
    whose pixels are reference pixels: the top and bottom border).

    Examples
    --------
    >>> from spherex_reduce import DetectorGeometry, ReadoutSchedule
    >>> from spherex_reduce.analysis.timestreams import reference_row_reads
    >>> g = DetectorGeometry(8, 8, 1, ref_border={"top": 2, "left": 1})
    >>> reference_row_reads(ReadoutSchedule(g, skip=1, ref_mode="none", ref_reads=0,
    ...                                     phantom_reads=0, nframes=3)).tolist()
    [0, 1]
    """
    g = schedule.geometry
    return np.flatnonzero(g.reference_pixel_mask().all(axis=1)[schedule.rows])


def phantom_timestream(exposure):
    """Phantom values of every channel in time order, detrended across frames.

    Parameters
    ----------
    exposure : `~spherex_reduce.Exposure` or `StreamPixels`
        Raw ramps in readout order with a ``phantom`` array (or their stream pixels).

    Returns
    -------
    `Timestream`
        ``values`` ``(nchannels, nframes, n_reads)``; ``samples`` the first of
        the ``c`` phantom samples of each read.  A straight line across frames
        is removed at every read position (the Video8 leakage drift and any
        offset) and the residual rescaled by ``sqrt(N/(N−2))``.
    """
    px = _pixels(exposure)
    s = px.schedule
    if px.phantom is None or s.phantom_reads == 0:
        raise SpherexReduceError("the exposure has no phantom reads (c = 0 or no PHANTOM)")
    vals = np.moveaxis(np.asarray(px.phantom), -1, 0)  # channels, frames, reads
    return Timestream(detrend_frames(vals), _frame_samples(s, s.phantom_samples()[:, 0]),
                      s.phantom_reads, s.geometry.pixel_rate)


def reference_timestream(exposure, source="columns", parity=None, leave_out=None):
    """Reference-pixel values in time order, detrended across frames.

    Parameters
    ----------
    exposure : `~spherex_reduce.Exposure` or `StreamPixels`
        Raw ramps in readout order (or their stream pixels).
    source : {'columns', 'rows'}
        ``'columns'``: the side reference columns
        (`~spherex_reduce.DetectorGeometry.reference_column_mask`: left of
        the first channel, right of the last, the sides ``ref_border``
        declares), the same number from each side (the narrower side's,
        farthest from the light-sensitive columns), averaged per read: one
        value per row read, ``values`` ``(sides, nframes, n_reads)``.
        ``'rows'``: every pixel of every read of a reference row (a row all
        of whose pixels are reference pixels, `reference_row_reads`) of every
        channel at the pixel rate, in each channel's scan order, ``values``
        ``(nchannels, nframes, n_ref_reads, width)``.
    parity : {None, 'even', 'odd'}
        Keep only the pixels sampled at even or odd offsets of a channel's
        row read (the column parities that alternating column noise, ACN,
        gives independent realisations); ``stride`` becomes 2.
    leave_out : array_like of bool, optional
        ``(nrows, ncols)`` in physical order: pixels left out (a telegraph or hot
        pixel whose noise a per-pixel model holds).  ``'columns'``: each read's
        mean is over a side's other columns (``white``: the factor this gives
        the white level; a read none of whose columns is left keeps them all);
        ``'rows'``: their values are NaN.

    Returns
    -------
    `Timestream`
        ``samples`` has the sample index of each value (the first averaged
        sample for ``'columns'``).
    """
    px = _pixels(exposure)
    s = px.schedule
    g = s.geometry
    if parity not in (None, "even", "odd"):
        raise SpherexReduceError(f"parity must be None, 'even' or 'odd', got {parity!r}")
    first_off = {None: 0, "even": 0, "odd": 1}[parity]
    stride = 1 if parity is None else 2
    offs = g.column_offsets()
    if source == "columns":
        sides = _side_columns(g)
        if not sides:
            raise SpherexReduceError("the array has no side reference columns "
                                     f"(ref_border = {g.border})")
        if parity is not None:
            sides = [c[offs[c] % 2 == first_off] for c in sides]
            if any(c.size == 0 for c in sides):
                raise SpherexReduceError("the border has no columns of that parity")
        nbox = sides[0].size
        drop = left_out_samples(leave_out, s)
        vals, white = [], []
        for c in sides:
            values = px.column_values[:, :, np.searchsorted(px.columns, c)]
            if drop is None:
                vals.append(values.mean(axis=-1))
                continue
            keep = keep_some(~drop[:, c], axis=1)  # a read with every column left out
            count = keep.sum(axis=1)
            vals.append(np.sum(values * keep, axis=-1, dtype=np.float64) / count)
            white.append(float(np.mean(nbox / count)))
        first = s.starts + offs[sides[0]].min()
        return Timestream(detrend_frames(np.stack(vals)), _frame_samples(s, first), nbox,
                          g.pixel_rate, stride, tuple(white))
    if source == "rows":
        reads = px.reads
        if reads.size == 0:
            raise SpherexReduceError("the schedule has no reference-row reads")
        w = g.channel_width
        order = np.argsort(offs.reshape(g.nchannels, w), axis=1)
        cols = order + (np.arange(g.nchannels) * w)[:, None]  # (nchannels, w) in scan order
        if parity is not None:  # by the offset in the row read (a window's: the full one's)
            cols = cols[:, offs[cols[0]] % 2 == first_off]
        vals = px.read_values[:, :, cols]  # frames, nref, nchannels, w'
        vals = np.moveaxis(vals, 2, 0)  # channels, frames, nref, w'
        flat = detrend_frames(vals.reshape(g.nchannels, s.nframes, -1))
        drop = left_out_samples(leave_out, s)
        if drop is not None:
            gone = np.moveaxis(drop[reads][:, cols], 1, 0)  # channels, nref, w'
            flat[np.broadcast_to(gone.reshape(g.nchannels, 1, -1), flat.shape)] = np.nan
        samples = s.starts[reads][:, None] + offs[cols[0]][None, :]
        return Timestream(flat.reshape(vals.shape), _frame_samples(s, samples), 1, g.pixel_rate,
                          stride)
    raise SpherexReduceError(f"source must be 'columns' or 'rows', got {source!r}")


def keep_some(keep, axis):
    """``keep`` with every member kept where ``axis`` would keep none of them (the rule
    that leaves a stream's samples out: never all of a read's, or a channel's).

    Examples
    --------
    >>> import numpy as np
    >>> from spherex_reduce.analysis.timestreams import keep_some
    >>> keep_some(np.array([[True, False], [False, False]]), axis=1).tolist()
    [[True, False], [True, True]]
    """
    return keep | ~keep.any(axis=axis, keepdims=True)


def left_out_samples(leave_out, schedule):
    """``(n_reads, ncols)``: the samples of each read of a frame that ``leave_out``
    (``(nrows, ncols)`` bool, physical order) leaves out; None without one.

    Examples
    --------
    >>> import numpy as np
    >>> from spherex_reduce import DetectorGeometry, ReadoutSchedule
    >>> from spherex_reduce.analysis.timestreams import left_out_samples
    >>> g = DetectorGeometry(8, 8, 1, ref_border={"top": 2})
    >>> s = ReadoutSchedule(g, skip=1, ref_mode="none", ref_reads=0, phantom_reads=0,
    ...                     nframes=3)
    >>> drop = np.zeros((8, 8), bool)
    >>> drop[5, 3] = True
    >>> read = int(np.flatnonzero(s.rows == 5)[0])        # the read of row 5
    >>> np.argwhere(left_out_samples(drop, s)).tolist() == [[read, 3]]
    True
    """
    if leave_out is None:
        return None
    g = schedule.geometry
    drop = np.asarray(leave_out, dtype=bool)
    if drop.shape != (g.nrows, g.ncols):
        raise SpherexReduceError(f"leave_out must be ({g.nrows}, {g.ncols}), the pixels of "
                                 f"the geometry; got {drop.shape}")
    return drop[schedule.rows]


def _burst_length(g, split):
    """Samples per reference-row burst of one channel (one parity if ``split``)."""
    return g.channel_width // 2 if split else g.channel_width


def _joined(streams):
    """One `Timestream` of the streams of several exposures of one schedule: their values
    side by side on the first axis (independent realisations of the same process)."""
    first = streams[0]
    return first._replace(values=np.concatenate([t.values for t in streams], axis=0))


def _parities(exposure, source, split):
    """The reference streams of ``source``, one per column parity when ``split``."""
    return [reference_timestream(exposure, source, p)
            for p in (("even", "odd") if split else (None,))]


def _streams(exposures, acn):
    """The streams `fit_raw_noise` fits, of every exposure joined, and their schedule and
    unit: ``schedule, unit, {name: [Timestream]}`` (one `Timestream` per column parity for
    the reference streams split by ``acn``).  Only the streams are kept, not the exposures."""
    schedule = unit = None
    parts = {}
    for k, e in enumerate(exposures):
        _raw(e)
        if schedule is None:
            schedule, unit = e.schedule, e.unit
        elif e.schedule != schedule or e.unit != unit:
            raise SpherexReduceError(
                f"exposure {k} has another schedule or unit ({e.unit}) than exposure 0 "
                f"({unit}): the streams of one fit come from one readout")
        g = e.geometry
        got = {}
        sides = _side_columns(g)
        if sides:
            got["border columns"] = _parities(e, "columns", acn and sides[0].size >= 2)
        if reference_row_reads(schedule).size:
            got["re-read rows"] = _parities(e, "rows", acn and g.channel_width >= 8)
        if e.phantom is not None and schedule.phantom_reads:
            got["phantom"] = [phantom_timestream(e)]
        for name, streams in got.items():
            parts.setdefault(name, []).append(streams)
    if schedule is None:
        raise SpherexReduceError("no exposure to fit")
    joined = {name: [_joined(list(p)) for p in zip(*per, strict=True)]
              for name, per in parts.items()}
    return schedule, unit, joined


def _parity_psd(streams, rate, nperseg):
    """Welch PSD of a reference stream, the mean over its column parities.

    The even and odd PSDs are averaged but the uncertainty counts the streams
    of one parity only: right when the parities are correlated (no ACN),
    conservative by up to √2 when they are independent.
    """
    spectra = [temporal_psd(t.values, rate, nperseg=nperseg) for t in streams]
    spec = spectra[0]
    total = spec["psd"]
    for other in spectra[1:]:
        total = total + other["psd"]
    spec["psd"] = total / len(spectra)
    return spec


#: Limits of a plausible noise fit (`implausible_fits`).
MAX_CHI2_PER_DOF, MIN_RELATIVE_ERROR = 10.0, 1e-12  # NEGATIVE_SIGMAS: the rule wiener applies
#: Fewest degrees of freedom (frequency bins less coefficients) that test a fit
MIN_DOF = 3


def implausible_fits(table):
    """What makes each stream's fit of a `fit_raw_noise` table implausible, if anything.

    A coefficient (``alpha``, ``beta``, ``gamma``) below zero by more than 3 of
    its standard errors (the model power would go negative), ``chi2/dof`` above
    10 (the model does not describe the spectrum), an error bar smaller
    than floating-point noise (``< 1e-12`` of the value: a degenerate fit), or
    fewer than `MIN_DOF` degrees of freedom (too few frequency bins to test
    the model: a stream of a few reads).

    Returns
    -------
    dict
        ``{stream: [reason, ...]}`` for the streams with a reason only.

    Examples
    --------
    >>> from astropy.table import Table
    >>> from spherex_reduce.analysis.timestreams import implausible_fits
    >>> t = Table({"stream": ["reference"], "alpha": [0.01], "alpha_err": [1e-3],
    ...            "beta": [-350.0], "beta_err": [9.8], "gamma": [2.6e3], "gamma_err": [1.3],
    ...            "chi2": [0.5], "dof": [12]})
    >>> implausible_fits(t)
    {'reference': ['beta = -350 is 36 sigma below zero']}
    """
    out = {}
    for row in table:
        why = []
        for name in ("alpha", "beta", "gamma"):
            value, err = float(row[name]), float(row[f"{name}_err"])
            if value < -NEGATIVE_SIGMAS * err:
                why.append(f"{name} = {value:.3g} is "
                           + (f"{-value / err:.0f} sigma below zero" if err > 0
                              else "below zero"))
            elif value != 0 and 0 < err < MIN_RELATIVE_ERROR * abs(value):
                why.append(f"{name} = {value:.3g} ± {err:.2g}, an error below floating-point "
                           "noise")
        if row["dof"] > 0 and row["chi2"] / row["dof"] > MAX_CHI2_PER_DOF:
            why.append(f"chi2/dof = {row['chi2']:.3g}/{row['dof']}")
        if row["dof"] < MIN_DOF:
            why.append(f"{row['dof']} degrees of freedom: too few frequency bins to test the "
                       "model (use more rows or reads)")
        if why:
            out[str(row["stream"])] = why
    return out


def fit_raw_noise(exposure, exponent=1.3, nperseg=None, nbins=30, fit=PARAMS, acn=True):
    """Fit eq. 1 to the reference-pixel and phantom streams of raw exposures.

    Welch spectra are computed within frames (segments never span the
    frame overhead).  Reference columns and phantom values are modelled as
    box-averaged, decimated streams (`aliased_basis`); reference rows are
    bursts at the pixel rate.  The reference fit joins columns and rows.
    Several exposures of one readout (the integrations of a 4-D file) give
    independent realisations of each stream: each is detrended across its own
    frames, and their periodograms are averaged (the uncertainties count
    them all).

    Parameters
    ----------
    exposure : `~spherex_reduce.Exposure` or iterable of them
        Raw ramps in readout order; several (read one at a time from an
        iterator, so only their streams are held) must have one schedule
        and unit.
    exponent : float or None
        Exponent of the third term; ``None`` fits it per stream.
    nperseg : int, optional
        Welch segment length of the per-read streams (default: the largest
        power of two not above the reads per frame).
    nbins : int
        Logarithmic bins per spectrum.
    fit : sequence of str
        Terms to fit.
    acn : bool
        Treat even and odd columns (offsets within a channel's row read) as
        separate streams, as alternating column noise makes them (paper §3.2;
        the simulator's default for Video8 and ROIC).  Averaging across
        parities would halve the low-frequency power of ACN terms.  The
        result is right with or without ACN; the uncertainties count one
        parity's streams, so they are conservative (by up to √2) when the
        parities are independent.  ``False`` uses every column as one stream.

    Returns
    -------
    `~astropy.table.Table`
        One row per stream (``reference``, ``phantom`` where the exposure has
        phantom reads): ``stream alpha alpha_err beta beta_err gamma gamma_err
        exponent chi2 dof fmin fmax`` (coefficients in the exposure's unit²
        per Hz etc., for the pixel-rate process).  ``meta['fits']`` holds the
        `NoiseModelFit` objects (not written to files).

    Examples
    --------
    >>> from spherex_reduce.io.examples import example_raw_exposure
    >>> from spherex_reduce.analysis import fit_raw_noise
    >>> e = example_raw_exposure()
    >>> one = fit_raw_noise(e, fit=("alpha",))
    >>> one["stream"].tolist(), str(one["alpha"].unit)
    (['reference', 'phantom'], 'electron2 / Hz')

    Two integrations (here the same one twice) average two periodograms per
    stream: the errors shrink by √2.

    >>> two = fit_raw_noise([e, e], fit=("alpha",))
    >>> round(float(one["alpha_err"][0] / two["alpha_err"][0]), 3)
    1.414
    """
    s, unit, streams = _streams([exposure] if isinstance(exposure, Exposure) else exposure,
                                acn)
    g = s.geometry
    fs, m = g.pixel_rate, s.row_samples
    nreads = s.n_reads
    nper = nperseg or 2 ** int(np.floor(np.log2(nreads)))
    nper = min(nper, nreads)
    rows, fits_ = [], {}
    frate = fs / m
    spectra, bases, names = [], [], []
    if "border columns" in streams:
        ts = streams["border columns"]
        spectra.append(_parity_psd(ts, frate, nper))
        names.append("border columns")
        bases.append(lambda f, e, b=ts[0].nbox, st=ts[0].stride: aliased_basis(f, fs, m, b, e,
                                                                               stride=st))
    if "re-read rows" in streams:
        tr = streams["re-read rows"]
        split = len(tr) == 2
        spectra.append(_parity_psd(tr, fs / 2 if split else fs, _burst_length(g, split)))
        names.append("re-read rows")
        bases.append(lambda f, e, d=tr[0].stride: aliased_basis(f, fs, d, 1, e))
    unit = unit or u.one
    if spectra:
        fits_["reference"] = fit_noise_model(spectra, exponent, nbins=nbins, fit=fit,
                                             basis=bases)
    if "phantom" in streams:
        spec = temporal_psd(streams["phantom"][0].values, frate, nperseg=nper)
        fits_["phantom"] = fit_noise_model(
            spec, exponent, nbins=nbins, fit=fit,
            basis=lambda f, e: aliased_basis(f, fs, m, s.phantom_reads, e))
    if not fits_:
        raise SpherexReduceError("the exposure has neither reference pixels nor phantom reads")
    for name, fit_ in fits_.items():  # for plots: what each spectrum is, and the PSD's unit
        fit_.bins.meta.update({"spectra": names if name == "reference" else [name],
                               "psd_unit": unit**2 / u.Hz})
    for name, r in fits_.items():
        rows.append({"stream": name, **r.to_row()})
    t = Table(rows=rows)
    units = {"alpha": unit**2 / u.Hz, "beta": unit**2}
    if exponent is not None:
        units["gamma"] = unit**2 * u.Hz ** (exponent - 1)
    for p, unit_p in units.items():
        t[p].unit = unit_p
        t[f"{p}_err"].unit = unit_p
    t["fmin"].unit = t["fmax"].unit = u.Hz
    flags = implausible_fits(t)
    if flags:
        t.meta["implausible"] = flags
        warnings.warn("implausible noise fit: " + "; ".join(
            f"{stream}: {', '.join(why)}" for stream, why in flags.items())
            + " (more frames, another band or a fixed exponent may help)",
            AstropyUserWarning, stacklevel=2)
    t.meta["fits"] = fits_
    label = "exponent" if exponent is None else exponent
    t.meta["comments"] = [f"p(f) = alpha + beta/f + gamma/f^{label}, one-sided, "
                          f"pixel rate {fs:g} Hz; {s.summary()}"]
    return t
