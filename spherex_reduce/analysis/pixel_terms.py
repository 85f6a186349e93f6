"""Per-pixel terms of a detector learnt from its darks (issue 33's per-pixel slice).

`fit_pixel_terms` measures, from one or several dark ramps of the same array,
what the simulator's scene adds pixel by pixel (``scene.dark_current``,
``scene.hot_pixel_fraction``, ``scene.hot_pixel_current``, ``scene.rtn``), a
read-noise map and the first read's (reset) offset; `PixelTerms.to_scene`
turns them into the ``scene:`` mapping.  Everything comes from each pixel's
first differences ``d_k = x_{k+1} - x_k`` over the reads after the first
(read 0 is kept aside: a reset offset moves it alone), computed over bands of
rows so that a full array needs one band of float32 work arrays at a time.
Pixels with a non-finite read (flagged NaN) are left out of everything.

Per pixel, per dark:

- **jumps**: ``|e_k| > jump_sigma × 1.4826 × median(|e|)``, ``e_k = d_k - mean
  rate × dt_k`` (the pixel's own robust scale, so a hot pixel's shot noise is not
  a jump, floored at the median scale of the band's pixels);
- **dark current**: the least-squares slope of the ramp, written on the
  differences (weights ``(k + 1)(m - k)``), with the jumps left out;
- **read-noise variance**: the sum of squares of the differences about that
  slope, less the dark current's shot noise (``I dt / gain``, ``I`` the pixel's
  own slope, not clipped at 0: its mean over pixels is then the mean current's),
  divided by its exact expectation per unit read-noise variance (white reads:
  the differences are correlated, so no ``ddof`` guess);
- **telegraph**: at least two jumps over the darks, alternating in sign within
  each dark (a cosmic ray jumps once, up).  For a two-state telegraph read at
  a regular interval the flips of successive intervals are independent with
  probability ``p = (1 - exp(-2 rate dt)) / 2``, so a pixel's flip count is
  binomial; the rate is the maximum-likelihood ``p`` of the counts given at
  least two (the detection condition) and the fraction is corrected for the
  telegraph pixels that flipped fewer than two times.  The amplitude is the
  mean size of the telegraph pixels' jumps.  A telegraph step below about
  ``jump_sigma`` times the differences' noise is not seen: the limit is
  stated in the note of ``telegraph_fraction``;
- **first-read offset**: read 0 less the line of the other reads at its time.

The existing reference-pixel search
(`~spherex_reduce.reduce.steps.reference.telegraph.find_telegraph`) is not
used: it scores the variance of a pixel's levels against its channel's, which
suits reference pixels (no current), but an active pixel's levels wander with
its dark current's shot noise (a hot pixel scores as a telegraph), and it
gives neither the amplitude nor the rate the scene needs.

The population terms are means (clipped at 5 robust standard deviations where
a tail would be unphysical; the read-noise variances, skewed when a pixel has few
degrees of freedom, where a ``χ²`` of theirs is beyond its 10⁻⁶ quantile, the
mean corrected for that cut) and ratios of sums over pixels; their
uncertainties come from a delete-a-group jackknife
over ``groups`` fixed pseudo-random groups of pixels, the per-pixel values
pooled over all darks first: this holds the pixels' own sampling (a fraction
of 4096 pixels is a binomial draw, which the scatter between darks of the same
pixels would leave out, as would two halves of one dark) and their
measurement noise.  A drift common to all pixels of a dark (the streams' 1/f)
is the stream model's term and is not removed here.
"""

import warnings
from dataclasses import dataclass, field

import numpy as np
from astropy import units as u
from astropy.table import Table
from scipy.optimize import brentq
from scipy.stats import binom, chi2

from ..core.errors import SpherexReduceError
from ..reduce.steps.reference.telegraph import MAD_TO_SIGMA
from .faint_telegraph import FAINT_TERMS, add_faint_terms
from .pixel_sums import MIN_READS, MIN_TELEGRAPH_INTERVALS, SCALE_CAP, add_dark, new_sums

__all__ = ["HOT_SIGMA", "MIN_READS", "MIN_TELEGRAPH_INTERVALS", "PixelSums", "PixelTerms",
           "dark_ramps", "dark_rows", "fit_pixel_terms", "pixel_rows"]

#: A pixel's flip probability above which the rate is not constrained (switches faster
#: than the reads: every interval is close to a coin toss).
MAX_FLIP_PROBABILITY = 0.45
#: Robust standard deviations above the median slope from which a pixel is hot.
HOT_SIGMA = 10.0
#: Standard deviations of a difference by which a found telegraph pixel's mean jump clears
#: the jumps' threshold (else it is fitted with the faint population).
CLEAR_SIGMA = 3.0
#: Standard errors (from the scatter of its slope between darks, with 3 or more) by which a
#: hot pixel's mean current exceeds the threshold: a telegraph pixel's slope crosses it in
#: one dark and not the next (36 % of 30 e steps at 0.3 Hz were hot before).
HOT_CONSISTENCY = 5.0
#: Chance that a white-noise pixel's read-noise variance is clipped from the mean
#: (`_typical_variance`; the truncation it leaves is corrected exactly).
_VARIANCE_CLIP = 1e-6
_POPULATIONS = ("active", "reference")


