"""The ``wiener`` reference strategy: each channel's drift at the time of every row read.

The paper's reference correction subtracts one constant per channel (and
frame).  Distributed reference reads sample the channel's readout drift all
through the frame, and the schedule knows the time of every read, so the
drift at the time of each row read can be estimated: the best linear unbiased
estimate from that channel's reference reads given the noise model's PSDs
(universal kriging, `~spherex_reduce.noise.read_covariance`).  Each frame's
and channel's offset is an unknown constant (a flat prior), the rest of the
drift has the PSDs' covariance.  With white noise only, the estimate is the
mean of the reference pixels: the ``mean`` strategy.  With ``side_columns`` the
side reference columns of the channels that have them are observed at every
light row's read too (`~spherex_reduce.reduce.steps.reference.side_values`): the
drift common to every channel, at every row.  The ``correct_reference`` kernel
subtracts the estimate row by row.
"""

import json
import threading
import warnings

import numpy as np
from astropy import units as u
from astropy.table import Table
from astropy.utils.exceptions import AstropyUserWarning

from ....core.errors import ConfigError
from ....core.parameters import Parameter, validate_parameters
from ....io.charge_unit import UNITS as CHARGE_UNITS
from ....noise.read_covariance import DOMAINS, ReadCovariance
from ...noise_effect import MEASURED_SIGMA, ReferenceEffect
from ...step import Strategy
from .drift_model import DriftModel
from .noise_models import (
    DEFAULT_NOISE,
    PAPER_PIXEL_RATE,
    load_noise_model,
    noise_model,
)
from .side_values import side_columns, side_values
from .strategies import (
    ALL,
    EVEN,
    ODD,
    ReferenceOffsets,
    group_columns,
    reference_pixels,
    without_telegraph,
)
from .telegraph import MAD_TO_SIGMA, TELEGRAPH_PARAMETERS

__all__ = ["WienerReference", "load_noise_model", "phantom_consumed"]

#: Models kept for reuse (each holds its solved weights: 1.8 MB at 2048 x 2048 x 10, 36 MB
#: with side columns), at most this many and, beyond the newest, these bytes: a run of
#: several wiener configurations (compare-strategies, the peers' benchmark: six models)
#: solved them again at every exposure when four were kept
_MAX_MODELS = 16
_MODEL_BYTES = 256 << 20
_MODELS = {}
_MODELS_LOCK = threading.Lock()


def _reads_of(side, schedule):
    """Read index (within a frame) of every reference read of a side block."""
    if side.order == "readout":
        return np.asarray(side.index)[schedule.is_reference[side.index]]
    return schedule.read_of_row()[np.asarray(side.index)]


def phantom_consumed(params, phantom_subtracted):
    """Whether a ``wiener`` correction with the step's ``params`` (a dict) estimates from the
    phantom values of every read, and so consumes them (a later ``subtract_phantom`` is
    skipped): when its ``phantom`` is ``auto`` and ``phantom_subtracted`` is False (the
    values were not subtracted before it).  Declared to the forecast by the strategy's
    ``noise_effect``; `WienerReference.uses_phantom` applies it to a run.

    Examples
    --------
    >>> from spherex_reduce.reduce.steps.reference.wiener import phantom_consumed
    >>> phantom_consumed({}, False), phantom_consumed({"phantom": "ignore"}, False)
    (True, False)
    """
    return not phantom_subtracted and params.get("phantom", "auto") == "auto"