@dataclass(frozen=True)
class PixelTerms:
    """What `fit_pixel_terms` measured.

    Attributes
    ----------
    table : `~astropy.table.Table`
        One row per term: ``term``, ``pixels`` (active, reference or all),
        ``value``, ``error`` (one standard deviation), ``unit``, ``status``
        (``fitted``, ``ruled out``: consistent with none, or ``not
        constrained``: value and error NaN) and ``note`` (the reason, or
        what the value means).
    maps : dict of `~astropy.units.Quantity` or `numpy.ndarray`
        ``(ny, nx)``, NaN at pixels with a non-finite read (their count is
        ``table.meta["unusable_pixels"]``): ``read_noise`` and ``read_noise_error`` (unit),
        ``dark_current`` and ``dark_current_error`` (unit/s), ``first_read_offset``
        (unit; NaN without one), ``hot`` and ``telegraph`` (bool),
        ``telegraph_amplitude`` (unit) and ``telegraph_rate`` (Hz, from the
        pixel's own flips; inf when it flipped at half its intervals or more),
        NaN off the telegraph pixels.
    unit : `~astropy.units.Unit`
        The darks' unit (electron or adu).
    gain : float
        Electrons per unit (1 for electrons).
    """

    table: Table
    maps: dict = field(repr=False)
    unit: u.UnitBase = u.electron
    gain: float = 1.0

    def row(self, term, pixels="all"):
        """The table row of ``term`` for ``pixels`` as a dict of plain values (KeyError if
        absent)."""
        sel = (self.table["term"] == term) & (self.table["pixels"] == pixels)
        if not sel.any():
            raise KeyError(f"no term {term!r} for {pixels} pixels")
        row = self.table[np.flatnonzero(sel)[0]]
        return {name: row[name].item() for name in self.table.colnames}

    def faint_population(self):
        """The faint telegraph population as the scene holds it, ``{"fraction",
        "amplitude", "rate"}`` (the active pixels'), when all three are fitted; else None
        (also without the faint terms)."""
        try:
            rows = [self.row(f"faint_telegraph_{k}", "active")
                    for k in ("fraction", "amplitude", "rate")]
        except KeyError:
            return None
        if any(r["status"] != "fitted" for r in rows):
            return None
        return {k: float(r["value"]) for k, r in zip(("fraction", "amplitude", "rate"), rows,
                                                     strict=True)}

    def to_scene(self):
        """The ``scene:`` mapping of these terms, in the darks' unit (per second for currents).

        ``dark_current`` is the mean current of the active pixels that are not
        hot, ``hot_pixel_current`` the mean excess of the hot ones, each with its
        spread (``*_spread``: the pixels' standard deviation less their
        measurement noise) where one is found, and ``rtn`` the telegraph
        populations: one with ``pixels: all`` when the active and reference
        populations agree within 3 standard deviations in fraction, amplitude
        and rate (their inverse-variance means; the active pixels' spreads),
        else a list of both (each with its ``amplitude_spread`` and
        ``rate_spread`` where found), else whichever was found, and the faint
        population (``faint_telegraph_*``) where fitted; left out when none was.

        Returns
        -------
        dict
            ``{"dark_current", "hot_pixel_fraction", "hot_pixel_current"[, "rtn"]}``
            and the spreads found (a term not fitted is left out: the scene's
            default, none of it), plain floats, ready for
            `~spherex_reduce.simulation.load_scene`, in the darks' unit (the
            scene's ``unit:``).

        Examples
        --------
        >>> import numpy as np
        >>> from astropy import units as u
        >>> from spherex_reduce.analysis.pixel_terms import fit_pixel_terms
        >>> rng = np.random.default_rng(1)
        >>> t = np.arange(20) * 1.5
        >>> x = rng.normal(0, 10, (20, 32, 32)) + 2.0 * t[:, None, None]
        >>> scene = fit_pixel_terms(x * u.electron, t * u.s).to_scene()
        >>> round(scene["dark_current"], 1), sorted(scene)
        (2.0, ['dark_current', 'hot_pixel_fraction'])
        """
        out = {}
        for term in ("dark_current", "hot_pixel_fraction", "hot_pixel_current"):
            row = self.row(term, "active")
            if row["status"] == "fitted":  # else the scene's default (none of it)
                out[term] = max(row["value"], 0.0)
        for term, of in (("dark_current_spread", "dark_current"),
                         ("hot_pixel_current_spread", "hot_pixel_current")):
            row = self.row(term, "active")
            if row["status"] == "fitted" and out.get(of, 0.0) > 0:  # a spread about a mean
                out[term] = float(row["value"])
        found = {}
        for pixels in _POPULATIONS:
            rows = [self.row(f"telegraph_{k}", pixels) for k in ("fraction", "amplitude", "rate")]
            if all(r["status"] == "fitted" for r in rows):
                found[pixels] = [(float(r["value"]), float(r["error"])) for r in rows]
            elif rows[0]["status"] == "fitted":
                why = next(r["note"] for r in rows if r["status"] != "fitted")
                warnings.warn(f"telegraph {pixels} pixels found but not all their terms: "
                              f"{why}; they are left out of the scene", stacklevel=2)
        keys = ("fraction", "amplitude", "rate")
        pops = {}
        if len(found) == 2:
            a, r = found["active"], found["reference"]
            if all(abs(x[0] - y[0]) <= 3 * np.hypot(x[1], y[1]) for x, y in zip(a, r, strict=True)):
                values = [_weighted(x, y) for x, y in zip(a, r, strict=True)]
                pops["all"] = {**dict(zip(keys, values, strict=True)), "pixels": "all",
                               **self._spreads("active")}
        if not pops:  # each population as found (the active and the reference ones differ)
            for pixels, values in found.items():
                pops[pixels] = {**dict(zip(keys, (v for v, _ in values), strict=True)),
                                "pixels": pixels, **self._spreads(pixels)}
        faint = self.faint_population()
        if faint is not None:  # steps below the jumps' threshold
            pops["faint"] = {**faint, "pixels": "active"}
        if len(pops) == 1:
            out["rtn"] = next(iter(pops.values()))
        elif pops:
            out["rtn"] = list(pops.values())
        return out

    def _spreads(self, pixels):
        """``amplitude_spread`` and ``rate_spread`` of a telegraph population, where fitted."""
        out = {}
        for key in ("amplitude_spread", "rate_spread"):
            row = self.row(f"telegraph_{key}", pixels)
            if row["status"] == "fitted":
                out[key] = float(row["value"])
        return out


def _weighted(x, y):
    wx, wy = 1 / max(x[1], 1e-300) ** 2, 1 / max(y[1], 1e-300) ** 2
    return float((wx * x[0] + wy * y[0]) / (wx + wy))


def dark_ramps(exposure):
    """The ramps, read times and reference mask of an exposure, as `fit_pixel_terms` takes them.

    Parameters
    ----------
    exposure : `~spherex_reduce.Exposure`
        Ramps ``(frames, n, ncols)`` in readout or physical order.  In
        readout order each row takes its first read of every frame (a reference
        row read several times per frame: the mean of its reads would blur a
        telegraph's steps).

    Returns
    -------
    ramps : `~astropy.units.Quantity`
        ``(frames, nrows, ncols)`` in physical order, the exposure's unit.
    times : `~astropy.units.Quantity`
        ``(frames,)`` start time of every frame (s).
    reference : `numpy.ndarray`
        ``(nrows, ncols)`` bool: the reference pixels.

    Examples
    --------
    >>> from spherex_reduce import simulate
    >>> from spherex_reduce.analysis.pixel_terms import dark_ramps
    >>> scene = {"geometry": {"nrows": 16, "ncols": 16, "nchannels": 1, "ref_border": 2},
    ...          "readout": {"skip": 2, "ref_reads": 8, "nframes": 4}}
    >>> ramps, times, ref = dark_ramps(simulate(scene, seed=1, mode="ramps"))
    >>> ramps.shape, times.unit, int(ref.sum())
    ((4, 16, 16), Unit("s"), 112)
    """
    ramps, times, reference, rows = dark_rows(exposure)
    return (ramps if rows is None else ramps[:, rows]), times, reference


def dark_rows(exposure):
    """`dark_ramps` without the copy: the exposure's stored ramps and, in readout order,
    the stored row of every row of pixels (what `PixelSums.add` takes as ``rows``).

    Returns
    -------
    ramps : `~astropy.units.Quantity`
        ``(frames, stored rows, ncols)``, a view of the exposure's data.
    times, reference
        As `dark_ramps`.
    rows : `numpy.ndarray` or None
        ``(nrows,)``: each row's first read of a frame (readout order), else None.

    Examples
    --------
    >>> from spherex_reduce import simulate
    >>> from spherex_reduce.analysis.pixel_terms import dark_rows
    >>> scene = {"geometry": {"nrows": 16, "ncols": 16, "nchannels": 1, "ref_border": 2},
    ...          "readout": {"skip": 2, "ref_reads": 8, "nframes": 4}}
    >>> ramps, times, ref, rows = dark_rows(simulate(scene, seed=1, mode="ramps"))
    >>> ramps.shape[1] > rows.size == 16            # reference rows read more than once
    True
    """
    s = exposure.schedule
    rows = pixel_rows(s, exposure.is_ramp, exposure.order)
    return (u.Quantity(exposure.data.data, exposure.unit, copy=False), s.frame_starts.to(u.s),
            exposure.geometry.reference_pixel_mask(), rows)


def pixel_rows(schedule, ramp=True, order="readout"):
    """The stored row of every row of pixels of darks of ``schedule`` (what `PixelSums.add`
    takes as ``rows``): in readout order each row's first read of a frame, in physical
    order None (rows stored as they are).

    Raises `~spherex_reduce.core.errors.SpherexReduceError` for an image (not ``ramp``)
    and for a row that is never read.

    Examples
    --------
    >>> from spherex_reduce import DetectorGeometry, ReadoutSchedule
    >>> from spherex_reduce.analysis.pixel_terms import pixel_rows
    >>> g = DetectorGeometry(8, 8, 1, ref_border={"top": 2})
    >>> s = ReadoutSchedule(g, skip=1, ref_reads=2, phantom_reads=0, nframes=3)
    >>> pixel_rows(s).size, pixel_rows(s, order="physical")
    (8, None)
    """
    if not ramp:
        raise SpherexReduceError("dark_ramps: the exposure holds an image, not ramps")
    rows = schedule.read_of_row()
    if order == "readout" and (rows < 0).any():
        raise SpherexReduceError(f"dark_ramps: rows {np.flatnonzero(rows < 0)[:5].tolist()}"
                                 " are never read")
    return rows if order == "readout" else None


def fit_pixel_terms(ramps, times, *, reference=None, gain=None, jump_sigma=5.0, labels=None,
                    hot_threshold=None, hot_sigma=HOT_SIGMA, groups=32, band_rows=32):
    """Read noise, dark current, hot and telegraph pixels and the reset offset of a detector.

    Parameters
    ----------
    ramps : `~astropy.units.Quantity` or sequence of them
        One dark ``(nreads, ny, nx)`` or several of the same pixels, read
        at the same times, in electrons or adu, physical order (`dark_ramps`).
        Bias-subtracted or raw: each pixel's constant level drops out.
    times : `~astropy.units.Quantity`
        ``(nreads,)`` time of every read (s); the rate of a telegraph needs them
        evenly spaced after read 0.
    reference : array_like of bool, optional
        ``(ny, nx)``: the reference pixels (no current; telegraph counted
        apart).  None: all pixels are light-sensitive.
    gain : float or `~astropy.units.Quantity`, optional
        Electrons per adu; required for adu darks (it sets the shot noise of
        the dark current).
    jump_sigma : float
        A jump exceeds this many robust standard deviations of the pixel's
        differences.
    hot_threshold : `~astropy.units.Quantity`, optional
        Dark current (unit/s) above which a pixel is hot; default the median
        current plus ``hot_sigma`` robust standard deviations of the active
        pixels' currents.
    hot_sigma : float
        See ``hot_threshold``.
    groups : int
        Groups of pixels of the jackknife (2 to 255).
    band_rows : int
        Rows processed at a time (memory: about 6 float32 arrays of
        ``nreads x band_rows x nx``, and about 14 float64 and 8 float32 maps of
        ``ny x nx``).
    labels : array_like of int, optional
        ``(ny, nx)``: the pixels read together, whose drift common at each read is
        removed before the faint telegraph's statistics
        (`~spherex_reduce.analysis.faint_telegraph.common_labels` of the darks'
        geometry); default each row's even and odd columns.

    Returns
    -------
    `PixelTerms`

    Raises
    ------
    SpherexReduceError
        Fewer than `MIN_READS` reads, shapes or units that disagree, adu
        without a gain, read times not increasing.

    Examples
    --------
    >>> import numpy as np
    >>> from astropy import units as u
    >>> from spherex_reduce.analysis.pixel_terms import fit_pixel_terms
    >>> rng = np.random.default_rng(2)
    >>> t = np.arange(30) * 1.5
    >>> x = rng.normal(0, 5.0, (30, 32, 32))                  # 5 adu read noise, no current
    >>> x[0] -= 18.0                                          # read 0 offset by -18 adu
    >>> res = fit_pixel_terms(x * u.adu, t * u.s, gain=2.0)
    >>> r = res.row("read_noise", "active")
    >>> round(r["value"], 1), r["unit"]
    (5.0, 'adu')
    >>> off = res.row("first_read_offset")
    >>> round(off["value"]), off["status"]
    (-18, 'fitted')
    >>> res.row("telegraph_fraction", "reference")["status"]
    'not constrained'
    """
    if not 2 <= int(groups) <= 255:  # before the darks are summed
        raise SpherexReduceError(f"fit_pixel_terms: groups must be 2 to 255, got {groups}")
    sums = PixelSums(times, reference=reference, gain=gain, jump_sigma=jump_sigma,
                     band_rows=band_rows, labels=labels)
    for dark in ramps if isinstance(ramps, (list, tuple)) else [ramps]:
        sums.add(dark)
    return sums.fit(hot_threshold=hot_threshold, hot_sigma=hot_sigma, groups=groups)