class WienerReference(Strategy):
    """Each channel's drift at every row read, from its reference reads and the noise PSDs.

    The optimal linear (kriging) estimate under an unknown constant per frame,
    channel and parity group; subtracted row by row.  Streams like ``mean``.

    Parameters
    ----------
    **params
        ``noise``, ``common``, ``acn``, ``domain``, ``regularization``,
        ``phantom``, ``side_columns``, ``sigma``, ``telegraph``,
        ``telegraph_sigma`` (declared,
        with their defaults and meaning, by :attr:`parameters`; the telegraph
        reference pixels are left out as by ``mean``).
    """

    kind, name = "reference", "wiener"
    parameters = (
        Parameter("noise", None, (str, type(None)), "noise model: a table name or ECSV "
                  "path, a fit-noise result (ECSV) or a scene file (YAML, its noise: section); "
                  "none: spherex-table2, the paper's electronics, for data in electrons at "
                  "100 kHz only"),
        Parameter("common", "auto", (str, list), "components one stream of which every "
                  "channel sees: auto (scope common), none, or a list of names"),
        Parameter("acn", False, (bool,), "estimate even and odd samples separately "
                  "(alternating column noise)"),
        Parameter("domain", "auto", (str,), "auto (frames for ramps, slopes for an image), "
                  "frames or slopes (weights for the ramp-fitted slope, applied to each frame)",
                  choices=("auto", *DOMAINS)),
        Parameter("regularization", 1e-9, (float,), "added to the diagonal of the reference "
                  "reads' covariance, relative to its mean", minimum=0, maximum=1),
        Parameter("phantom", "auto", (str,), "auto: when the phantom values are not yet "
                  "subtracted, estimate from them too (and consume them); ignore: never",
                  choices=("auto", "ignore")),
        Parameter("side_columns", False, (bool,), "also observe the side reference columns "
                  "at every row read (the drift common to every channel, from the channels "
                  "that have them; needs the whole exposure)"),
        Parameter("sigma", 5.0, (float,), "reference pixels beyond this many robust (MAD) "
                  "standard deviations from the channel's median are not used",
                  minimum=0, exclusive_minimum=True),
        *TELEGRAPH_PARAMETERS,
    )
    #: a drift estimate at every read, with these weights; its MAD clip forecast as none
    noise_effect = ReferenceEffect("wiener", linear={"sigma": MEASURED_SIGMA},
                                   consumes_phantom=phantom_consumed)

    def __init__(self, **params):
        params = validate_parameters(params, self.parameters, type(self).__name__)
        super().__init__(**params)
        noise, common = params["noise"], params["common"]
        #: whether the config named the noise model (the default is the paper's electronics,
        #: refused for data of another unit or pixel rate: `check_data`)
        self.noise_given = noise is not None
        noise = DEFAULT_NOISE if noise is None else noise
        self.noise, self.acn, self.domain = noise, params["acn"], params["domain"]
        self.phantom = params["phantom"]
        self.regularization, self.sigma = params["regularization"], params["sigma"]
        self.side_columns = params["side_columns"]
        self.telegraph, self.telegraph_sigma = params["telegraph"], params["telegraph_sigma"]
        self.components, self.model_unit = noise_model(noise)
        if self.acn and not any(c.acn for c in self.components):
            warnings.warn("correct_reference (wiener): acn: true, but the noise model has no "
                          "ACN component: the even and odd columns are estimated apart, from "
                          "half the reference pixels each, which only adds noise between "
                          "them; set acn: false, or give a model with ACN", AstropyUserWarning,
                          stacklevel=2)
        names = [c.name for c in self.components]
        if common == "auto":
            self.common = frozenset(c.name for c in self.components if c.scope == "common")
        elif common == "none":
            self.common = frozenset()
        elif isinstance(common, list) and all(isinstance(n, str) for n in common):
            unknown = sorted(set(common) - set(names))
            if unknown:
                raise ConfigError(f"correct_reference.common: {unknown} not in the noise model "
                                  f"({', '.join(names)})")
            self.common = frozenset(common)
        else:
            raise ConfigError("correct_reference.common: expected auto, none or a list of "
                              f"component names, got {common!r}")

    @property
    def needs_exposure(self):
        return bool(self.side_columns)

    def side_groups(self, geometry):
        """`~spherex_reduce.reduce.steps.reference.side_values.side_columns` of each parity
        group, or None when the side values are not observed (``side_columns`` false, or a
        geometry without side columns, or one channel: the mean is the channel)."""
        if not self.side_columns or geometry.nchannels < 2:
            return None
        groups = side_columns(geometry, self.acn)
        return groups if all(groups) else None

    def uses_phantom(self, context):
        """Whether the phantom values of every read are observations (and get consumed)."""
        return (phantom_consumed({"phantom": self.phantom}, not context.has_phantom)
                and context.schedule.phantom_reads > 0)

    # -- the model ----------------------------------------------------------------------
    def _model(self, schedule, domain, offsets, side=None):
        """The model of one parity group (``side``: its side columns' ``(channel, columns)``,
        or None); shared by every strategy of this process with the same noise model and
        schedule (its weights are solved once)."""
        col = schedule.geometry.column_offsets()
        side_offsets = [] if side is None else [col[c] for _, c in side]
        key = (repr([c.to_dict() for c in self.components]), tuple(sorted(self.common)),
               json.dumps([schedule.geometry.to_dict(), schedule.to_dict()], sort_keys=True,
                          default=str), domain, offsets.tobytes(), self.regularization,
               tuple(o.tobytes() for o in side_offsets))
        with _MODELS_LOCK:
            model = _MODELS.pop(key, None)
            if model is None:
                model = DriftModel(ReadCovariance(schedule, self.components, offsets, domain,
                                                  common=self.common,
                                                  side_offsets=side_offsets))
            _MODELS[key] = model  # most recently used last
            while len(_MODELS) > 1 and (len(_MODELS) > _MAX_MODELS or sum(
                    m.held_bytes() for m in _MODELS.values()) > _MODEL_BYTES):
                _MODELS.pop(next(iter(_MODELS)))
        return model

    def predicted_variance(self, context, reads=None, parity=0):
        """Predicted error variance of each read's estimate, and of the ``mean`` strategy's.

        For full reference reads (no pixel left out) in every channel, under
        the strategy's noise model: what the estimate of one channel's value
        at each read misses, ``E[(t̂ - t)^2]``, where ``t`` is the mean of
        the group's pixels of that read (minus its phantom value when the
        phantom is subtracted).

        Parameters
        ----------
        context : `~spherex_reduce.core.block.Context`
            The schedule, whether the input is ramps (``domain: auto``) and
            whether it carries phantom values (used with ``phantom: auto``).
        reads : array_like of int, optional
            The reference reads (default: the schedule's).
        parity : int
            The group (0, or 1 for odd samples with ``acn``).

        Returns
        -------
        wiener, mean : `numpy.ndarray`, shape ``(n_reads,)``
            In the noise model's unit squared: e² for ``domain: frames``, (e/s)²
            for ``slopes`` (compare them with data in electrons).

        Examples
        --------
        >>> from spherex_reduce import ReadoutSchedule
        >>> from spherex_reduce.core.block import Context
        >>> from spherex_reduce.reduce.steps.reference.wiener import WienerReference
        >>> s = ReadoutSchedule()   # the paper's case, slopes with phantom values
        >>> w, m = WienerReference().predicted_variance(Context(s, "readout", False,
        ...                                                     has_phantom=True))
        >>> a = s.active_read_indices
        >>> bool(w[a].mean() < 0.8 * m[a].mean())
        True
        """
        *_, var, mvar = self._full_weights(context, reads, parity)
        return var, mvar

    def read_weights(self, context, parity=0):
        """The weights the estimate applies when every reference pixel is usable.

        The estimate of channel ``ch`` (group ``parity``) at every read is
        ``w @ y_ch + wd @ mean_ch(y)``: ``y_ch`` the channel's observations, the
        value of each reference read (the mean of the group's pixels, minus the
        read's phantom value once it is subtracted) and, when the strategy
        estimates from them, the phantom value of every read, in read order;
        ``mean_ch`` their mean over channels; with ``side_columns`` it adds
        ``ws @ s`` (`side_weights`).  Linear: the noise forecast propagates
        them.

        Parameters
        ----------
        context : `~spherex_reduce.core.block.Context`
            As `predicted_variance`.
        parity : int
            The group (0, or 1 for odd samples with ``acn``).

        Returns
        -------
        w : `numpy.ndarray`, shape ``(n_reads, k [+ n_reads])``
        wd : `numpy.ndarray` or None
            Same shape; None with one channel.
        kind : str
            What a reference read's value is (`~spherex_reduce.noise.read_covariance.KINDS`:
            ``'pixels'``, or ``'subtracted'`` once the phantom values are subtracted).
        phantom : bool
            Whether the phantom values of every read are observations.

        Examples
        --------
        >>> import numpy as np
        >>> from spherex_reduce import ReadoutSchedule
        >>> from spherex_reduce.core.block import Context
        >>> from spherex_reduce.reduce.steps.reference.wiener import WienerReference
        >>> s = ReadoutSchedule(nframes=4)
        >>> w, wd, kind, phantom = WienerReference().read_weights(
        ...     Context(s, "readout", False, has_phantom=True))
        >>> w.shape == (s.n_reads, s.ref_reads + s.n_reads), kind, phantom
        (True, 'pixels', True)
        >>> bool(np.allclose((w + wd)[:, :s.ref_reads].sum(axis=1), 1))  # unbiased
        True
        """
        w, wd, *_ = self._full_weights(context, None, parity)
        use = self.uses_phantom(context)
        return w, wd, self._kind(context, use), use

    def side_weights(self, context, parity=0):
        """The weights of the side values, when the strategy observes them.

        The estimate of every channel (group ``parity``) adds ``ws @ s`` to
        `read_weights`' terms: ``s`` the side value of each read in ``reads``,
        the mean over the channels in ``groups`` of their side pixels' mean.

        Parameters
        ----------
        context, parity
            As `read_weights`.

        Returns
        -------
        ws : `numpy.ndarray`, shape ``(n_reads, r)``, or None
            None when no side value is observed (`side_groups`).
        reads : `numpy.ndarray` of int, shape ``(r,)``
            The light-sensitive rows' reads, in read order.
        groups : list of (int, `numpy.ndarray`)
            The channels with side columns in the group, and those columns.

        Examples
        --------
        Each channel's white noise and a pink drift common to all (a noise table in a
        temporary file):

        >>> import tempfile, pathlib
        >>> import numpy as np
        >>> from astropy.table import Table
        >>> from spherex_reduce import DetectorGeometry, ReadoutSchedule
        >>> from spherex_reduce.core.block import Context
        >>> from spherex_reduce.reduce.steps.reference.wiener import WienerReference
        >>> g = DetectorGeometry(32, 32, 4, ref_border=4, scan="alternate")
        >>> s = ReadoutSchedule(g, nframes=3, phantom_reads=0)
        >>> path = pathlib.Path(tempfile.mkdtemp()) / "pink.ecsv"
        >>> Table({"name": ["white", "pink"], "alpha": [2e-3, 0.0], "beta": [0.0, 1e-3],
        ...        "gamma": [0.0, 0.0], "scope": ["channel", "common"]}
        ...       ).write(path, format="ascii.ecsv")
        >>> w = WienerReference(noise=str(path), side_columns=True)
        >>> ws, reads, groups = w.side_weights(Context(s, "readout", True))
        >>> ws.shape == (s.n_reads, 24), [ch for ch, _ in groups]
        (True, [0, 3])
        >>> bool(np.allclose(ws.sum(axis=1), 0))  # the side values' own offset cancels
        True
        """
        s = context.schedule
        groups = self.side_groups(s.geometry)
        ws = self._full_weights(context, None, parity)[2]
        return ws, np.sort(s.active_read_indices), (None if groups is None else groups[parity])

    def _full_weights(self, context, reads, parity):
        """`DriftModel.weights` of full reference reads: ``(w, wd, ws, variance, mean
        variance)``."""
        s = context.schedule
        reads = s.reference_read_indices if reads is None else np.asarray(reads, dtype=int)
        groups = group_columns(s.geometry, self.acn)
        cols = groups[0, parity][groups[0, parity] >= 0]
        domain = self._domain(context)
        use = self.uses_phantom(context)
        kind = self._kind(context, use)
        sides = self.side_groups(s.geometry)
        side_reads = None if sides is None else np.sort(s.active_read_indices)
        model = self._model(s, domain, s.geometry.column_offsets()[cols],
                            None if sides is None else sides[parity])
        return model.weights(self, kind, reads, np.full(reads.size, float(cols.size)),
                             cols.size, s.geometry.nchannels, True, use, side_reads)

    def _domain(self, context):
        """``frames`` or ``slopes``: ``auto`` is frames for ramps (or a single frame)."""
        nframes = context.schedule.nframes
        if self.domain == "auto":
            return "frames" if context.ramp or nframes < 2 else "slopes"
        if self.domain == "slopes" and nframes < 2:
            raise ConfigError("correct_reference.domain: slopes needs a schedule of at least "
                              f"2 frames (NFRAMES={nframes}); use domain: frames")
        return self.domain

    @staticmethod
    def _kind(context, with_phantom):
        """What a read's value is: its pixels' mean, minus its phantom value once
        ``subtract_phantom`` has run (`~spherex_reduce.noise.read_covariance.KINDS`)."""
        subtracted = bool(context.schedule.phantom_reads) and not context.has_phantom
        return "subtracted" if subtracted and not with_phantom else "pixels"

    # -- the estimate -------------------------------------------------------------------
    def check_data(self, context):
        """Refuse data the noise model does not describe: another unit than the model's
        (``input: gain`` converts ADU to electrons first), or, with the default model (the
        paper's electronics: electrons, 100 kHz), data from another readout, or a window
        of a larger array (its reads are not evenly spaced: the model's lags assume they
        are)."""
        if context.schedule.geometry.window is not None:
            raise ConfigError("correct_reference.strategy: wiener does not model a window of "
                              "a larger array (its reads are spread over the full readout); "
                              "use strategy: mean or acn")
        unit = None if context.unit is None else u.Unit(context.unit)
        # frames in the model's unit, slopes in it per second
        charge = None if unit is None else unit * u.s if (
            unit == self.model_unit / u.s or unit * u.s in CHARGE_UNITS) else unit
        rate = float(u.Quantity(context.schedule.geometry.pixel_rate, u.Hz).value)
        if not self.noise_given and (rate != PAPER_PIXEL_RATE or charge not in (None,
                                                                            u.electron)):
            raise ConfigError(
                f"correct_reference.noise: the default noise model ({DEFAULT_NOISE}, the "
                f"paper's electronics: electrons at {PAPER_PIXEL_RATE:g} Hz) does not describe "
                f"these data ({rate:g} Hz, {unit or 'no unit'}): name a noise model, e.g. a "
                "fit-noise result of your darks")
        if charge is not None and charge != self.model_unit and self.noise_given:
            # a scene in adu with its gain describes data in electrons too, and back
            comps, unit_ = noise_model(self.noise, unit=charge)
            if unit_ == charge:
                self.components, self.model_unit = comps, unit_
        if charge is not None and charge != self.model_unit:
            raise ConfigError(
                f"correct_reference.noise: the noise model {self.noise} is in "
                f"{self.model_unit}, the data in {unit}: give a model in the data's unit (a "
                "fit-noise result or characterize model of these darks; a scene in adu with "
                "its gain: serves both), or convert the data (input: gain)")

    def estimate(self, side, context, exposure=None):
        self.check_data(context)
        s = context.schedule
        g = s.geometry
        usable = reference_pixels(side, s)  # (L, k, ncols), NaN: unusable
        values, _, found = without_telegraph(self, usable, side, s)
        # the telegraph pixels' usable reads
        left_out = None if found is None else found.reads & np.isfinite(usable)
        del usable
        reads = _reads_of(side, s)
        domain = self._domain(context)
        phantom = None
        if self.uses_phantom(context) and side.read_phantom is not None:
            phantom = np.asarray(side.read_phantom, dtype=np.float64)
        # a frame with a non-finite phantom value: estimated from its reference reads alone
        # (its phantom values are consumed all the same: nothing subtracts them later)
        bad = np.zeros(values.shape[0], bool) if phantom is None else ~np.isfinite(
            phantom).all(axis=(1, 2))
        if bad.any():
            warnings.warn(f"correct_reference (wiener): {int(bad.sum())} frame(s) with "
                          "non-finite phantom values estimated from the reference reads alone",
                          AstropyUserWarning, stacklevel=2)
        kind = self._kind(context, phantom is not None)
        groups = group_columns(g, self.acn)  # (nch, P, w), -1 pads
        nch, npar = groups.shape[:2]
        obs, n, clipped = self._reference_values(values, groups)
        weights_n = n if left_out is None else self._counts_with(n, left_out, groups)
        L, n_reads = values.shape[0], s.n_reads
        sides, sv = self.side_groups(g), None
        if sides is not None:
            if exposure is None:
                raise ValueError("correct_reference (wiener): side_columns needs the exposure "
                                 "(the side columns of every row)")
            sv = side_values(exposure, sides, self.sigma)
        rows = np.full((L, n_reads, nch, npar), np.nan)
        predicted = np.full((npar, n_reads), np.nan)
        mean_predicted = np.full((npar, n_reads), np.nan)
        for p in range(npar):
            cols = groups[0, p][groups[0, p] >= 0]
            model = self._model(s, domain, g.column_offsets()[cols],
                                None if sv is None else sides[p])
            out = np.full((L, n_reads, nch), np.nan)
            # frames with their phantom values, then those without (the pixels' own drift)
            for frames, k, ph in ((~bad, kind, phantom), (bad, "pixels", None)):
                if not frames.any():
                    continue
                part = out[frames]
                var = model.estimate(self, k, reads, obs[frames][..., p],
                                     weights_n[frames][..., p],
                                     cols.size, None if ph is None else ph[frames], part,
                                     None if sv is None else (sv.reads,
                                                              sv.values[p][frames]))
                out[frames] = part
                if np.isnan(predicted[p]).all():  # the first frames' prediction
                    predicted[p], mean_predicted[p] = var
            rows[..., p] = out
        active = s.active_read_indices
        with warnings.catch_warnings():  # a group without usable pixels: NaN, flagged later
            warnings.simplefilter("ignore", RuntimeWarning)
            offsets = np.nanmean(rows[:, active] if active.size else rows, axis=1)
        parity = [EVEN, ODD] if self.acn else [ALL]
        drift = self._drift_table(rows, parity, context, domain, predicted, mean_predicted,
                                  active, phantom is not None, sv, sides)
        return ReferenceOffsets(offsets, n.sum(axis=1), clipped, parity, rows=rows,
                                tables={"REFDRIFT": drift}, telegraph=found)

    @staticmethod
    def _counts_with(n, left_out, groups):
        """Pixel counts ``n (L, k, nch, P)`` with the telegraph pixels' reads added back
        (``left_out (L, k, ncols)``), for the weights alone: the estimate then shares its
        weights across channels as without telegraph pixels (one solve instead of one per
        channel, 5x faster at full size), at the price of a white noise understated by a
        few percent for reads that lost pixels.  A read with no pixel left stays at 0."""
        extra = left_out[:, :, np.maximum(groups, 0)] & (groups >= 0)
        return np.where(n > 0, n + extra.sum(axis=-1), 0)

    def _reference_values(self, values, groups):
        """Each reference read's value per channel and group ``(L, k, nch, P)`` (the mean of
        its usable pixels, outliers beyond ``sigma`` robust deviations left out), the
        pixels averaged, and the pixels left out per ``(L, nch, P)``."""
        v = values[:, :, np.maximum(groups, 0)]  # (L, k, nch, P, w)
        v[:, :, groups < 0] = np.nan
        usable = np.isfinite(v)
        with warnings.catch_warnings():  # a group without usable pixels: NaN, flagged later
            warnings.simplefilter("ignore", RuntimeWarning)
            med = np.nanmedian(v, axis=(1, 4), keepdims=True)
            mad = np.nanmedian(np.abs(v - med), axis=(1, 4), keepdims=True)
        with np.errstate(invalid="ignore"):
            clipped = usable & (np.abs(v - med) > self.sigma * MAD_TO_SIGMA * mad) & (mad > 0)
        v[clipped] = np.nan
        n = np.isfinite(v).sum(axis=-1)
        with np.errstate(invalid="ignore", divide="ignore"):
            obs = np.where(n > 0, np.nansum(v, axis=-1) / np.maximum(n, 1), np.nan)
        return obs, n, clipped.sum(axis=(1, 4))

    def _drift_table(self, rows, parity, context, domain, predicted, mean_predicted, active,
                     used_phantom, sv=None, sides=None):
        L, n_reads, nch, npar = rows.shape
        fr, ch, pa = np.meshgrid(np.arange(L), np.arange(nch), np.arange(npar), indexing="ij")
        cols = {}
        if context.ramp:
            cols["frame"] = fr.ravel()
        cols["channel"] = ch.ravel()
        cols["parity"] = np.asarray(parity)[pa.ravel()]
        cols["drift"] = rows.transpose(0, 2, 3, 1).reshape(-1, n_reads).astype(np.float32)

        def rms(v):
            v = v[:, active] if active.size else v
            return float(np.sqrt(np.nanmean(v))) if np.isfinite(v).any() else float("nan")

        unit = str(context.unit or "")
        table = Table(cols, meta={
            "strategy": self.name, "bunit": unit, "domain": domain,
            "noise": str(self.noise), "common": sorted(self.common),
            "phantom_used": bool(used_phantom),
            "side_channels": "" if sv is None else " ".join(
                str(ch) for ch in sorted({ch for part in sides for ch, _ in part})),
            "side_pixels_left_out": 0 if sv is None else sv.left_out,
            "side_reads_clipped": 0 if sv is None else sv.clipped,
            "predicted_rms_error": rms(predicted),
            "mean_predicted_rms_error": rms(mean_predicted),
            # the noise model's unit (the data's: `check_data`)
            "predicted_unit": str(self.model_unit / u.s if domain == "slopes"
                                  else self.model_unit)})
        table["drift"].description = (f"drift subtracted from each read of the frame, in read "
                                      f"order ({unit or 'data unit'})")
        return table