class PixelSums:
    """The per-pixel sums of `fit_pixel_terms`, added one dark at a time (so darks read one
    after the other need not be held together).

    Parameters
    ----------
    times, reference, gain, jump_sigma, band_rows
        As `fit_pixel_terms`.

    Examples
    --------
    >>> import numpy as np
    >>> from astropy import units as u
    >>> from spherex_reduce.analysis.pixel_terms import PixelSums
    >>> rng = np.random.default_rng(3)
    >>> t = np.arange(20) * 1.5 * u.s
    >>> sums = PixelSums(t, gain=1.0)
    >>> for _ in range(2):                            # two darks of the same pixels
    ...     moved = sums.add(rng.normal(0, 4.0, (20, 16, 16)) * u.electron)
    >>> round(sums.fit().row("read_noise", "active")["value"])
    4
    """

    def __init__(self, times, *, reference=None, gain=None, jump_sigma=5.0, band_rows=32,
                 labels=None):
        self._given = (times, reference, gain)
        self._labels = labels
        self.jump_sigma, self.band_rows = float(jump_sigma), max(int(band_rows), 1)
        self.ndarks = 0
        self._acc = None

    def add(self, ramps, rows=None):
        """Add one dark ``(nreads, ny, nx)`` (a Quantity, as `fit_pixel_terms` takes it):
        the same pixels, times and unit as the first.  ``rows`` (optional): the stored row
        of each row of pixels (e.g. a readout-order exposure's first read of each row),
        taken a band at a time rather than copying the dark.

        Returns the dark's pixels whose noise these terms hold ``(ny, nx)`` bool: a jump in
        this dark (a telegraph's step; also between reads 0 and 1: read 0 offset from the
        pixel's line beyond ``jump_sigma`` robust standard deviations of its band's) or
        hot by this dark's slopes (above the median plus ``hot_sigma`` = 10 robust
        standard deviations of the light-sensitive pixels', as `fit` flags them): what a
        stream model of the same darks leaves out."""
        unit = getattr(ramps, "unit", None)
        shape = _checked(unit, np.shape(ramps), None)  # the values are a view: no copy
        return self.add_rows(lambda idx: ramps.value[:, idx], shape, unit,
                             np.arange(shape[1]) if rows is None else rows)

    def add_rows(self, take, shape, unit, rows):
        """Add one dark that is not held whole, as `add` adds it: ``take(idx)`` gives the
        stored rows ``idx`` (an integer array) of every read, ``(nreads, len(idx), nx)``,
        in ``unit``; ``shape`` is the dark's ``(nreads, stored rows, nx)`` and ``rows``
        the stored row of each row of pixels (as `add`'s).  A band of ``band_rows`` rows
        of pixels is asked for at a time.  Returns what `add` returns.

        Examples
        --------
        >>> import numpy as np
        >>> from astropy import units as u
        >>> from spherex_reduce.analysis.pixel_terms import PixelSums
        >>> x = np.random.default_rng(3).normal(0, 4.0, (20, 16, 16))
        >>> a, b = PixelSums(np.arange(20) * 1.5 * u.s), PixelSums(np.arange(20) * 1.5 * u.s)
        >>> rows = np.arange(16)[::-1]                    # stored bottom row first
        >>> _ = a.add(x * u.electron, rows=rows)
        >>> _ = b.add_rows(lambda idx: x[:, idx], x.shape, u.electron, rows)
        >>> a.fit().row("read_noise", "active") == b.fit().row("read_noise", "active")
        True
        """
        rows = np.asarray(rows, dtype=np.intp)
        return self._add(lambda sl: take(rows[sl]), unit, _checked(unit, tuple(shape), rows))

    def _add(self, band, unit, shape):
        """Add the dark whose band of rows of pixels ``sl`` (a slice) is ``band(sl)``."""
        if self._acc is None:  # times, gain and mask checked once, against the first dark
            self.gain, self.t, self.ref = _settings(*self._given, unit, shape)
            self.unit, self.shape = unit, shape
            self._acc = new_sums(shape, self.t, self.jump_sigma, self.gain,
                                 _labels(self._labels, self.ref))
        elif unit != self.unit or shape != self.shape:
            raise SpherexReduceError(f"fit_pixel_terms: dark {self.ndarks} has shape {shape} "
                                     f"and unit {unit}; dark 0 {self.shape} and {self.unit} "
                                     "(each (nreads, ny, nx), one unit)")
        slopes, jumped = add_dark(self._acc, band, shape, self.t, self.band_rows)
        ok = np.isfinite(slopes)
        self._acc["s1"] += (kept := np.where(ok, slopes, 0.0))  # the darks' slopes: scatter
        self._acc["s2"] += kept ** 2
        active = ~self.ref & ok
        # the dark's drift common to its pixels (the streams' 1/f): its median slope
        med = float(np.median(slopes[active])) if active.any() else np.nan
        self._acc["drifts"].append(med)
        self.ndarks += 1
        if active.any():
            jumped |= active & (slopes > _hot_threshold(slopes, active, HOT_SIGMA, med))
        return jumped

    def fit(self, *, hot_threshold=None, hot_sigma=HOT_SIGMA, groups=32):
        """The `PixelTerms` of the darks added (``hot_threshold``, ``hot_sigma``,
        ``groups``: as `fit_pixel_terms`)."""
        if self._acc is None:
            raise SpherexReduceError("fit_pixel_terms: no darks given")
        if not 2 <= int(groups) <= 255:
            raise SpherexReduceError(f"fit_pixel_terms: groups must be 2 to 255, got {groups}")
        n, ny, nx = self.shape
        gid = np.random.default_rng(0).integers(0, int(groups), (ny, nx), dtype=np.uint8)
        # a shallow copy: the summary takes its sums out of the dict (not out of the arrays)
        return _summarise(dict(self._acc), self.ref, gid, int(groups), self.unit, self.gain,
                          self.t, n, self.ndarks, hot_threshold, float(hot_sigma))


# -- inputs --------------------------------------------------------------------------
def _checked(unit, shape, rows):
    """The shape ``(nreads, ny, nx)`` of the pixels of a dark of ``unit`` stored as
    ``shape`` (with ``rows``: the stored rows of each row of pixels), checked."""
    if unit not in (u.electron, u.adu):
        raise SpherexReduceError(f"fit_pixel_terms: darks must be in electron or adu, got {unit}")
    if len(shape) != 3:
        raise SpherexReduceError(f"fit_pixel_terms: dark 0 has shape {shape} and unit {unit} "
                                 "(each (nreads, ny, nx), one unit)")
    if rows is not None:  # the stored rows of each row of pixels (a view, not a copy)
        if rows.ndim != 1 or (rows.size and (rows.min() < 0 or rows.max() >= shape[1])):
            raise SpherexReduceError(f"fit_pixel_terms: rows must index the {shape[1:2]} "
                                     "stored rows")
        shape = (shape[0], rows.size, shape[2])
    if shape[0] < MIN_READS:
        raise SpherexReduceError(f"fit_pixel_terms: a dark of {shape[0]} reads; at least "
                                 f"{MIN_READS} are needed (two differences)")
    return shape


def _settings(times, reference, gain, unit, shape):
    """The gain (e per unit), read times (s) and reference mask of darks of ``unit`` and
    ``shape``, checked."""
    try:
        t = np.atleast_1d(u.Quantity(times).to_value(u.s)).astype(np.float64)
    except (u.UnitsError, TypeError, ValueError) as exc:
        raise SpherexReduceError(f"fit_pixel_terms: times must be a time Quantity (s): "
                                 f"{exc}") from None
    if t.shape != (shape[0],) or not np.all(np.isfinite(t)) or np.any(np.diff(t) <= 0):
        raise SpherexReduceError(f"fit_pixel_terms: times must be {shape[0]} increasing finite "
                                 f"values (s), one per read; got shape {t.shape}")
    if unit == u.adu:
        if gain is None:
            raise SpherexReduceError("fit_pixel_terms: adu darks need the gain (e/adu): it "
                                     "separates the dark current's shot noise from read noise")
        g = u.Quantity(gain, u.electron / u.adu).value
    else:
        g = 1.0 if gain is None else u.Quantity(gain, u.electron / unit).value
    if not (np.isfinite(g) and g > 0):
        raise SpherexReduceError(f"fit_pixel_terms: gain must be finite and > 0, got {g}")
    ref = (np.zeros(shape[1:], bool) if reference is None
           else np.asarray(reference, dtype=bool))
    if ref.shape != shape[1:]:
        raise SpherexReduceError(f"fit_pixel_terms: reference mask {ref.shape} differs from "
                                 f"the pixels {shape[1:]}")
    return float(g), t, ref


# -- the darks' labels ------------------------------------------------------------------
def _labels(labels, ref):
    """The pixels read together (`~spherex_reduce.analysis.faint_telegraph.common_labels`),
    checked; default each row's even and odd columns; -1 on the reference pixels."""
    if labels is None:
        ny, nx = ref.shape
        labels = np.arange(ny)[:, None] * 2 + np.arange(nx)[None, :] % 2
    labels = np.asarray(labels)
    if labels.shape != ref.shape or labels.dtype.kind not in "iu":
        raise SpherexReduceError(f"fit_pixel_terms: labels must be integers of shape "
                                 f"{ref.shape}, got {labels.dtype} {labels.shape}")
    return np.where(ref, -1, labels).astype(np.int64)


# -- summaries ---------------------------------------------------------------------------
def _jackknife(f, columns, sel, gid, k):
    """``f`` of the sums of ``columns`` (per-pixel arrays) over the pixels ``sel``, and its
    delete-a-group jackknife error (NaN when ``f`` is not finite without some group).

    Every summary is a function of sums over pixels, so one pass of `numpy.bincount` gives
    the groups' sums and each delete-a-group value is ``f(total - group)``.
    """
    g = gid[sel].astype(np.intp)  # once: bincount would convert it for every column
    count = None
    sums = []
    for c in columns:
        if np.ndim(c) == 0 and c == 1.0:  # a pixel count: the same sums, without weights
            count = np.bincount(g, minlength=k).astype(np.float64) if count is None else count
            sums.append(count)
        else:
            sums.append(np.bincount(g, weights=np.asarray(np.broadcast_to(c, sel.shape)[sel],
                                                          dtype=np.float64), minlength=k))
    sums = np.array(sums)
    total = sums.sum(axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        full = float(f(total))
        parts = np.array([f(total - sums[:, j]) for j in range(k)], dtype=np.float64)
    if not np.isfinite(full) or not np.all(np.isfinite(parts)):
        return full, np.nan
    return full, float(np.sqrt((k - 1) / k * np.sum((parts - parts.mean()) ** 2)))


def _ratio(total):
    return total[0] / total[1] if total[1] > 0 else np.nan


def _within(a, sel):
    """The pixels of ``sel`` where ``a`` is finite and within 5 robust standard deviations of
    its median over them, and ``a - median`` (0 elsewhere)."""
    ok = sel & np.isfinite(a)
    if not ok.any():
        return ok, np.zeros(a.shape)
    r = np.where(ok, a - np.median(a[ok]), 0.0)
    return ok & (np.abs(r) <= 5 * MAD_TO_SIGMA * np.median(np.abs(r[ok]))), r


def _typical(a, sel, gid, k):
    """Mean of ``a`` over the pixels of ``sel`` within 5 robust standard deviations of its
    median, and its error: a median's delete-a-group jackknife is unreliable with a few
    pixels per group (a population's median and clipped mean agree when it is symmetric)."""
    keep, _ = _within(a, sel)
    return _jackknife(_ratio, (np.where(keep, a, 0.0), 1.0), keep, gid, k)


def _typical_variance(var, nu, sel, gid, k):
    """Mean of per-pixel variances ``var`` over the pixels of ``sel``, and its error.

    A white-noise pixel's variance is ``σ² χ²_ν / ν`` (``ν`` its degrees of freedom,
    Satterthwaite's for a quadratic form): skewed when ``ν`` is small, so a clip at robust
    standard deviations about the median would cut its long tail (−27 % at ``ν`` = 1, a
    dark of 3 reads).  Pixels beyond the ``χ²_ν`` quantile of `_VARIANCE_CLIP` (scaled by
    the median) are left out, and the mean divided by what that truncation leaves of a
    ``χ²_ν`` variable's mean, ``P(χ²_{ν+2} ≤ νz) / P(χ²_ν ≤ νz)``.
    """
    ok = sel & np.isfinite(var)
    scale = np.median(var[ok]) / (chi2.median(nu) / nu) if ok.any() else np.nan
    if not scale > 0:
        return np.nan, np.nan
    z = chi2.isf(_VARIANCE_CLIP, nu) / nu
    keep = ok & (np.abs(var) <= z * scale)
    kept = chi2.cdf(nu * z, nu + 2) / chi2.cdf(nu * z, nu)
    value, err = _jackknife(_ratio, (np.where(keep, var, 0.0), 1.0), keep, gid, k)
    return value / kept, err / kept


def _spread(a, noise, sel, gid, k):
    """Variance of ``a`` less each pixel's measurement variance ``noise²`` (the mean of
    ``(a - median)² - noise²``, exact for pixels of unequal noise), over the pixels within 5
    robust standard deviations of the median; negative when the scatter is all noise."""
    keep, r = _within(a, sel & np.isfinite(noise))
    if keep.sum() < 2:
        return np.nan, np.nan
    return _jackknife(_ratio, (np.where(keep, r ** 2 - noise ** 2, 0.0), 1.0), keep, gid, k)


def _flip_probability(mean, m):
    """Maximum-likelihood flip probability of binomial(m, p) counts known to be >= 2, whose
    mean is ``mean``: ``E[c | c >= 2] = (m p - P(c = 1)) / P(c >= 2)`` is ``mean``."""
    if not np.isfinite(mean):
        return np.nan

    def excess(p):
        return (m * p - binom.pmf(1, m, p)) / binom.sf(1, m, p) - mean

    lo, hi = 1e-6 / m, 0.5
    if excess(lo) >= 0:
        return 0.0
    if excess(hi) <= 0:
        return 0.5
    return brentq(excess, lo, hi, xtol=1e-12)


def _hot_threshold(slope, active, hot_sigma, med=None):
    """The median slope of the ``active`` pixels (``med`` if known) plus ``hot_sigma``
    robust standard deviations: above it a pixel is hot."""
    med = np.median(slope[active]) if med is None else med
    return med + hot_sigma * MAD_TO_SIGMA * np.median(np.abs(slope[active] - med))


def _summarise(acc, ref, gid, k, unit, g, t, n, ndarks, hot_threshold, hot_sigma):
    des = acc["design"]
    rows = []

    def add(term, pixels, value, error, unit_, status="fitted", note=""):
        if status != "not constrained" and not (np.isfinite(value) and np.isfinite(error)):
            value, error, status = np.nan, np.nan, "not constrained"
            note = f"too few pixels in a jackknife group for an error ({note})"
        rows.append((term, pixels, float(value), float(error), str(unit_), status, note))

    def refuse(term, pixels, unit_, reason):
        add(term, pixels, np.nan, np.nan, unit_, "not constrained", reason)

    rate_unit = unit / u.s
    f32 = np.float32
    bad = acc.pop("bad")  # a non-finite read: left out of everything
    good = ~bad
    ref = ref & good
    wdt = acc.pop("wdt")
    slope = np.divide(acc.pop("wd"), wdt, out=np.zeros_like(wdt), where=wdt > 0)
    current = np.maximum(slope, 0.0) / g  # shot noise per unit time, unit^2 / s
    kept = acc.pop("kept")  # reads kept, in darks (each dark's jumps left out)
    a_r = np.where(kept > 0, kept * des["ar"], np.inf)
    # the expected shot noise of the pixel's own slope, signed: its mean over pixels is the
    # mean current's (clipped at 0, noise-driven slopes of a low current took variance away)
    var = (acc.pop("q") - slope / g * kept * des["as_"]) / a_r
    v0 = np.maximum(var, 0.0)
    se_var = np.sqrt(2 * kept * (v0 ** 2 * des["trr"] + 2 * v0 * current * des["trs"]
                                 + current ** 2 * des["tss"])) / a_r
    del a_r
    noise = np.sqrt(v0).astype(f32)
    noise_err = (se_var / (2 * np.maximum(np.maximum(noise, np.sqrt(se_var)), 1e-30))
                 ).astype(f32)
    del se_var
    slope_err = (np.sqrt(np.maximum(v0 * acc.pop("vr") + current * acc.pop("vs"), 0.0))
                 / np.where(wdt > 0, wdt, np.inf)).astype(f32)
    del kept, wdt
    dt = float(np.median(des["dt"]))
    step = (np.sqrt(2 * np.median(v0[good]) + np.median(current[good]) * dt) if good.any()
            else np.nan)
    del v0, current
    var = var.astype(f32)

    m_total = des["m"] * ndarks
    tel_ok = des["m"] >= MIN_TELEGRAPH_INTERVALS
    telegraph = tel_ok & (acc["jumps"] >= 2) & acc["alternate"] & good
    # its steps must be clear of the threshold, or some of its flips were missed (its rate
    # and step come out wrong: 7.5 % at 0.012 Hz for 10 % at 0.3 Hz): such a pixel is left
    # to the faint population.  Its noise is taken no higher than the search's cap on it
    # (`SCALE_CAP` times the typical): its own estimate from a few tens of differences
    # scatters up (more than a third above the typical one time in thirty for a pixel
    # that switches at every third difference) and handed 3 % of a clear telegraph
    # population to the faint one
    typical = float(np.median(noise[good])) if good.any() else np.inf
    clearance = (acc["jump_sigma"] + CLEAR_SIGMA) * np.sqrt(2.0) * np.minimum(
        noise, SCALE_CAP * typical)
    with np.errstate(invalid="ignore"):
        clear = acc["jsize"] / np.maximum(acc["jumps"], 1) >= clearance
    steps = _cross_cleared(acc, telegraph, clearance)
    telegraph &= clear
    amplitude = np.where(telegraph, acc["jsize"] / np.maximum(acc["jumps"], 1),
                         np.nan).astype(f32)
    regular = np.ptp(des["dt"]) <= 1e-6 * dt
    with np.errstate(divide="ignore", invalid="ignore"):
        pix_rate = np.where(telegraph, -np.log1p(-2 * np.minimum(acc["jumps"] / m_total, 0.5))
                            / (2 * dt), np.nan).astype(f32)

    active = ~ref & good
    nu = ndarks * des["ar"] ** 2 / des["trr"]  # degrees of freedom of a pixel's variance
    for pixels, sel in zip(_POPULATIONS, (active, ref), strict=True):
        if not sel.any():
            for term in ("read_noise", "read_noise_spread"):
                refuse(term, pixels, unit, f"no {pixels} pixels")
            continue
        value, err = _typical_variance(var, nu, sel, gid, k)
        add("read_noise", pixels, np.sqrt(max(value, 0)),
            err / (2 * np.sqrt(max(value, 1e-300))), unit,
            note="root of the pixels' mean read-noise variance (chi2 clipped)")
        if nu < 2:  # a pixel's noise from one value: its error is as large as itself
            refuse("read_noise_spread", pixels, unit, f"{nu:.3g} degree of freedom per pixel "
                   "(one dark of 3 reads): no spread to tell from each pixel's own error")
            continue
        _add_spread(add, "read_noise_spread", pixels, _spread(noise, noise_err, sel, gid, k),
                    unit)

    if not active.any():
        for term in ("dark_current", "dark_current_spread", "hot_pixel_fraction",
                     "hot_pixel_current", "hot_pixel_current_spread"):
            refuse(term, "active", rate_unit if "fraction" not in term else "",
                   "no light-sensitive pixels")
        hot = np.zeros_like(active)
    else:
        if hot_threshold is None:
            threshold = _hot_threshold(slope, active, hot_sigma)
            how = f"median + {hot_sigma:g} robust sd"
        else:
            threshold = u.Quantity(hot_threshold, rate_unit).value
            how = "given"
        hot = active & (slope > threshold)
        if ndarks >= 3:  # a hot pixel's current stays: a telegraph's slope moves dark to dark
            s1, s2 = acc.pop("s1") / ndarks, acc.pop("s2") / ndarks
            se = np.sqrt(np.maximum(s2 - s1 * s1, 0.0) / (ndarks - 1))
            hot &= s1 - threshold > HOT_CONSISTENCY * se
            how += f", in every dark (mean above it by {HOT_CONSISTENCY:g} standard errors)"
        cold = active & ~hot
        dark, dark_err = _jackknife(_ratio, (slope, 1.0), cold, gid, k)
        drifts = np.asarray(acc["drifts"], dtype=np.float64)
        common = ""
        if ndarks > 1 and np.all(np.isfinite(drifts)):
            # a drift common to all pixels of a dark (1/f) is in no group apart: the scatter of
            # the darks' median slopes holds it, less what their pixels' own noise gives a
            # median of N (pi/2 sigma^2/N; the jackknife holds that)
            own = np.pi / 2 * ndarks * np.mean(slope_err[cold].astype(np.float64) ** 2) \
                / max(cold.sum(), 1)
            excess = max(np.var(drifts, ddof=1) - own, 0.0)
            dark_err = float(np.hypot(dark_err, np.sqrt(excess / ndarks)))
            common = ("; error: the jackknife over pixels and the drift common to a dark's "
                      "pixels (the scatter of the darks' median slopes beyond their noise)")
        add("dark_current", "active", dark, dark_err, rate_unit,
            note="mean of the active pixels that are not hot (a low current's slopes are "
            "skewed: their median is low)" + common)
        _add_spread(add, "dark_current_spread", "active",
                    _spread(slope, slope_err, cold, gid, k), rate_unit)
        add("hot_threshold", "active", threshold, 0.0, rate_unit, note=how)
        frac, frac_err = _jackknife(_ratio, (hot, 1.0), active, gid, k)
        add("hot_pixel_fraction", "active", frac, frac_err, "",
            note=f"active pixels above {threshold:.4g} {rate_unit}")
        if hot.sum() >= 2:
            excess = slope - dark
            value, err = _typical(excess, hot, gid, k)
            add("hot_pixel_current", "active", value, err, rate_unit,
                note="mean current of the hot pixels above dark_current (5 robust sd clipped)")
            _add_spread(add, "hot_pixel_current_spread", "active",
                        _spread(excess, slope_err, hot, gid, k), rate_unit)
        else:
            for term in ("hot_pixel_current", "hot_pixel_current_spread"):
                refuse(term, "active", rate_unit, f"{int(hot.sum())} hot pixel(s) found")

    limit = f"jumps above {acc['jump_sigma']:g} sd of the differences (about {step:.3g} {unit})"
    for pixels, sel in zip(_POPULATIONS, (active, ref), strict=True):
        reason = _telegraph_reason(sel, pixels, des["m"], regular)
        _telegraph(add, refuse, pixels, sel, telegraph, amplitude, pix_rate, acc, m_total, dt,
                   gid, k, unit, reason, limit, noise, steps)
    # a pixel that jumped once in all the darks, clear of the threshold, is a cosmic ray or
    # a telegraph of the found population that flipped once (counted there)
    if acc.get("lags") is None:
        for name, un in zip(FAINT_TERMS, (unit ** 2, u.Hz, "", unit, unit ** 2, unit),
                            strict=True):
            refuse(name, "active", un, f"{des['m']} differences per dark; at least "
                   f"{MIN_TELEGRAPH_INTERVALS} are needed")
    else:
        add_faint_terms(add, refuse, acc, active & ~hot & ~telegraph
                        & ~((acc["jumps"] == 1) & clear), active, slope / g, ndarks, k, unit,
                        des, _jackknife)

    if not acc["skip_first"]:
        refuse("first_read_offset", "all", unit, f"{n} reads: read 0 is needed for the line")
    else:
        usable = ~hot & ~telegraph & good
        off = acc["offset"] / ndarks  # (not in place: the sums stay for another fit)
        value, err = _jackknife(_ratio, (off, 1.0), usable, gid, k)
        status = "fitted" if abs(value) > 3 * err else "ruled out"
        add("first_read_offset", "all", value, err, unit, status,
            "mean of read 0 less the line of the later reads (hot and telegraph pixels "
            "left out); ruled out within 3 sd of 0")

    table = Table(rows=rows, names=("term", "pixels", "value", "error", "unit", "status",
                                    "note"),
                  dtype=(str, str, float, float, str, str, str),
                  meta={"nreads": n, "ndarks": ndarks, "gain": g, "unit": str(unit),
                        "groups": k, "unusable_pixels": int(bad.sum())})
    def q(a, un):
        a = np.asarray(a, dtype=f32)
        a[bad] = np.nan
        return u.Quantity(a, un, copy=False)

    maps = {"read_noise": q(noise, unit), "read_noise_error": q(noise_err, unit),
            "dark_current": q(slope, rate_unit), "dark_current_error": q(slope_err, rate_unit),
            "first_read_offset": q(off if acc["skip_first"] else np.full(ref.shape, np.nan),
                                   unit),
            "hot": hot, "telegraph": telegraph, "telegraph_amplitude": q(amplitude, unit),
            "telegraph_rate": q(pix_rate, u.Hz)}
    return PixelTerms(table, maps, unit, g)


def _add_spread(add, term, pixels, spread, unit):
    value, err = spread
    if not np.isfinite(value):
        add(term, pixels, np.nan, np.nan, unit, "not constrained", "fewer than 2 pixels")
        return
    root = np.sqrt(max(value, 0.0))
    status = "fitted" if value > 3 * err else "ruled out"
    scale = max(root, np.sqrt(err), 1e-300) if np.isfinite(err) else 1.0
    add(term, pixels, root, err / (2 * scale) if np.isfinite(err) else 0.0,
        unit, status, "sd of the pixels less their measurement noise; ruled out: "
        "within 3 sd of none")


def _telegraph_reason(sel, pixels, m, regular):
    if not sel.any():
        return f"no {pixels} pixels"
    if m < MIN_TELEGRAPH_INTERVALS:
        return (f"{m} differences per dark; at least {MIN_TELEGRAPH_INTERVALS} tell a "
                "telegraph's jumps from the pixel's noise")
    return "" if regular else "read times not evenly spaced: no rate"


def _cross_cleared(acc, candidate, clearance):
    """The jumps that measure a telegraph population's step: per pixel, the sizes and the
    number of the jumps of each half of the intervals (``jumps_a``: the first half of each
    dark's) where the other half's mean jump is ``clearance`` or more, on the ``candidate``
    pixels (alternating, 2 jumps or more).

    A pixel found jump by jump must have its mean jump clear of the threshold, but the
    mean over the pixels that cleared it is a mean over those whose jumps measured high
    (+2.6 e, 20 of its errors, on 125 e steps in 10 e noise): the half that
    decides is not the half that is measured, so the sizes are not selected on their own
    noise (the two halves share one read per dark at most).
    """
    n_a, s_a = acc["jumps_a"], acc["jsize_a"]
    n_b, s_b = acc["jumps"] - n_a, acc["jsize"] - s_a
    with np.errstate(invalid="ignore"):
        clear_a = candidate & (n_a > 0) & (s_a >= clearance * n_a)
        clear_b = candidate & (n_b > 0) & (s_b >= clearance * n_b)
    return (np.where(clear_b, s_a, 0.0) + np.where(clear_a, s_b, 0.0),
            np.where(clear_b, n_a, 0.0) + np.where(clear_a, n_b, 0.0))


def _telegraph(add, refuse, pixels, sel, telegraph, amplitude, pix_rate, acc, m_total, dt,
               gid, k, unit, reason, limit, noise, steps):
    names = ("telegraph_fraction", "telegraph_amplitude", "telegraph_amplitude_spread",
             "telegraph_rate", "telegraph_rate_spread")
    units = ("", unit, unit, u.Hz, u.Hz)
    if reason and not reason.startswith("read times"):
        for name, un in zip(names, units, strict=True):
            refuse(name, pixels, un, reason)
        return
    limit_note = f"{limit} are seen"
    found = sel & telegraph
    counts = acc["jumps"]

    columns = (found, 1.0, np.where(found, counts, 0))  # summed over the pixels of sel

    def prob(total):
        return _flip_probability(total[2] / total[0], m_total) if total[0] > 0 else np.nan

    def fraction(total):
        if total[0] == 0:
            return 0.0
        p = prob(total)
        return total[0] / total[1] / max(binom.sf(1, m_total, p), 1e-12)

    nfound = int(found.sum())
    if nfound == 0:
        add(names[0], pixels, 0.0, 1.0 / sel.sum(), "", "ruled out",
            f"none found; {limit_note}")
        for name, un in zip(names[1:], units[1:], strict=True):
            refuse(name, pixels, un, f"no telegraph {pixels} pixels found")
        return
    value, err = _jackknife(fraction, columns, sel, gid, k)
    add(names[0], pixels, value, err, "", "fitted",
        f"{nfound} found, corrected for those that flipped < 2 times; {limit_note}")
    sizes, used = steps
    measured = sel & (used > 0)
    how = ("mean size of the telegraph pixels' jumps, each half of a pixel's intervals where "
           "the other half's mean jump clears the threshold")
    value, err = (_jackknife(_ratio, (sizes, used), measured, gid, k) if measured.any()
                  else (np.nan, np.nan))
    if not np.isfinite(err):  # too few pixels with jumps in both halves for an error
        sizes, used, measured = acc["jsize"], counts, found
        how = ("mean size of the jumps of the telegraph pixels found (too few with jumps in "
               "both halves of their intervals: a little high, selected on their sizes)")
        value, err = _jackknife(_ratio, (sizes, used), measured, gid, k)
    # each jump is measured with the noise of a difference: a floor under a jackknife of a few
    # groups holding telegraph pixels (itself uncertain)
    floor = np.sqrt(np.sum(2 * noise[measured] ** 2 * used[measured])) / used[measured].sum()
    add(names[1], pixels, value, max(err, floor), unit,
        note=f"{how} (error: the jackknife's, at least the jumps' own noise)")
    step_noise = np.sqrt(2) * noise / np.sqrt(np.maximum(counts, 1))
    _add_spread(add, names[2], pixels, _spread(amplitude, step_noise, found, gid, k), unit)
    if reason:
        for name, un in zip(names[3:], units[3:], strict=True):
            refuse(name, pixels, un, reason)
        return
    p, p_err = _jackknife(prob, columns, sel, gid, k)
    if not 0 < p < MAX_FLIP_PROBABILITY:
        why = ("every telegraph pixel flipped exactly twice: the rate is below what the darks "
               "resolve" if p <= 0 else f"flip probability {p:.2f}: switches faster than the "
               "reads")
        for name, un in zip(names[3:], units[3:], strict=True):
            refuse(name, pixels, un, why)
        return
    rate = -np.log1p(-2 * p) / (2 * dt)
    add(names[3], pixels, rate, p_err / ((1 - 2 * p) * dt), u.Hz, note=(
        f"from the flip probability {p:.4f} per {dt:.4g} s (maximum likelihood, >= 2 flips)"))
    rate_noise = np.full(pix_rate.shape, np.sqrt(p * (1 - p) / m_total) / ((1 - 2 * p) * dt))
    _add_spread(add, names[4], pixels, _spread(pix_rate, rate_noise, found, gid, k), u.Hz)
