"""`Characterization`: the fitted model of a detector, as a scene, a report and a plot."""

import dataclasses

import numpy as np
from astropy import units as u
from astropy.table import Table

from ...noise.components import NoiseComponent
from ..faint_telegraph import MIN_GROUP
from .model import (
    ACN_SIGMAS,
    BAD_FIT_PROBABILITY,
    LAYOUT,
    PARAMS,
    Estimate,
    combine,
    goodness,
    scene_values,
)
from .spectra import NOT_REPORTED, SPECTRA

__all__ = ["Characterization", "group_drift", "hold_white", "seen_white"]

#: A reference-pixel white level this many standard errors from the light-sensitive
#: pixels' is reported as different.
DIFFERENT_SIGMAS = 3.0


def _units(unit, exponent):
    return {"alpha": unit**2 / u.Hz, "beta": unit**2,
            "gamma": unit**2 * u.Hz ** (exponent - 1)}


#: the spectrum each component is fitted from, whose bins give its frequencies
SOURCES = {"channel": "pixels", "acn": "acn", "common": "pixels_common",
           "channel_both": "both", "common_both": "both_common",
           "channel_phantom": "phantom", "common_phantom": "phantom_common"}

#: The per-pixel terms `Characterization.summary` prints (the report holds them all).
PIXEL_SUMMARY = ("read_noise", "dark_current", "hot_pixel_fraction", "telegraph_fraction",
                 "first_read_offset")


@dataclasses.dataclass
class Characterization:
    """The noise model fitted to a detector's darks (`characterize`).

    Attributes
    ----------
    schedule : `~spherex_reduce.ReadoutSchedule`
        The darks' readout.
    unit : `~astropy.units.Unit`
        The darks' unit: the model's coefficients are in ``unit²/Hz`` etc.
    darks : list of str
        The darks (files, integrations).
    ngroups : int
        Darks or segments, each left out in turn for the jackknife uncertainties.
    exponent, exponent_err : float
        The exponent of every component's third term; its error when fitted (else None).
    components : dict
        ``{name: Estimate}``: ``alpha beta gamma`` and their standard errors of
        each component (`LAYOUT` gives scope and visibility).
    spectra : dict
        ``{name: Estimate}``: the fit of each spectrum (`SPECTRA`).
    spreads : dict
        Per view (``pixels``, ``phantom``, ``reference``): per-channel values and
        errors, the channels' standard deviation and whether it is real.
    acn : dict or None
        The ACN test: ``power``, ``error``, ``z``, ``found``, ``band`` (Hz).
    marks : list of str
        One line per term the darks cannot constrain, or that the model holds
        otherwise than the darks show.

    Examples
    --------
    >>> from spherex_reduce.io.examples import example_raw_exposure
    >>> from spherex_reduce.analysis.characterize import characterize
    >>> model = characterize(example_raw_exposure(), segments=2)
    >>> sorted(model.scene()), model.scene()["unit"]
    (['geometry', 'noise', 'readout', 'scene', 'unit'], 'electron')
    >>> set(model.report()["kind"]) >= {"component", "spectrum", "channel", "exponent"}
    True
    >>> model.to_yaml().startswith("# noise model fitted by spherex-reduce characterize")
    True
    """

    schedule: object
    unit: object
    darks: list
    ngroups: int
    exponent: float
    exponent_err: object
    components: dict
    spectra: dict
    spreads: dict
    acn: object
    acn_on: bool
    marks: list
    bins: dict = dataclasses.field(repr=False, default_factory=dict)
    #: the config's ``input: gain`` (e⁻/ADU) the darks were converted with, if any
    gain: object = None
    #: the per-pixel terms (`~spherex_reduce.analysis.pixel_terms.PixelTerms`), if fitted
    pixel_terms: object = None
    #: the darks' slope scatter against N and reduced P(k), measured and predicted
    #: (`~spherex_reduce.analysis.characterize.check.compare`), if measured
    check: object = None

    @classmethod
    def build(cls, full, jack, boxes, schedule, unit, darks, exponent_fitted=False,
              segmented=False, gain=None):
        """The model from the fits of all darks pooled (``full``) and of the darks pooled
        without each one in turn (``jack``, `combine`); says what is missing."""
        nch = schedule.geometry.nchannels
        got = combine(full, jack, boxes, nch)
        exponent = got["exponent"]
        self = cls(schedule, u.Unit(unit), list(darks), len(jack), float(exponent.values[0]),
                   float(exponent.errors[0]) if exponent_fitted else None,
                   got["components"], got["spectra"], got["spreads"], got["acn"],
                   got["acn_on"], [])
        self.bins = {k: v.bins for k, v in full.items() if k not in NOT_REPORTED}
        self.gain = gain
        self.marks = self._marks(boxes)
        if segmented:
            self.marks.append(
                f"uncertainties: from {self.ngroups} runs of frames of {len(self.darks)} "
                "dark(s), which are not quite independent (on the round trip their errors "
                "came out up to 1.9 times too small for the correlated terms): give separate "
                "darks for trusted errors")
        return self

    # -- what the darks cannot say --------------------------------------------------------
    def _marks(self, boxes):
        out = []
        s = self.schedule
        if self.unit not in (u.electron, u.one) and not (
                self.unit == u.adu and isinstance(self.gain, (int, float))):
            out.append(f"unit: the darks are in {self.unit} and the config gives no input: gain, "
                       f"so the scene's coefficients are in {self.unit}" + (
                           " (unit: adu; simulate makes darks in adu, forecast, sweep and "
                           "design-readout need a gain: e-/adu added to the scene)"
                           if self.unit == u.adu else
                           " (a unit the scene cannot state: simulate, forecast and "
                           "design-readout take its numbers as electrons)"))
        if s.phantom_reads == 0 or "phantom" not in self.spectra:
            why = ("the darks have no phantom reads" if s.phantom_reads == 0 else
                   "the darks' phantom reads are constant (no noise)")
            out.append("channel_both, channel_phantom, common_both, common_phantom: not "
                       f"constrained: {why} (the model's components are seen by the pixels "
                       "only)")
        if s.geometry.nchannels == 1:
            out.append("common: not constrained: one channel, so the part common to all "
                       "channels cannot be told from each channel's (the model holds both as "
                       "channel)")
        if self.acn is None:
            out.append("acn: not tested: a channel has no light-sensitive column of one "
                       "parity")
        if "reference" not in self.spreads:
            out.append("reference: not constrained: the darks have no reference-row reads or "
                       "side reference columns")
        for view, sp in self.spreads.items():
            for i, p in enumerate(PARAMS):
                if sp["real"][i]:
                    out.append(f"{view}.{p}: differs between channels (standard deviation "
                               f"{sp['spread'][i]:.3g}); the model holds the channel mean")
        notes = self._scene_values()[1]
        for name, est in self.components.items():
            for i, p in enumerate(PARAMS):
                v, e = est.values[i], est.errors[i]
                if (name, p) in notes:
                    sig = f"{-v / e:.1f} sigma" if e > 0 else "no error"
                    out.append(f"{name}.{p} = {v:.3g} ± {e:.2g}" + (
                        f" is below zero ({sig})" if v < 0 else "") + f": {notes[(name, p)]}")
        for name, (c2, dof, prob) in goodness(self.bins, s.geometry.nchannels).items():
            if prob < BAD_FIT_PROBABILITY:
                out.append(f"{name}: the fit is visibly bad (chi2/dof = {c2:.0f}/{dof}, "
                           f"probability {prob:.1g}): the darks hold noise the model lacks")
        if self.ngroups < 5:
            out.append(f"uncertainties: from the scatter of {self.ngroups} darks or segments "
                       f"only (Student t with {self.ngroups - 1} degrees of freedom)")
        return out

    # -- the scene ------------------------------------------------------------------------
    def faint_white(self, components=None):
        """The light-sensitive pixels' white read variance per read (the darks' unit
        squared) that the scene's channel white level holds instead of the streams',
        where the per-pixel terms fitted a faint telegraph population; else None.

        Faint telegraph pixels (`~spherex_reduce.analysis.faint_telegraph`) cannot be
        left out of the streams one by one, so part of their steps stays in the streams
        and is fitted as the channels' white level, while the scene holds the population
        too (``scene.rtn``): 5.9 % of the channel white level, 17 of its errors, on
        ``benchmarks/bench_characterize_heldout.py``'s case with one (10 % of the
        pixels switching 30 e at 0.3 Hz under 3.9 e reads), 17 % and 7 % in the
        tests' cases.  What stays depends on which switches each dark's jump search
        flagged (those pixels are left out of that dark's streams), so it cannot be
        computed from the population's power and rate (taken out that way, the
        channel white came out at a fifth of the truth).  The
        per-pixel fit's ``white_read_noise`` (the pixels' structure function with the
        drift common to the pixels read together and the faint telegraph taken out) is
        the white level without them, less what the model's correlated noise adds about
        the mean of the pixels read together (`group_drift`: white from read to read, so
        the fit holds it, where the components hold it too).  Held only where the scene
        holds the population
        (`~spherex_reduce.analysis.pixel_terms.PixelTerms.faint_population`, what
        ``to_scene`` puts in ``rtn``).  ``components``: the scene's (`_scene_components`),
        made here if None."""
        pt = self.pixel_terms
        if pt is None or pt.faint_population() is None:
            return None
        white = pt.row("white_read_noise", "active")
        if white["status"] != "fitted":
            return None
        comps = self._scene_components() if components is None else components
        return max(float(white["value"]) ** 2 - group_drift(comps, self.schedule), 0.0)

    def _scene_values(self):
        """`scene_values` of the components, each over its spectrum's binned frequencies."""
        bands = {}
        for name in self.components:
            b = self.bins.get(SOURCES.get(name), self.bins.get("pixels"))
            if b is not None and len(b):
                f = np.asarray(b["frequency"], dtype=np.float64)
                bands[name] = (float(f.min()), float(f.max()))
        return scene_values({n: est.values for n, est in self.components.items()},
                            self.exponent, bands)

    def _scene_components(self):
        """The components as the scene's mappings (`_scene_values`; those all zero left
        out, a white ``channel`` of 0 where none is left)."""
        comps = []
        for name, held in self._scene_values()[0].items():
            scope, visibility = LAYOUT[name]
            values = {p: float(v) for p, v in zip(PARAMS, held, strict=True)}
            if not any(values.values()):
                continue
            comp = {"name": name, **values, "exponent": self.exponent, "scope": scope,
                    "visibility": visibility}
            if scope == "channel":  # ACN: its own component, or every channel one's
                comp["acn"] = name == "acn" or (self.acn_on and "acn" not in self.components)
            comps.append(comp)
        if not comps:  # a scene with no components simulates the default table: not this
            comps.append({"name": "channel", "alpha": 0.0, "exponent": self.exponent})
        return comps

    def scene(self):
        """The model as a scene mapping (``unit``, ``gain`` in adu where known,
        ``geometry``, ``readout``, ``noise``, ``scene``), in the darks' unit: what
        `~spherex_reduce.simulation.load_scene` takes.

        No coefficient is below zero: one fitted below zero is moved into the term it
        is constrained with (`~spherex_reduce.analysis.characterize.model.scene_values`),
        and `marks` says what was moved, one line per term."""
        comps = self._scene_components()
        white = self.faint_white(comps)
        if white is not None:  # the faint telegraph population once: in scene.rtn
            hold_white(comps, white, self.schedule)
        active = self._active_read_noise(comps, white)
        out = {}
        if self.unit in (u.electron, u.adu):  # the scene's unit: the darks'
            out["unit"] = self.unit.to_string()
            if self.unit == u.adu and isinstance(self.gain, (int, float)):
                out["gain"] = float(self.gain)
        out.update({"geometry": self.schedule.geometry.to_dict(),
                    "readout": self.schedule.to_dict(), "noise": {"components": comps}})
        terms = {} if self.pixel_terms is None else self.pixel_terms.to_scene()
        if active:
            terms["active_read_noise"] = active
        if terms:
            out["scene"] = terms
        return out

    def _white_levels(self, white):
        """``(light, light_err, reference, reference_err)``: the white levels (the darks'
        unit squared per Hz) of the light-sensitive pixels as the scene holds them (the
        pixels' white read noise ``white``, `faint_white`, where it is held, else the
        components' ``channel + common``) and of the reference pixels, with their standard
        errors; None without both."""
        ref = self.spectra.get("reference")
        parts = [self.components[n] for n in ("channel", "common") if n in self.components]
        if ref is None or not parts or "reference" not in self.spreads:
            return None
        if white is not None:  # its error: d(v^2) = 2 v dv, per read; as a level, 2 / fs
            fs = self.schedule.geometry.pixel_rate
            row = self.pixel_terms.row("white_read_noise", "active")
            light, err = 2.0 * white / fs, 4.0 * float(row["value"]) * float(row["error"]) / fs
        else:  # each pixel's white level: channel + common, the jackknife error of the sum
            est = Estimate.of(sum(p.values for p in parts), sum(p.leave_one_out for p in parts))
            light, err = float(est.values[0]), float(est.errors[0])
        return light, err, float(ref.values[0]), float(ref.errors[0])

    @staticmethod
    def _white_gap(levels):
        """``(light - reference, its standard error)`` of ``levels`` (`_white_levels`) where
        they differ by more than `DIFFERENT_SIGMAS` standard errors, else None."""
        if levels is None:
            return None
        light, light_err, ref, ref_err = levels
        err = float(np.hypot(light_err, ref_err))
        d = light - ref
        return (d, err) if err > 0 and abs(d) > DIFFERENT_SIGMAS * err else None

    def _active_read_noise(self, components, white):
        """Where the reference pixels read quieter than the light-sensitive ones (`_white_gap`;
        ``white``: `faint_white`), the white read noise (per read, the darks' unit) only the
        light-sensitive pixels see: the ``channel`` component's white level (in
        ``components``, scene mappings, changed in place) is lowered to what the reference
        pixels show and the difference becomes ``scene.active_read_noise``; else 0 and
        nothing changes."""
        levels = self._white_levels(white)
        gap = self._white_gap(levels)
        if gap is None or gap[0] < 0:
            return 0.0
        seen = seen_white(components)
        channel = next((c for c in components if c["name"] == "channel"), None)
        if channel is None:
            return 0.0
        take = min(seen - levels[2], channel["alpha"])
        if not take > 0:
            return 0.0
        channel["alpha"] -= take
        return float(np.sqrt(take * self.schedule.geometry.pixel_rate / 2))

    def reference_white_mark(self):
        """The line saying how the reference pixels' white level differs from the
        light-sensitive pixels' (by more than `DIFFERENT_SIGMAS` standard errors) and what
        the scene holds, or None; made once the per-pixel terms are known (the
        light-sensitive level may be theirs: `faint_white`)."""
        levels = self._white_levels(self.faint_white())
        gap = self._white_gap(levels)
        if gap is None:
            return None
        light, light_err, ref, ref_err = levels
        active = (self.scene().get("scene") or {}).get("active_read_noise")
        if gap[0] < 0:
            held = ("the model holds the light-sensitive value for every pixel (a white "
                    "level of the reference pixels above theirs is not a scene term)")
        elif active:
            held = (f"the model holds both: the reference level in the components, the "
                    f"light-sensitive pixels' excess as scene.active_read_noise = "
                    f"{active:.4g} {self.unit} per read")
        else:
            held = ("the model holds the light-sensitive value for every pixel (no channel "
                    "component's white level to lower to the reference pixels')")
        return (f"reference: white level {ref:.4g} ± {ref_err:.2g} differs from the "
                f"light-sensitive pixels' {light:.4g} ± {light_err:.2g} "
                f"({abs(gap[0]) / gap[1]:.1f} sigma); {held}")

    def to_yaml(self):
        """The scene as YAML text, its unit and provenance in comments."""
        import yaml

        unit = self.unit.to_string() or "dimensionless"
        gain = "" if self.gain is None else f", read with input: gain {self.gain} e/ADU"
        head = [f"# noise model fitted by spherex-reduce characterize to {len(self.darks)} "
                f"dark(s) ({self.ngroups} darks or segments{gain})",
                f"# unit: {unit} (alpha {unit}^2/Hz, beta {unit}^2, gamma "
                f"{unit}^2 Hz^{self.exponent - 1:.3g}); pixel rate "
                f"{self.schedule.geometry.pixel_rate:g} Hz",
                *(f"# not constrained or held otherwise: {m}" for m in self.marks)]
        return "\n".join(head) + "\n" + yaml.safe_dump(self.scene(), sort_keys=False)

    # -- the report -----------------------------------------------------------------------
    def report(self):
        """Every fitted number with its uncertainty, as a table.

        Rows: each component's terms (``component``), each spectrum's fit
        (``spectrum``), each view's per-channel values (``channel``), the ACN
        test and the exponent, the per-pixel terms (``pixel``), and where the darks'
        slope images were measured, the slope scatter at each frame count
        (``slope_scatter``, name ``N=...``), the 5-20' band power (``band_power``)
        and P(k) (``power_spectrum``, name ``k=...``): ``measured``, ``predicted``,
        ``predicted_without_telegraph`` and ``ratio`` (measured / predicted; its
        ``spread`` is the target); columns ``kind name parameter value error
        spread unit``.  ``meta['marks']`` holds `marks`, ``meta['check']`` the
        measured statistic.
        """
        units = _units(self.unit, self.exponent)
        rows = []

        def add(kind, name, p, value, error, spread=np.nan, unit=None):
            rows.append({"kind": kind, "name": name, "parameter": p, "value": float(value),
                         "error": float(error), "spread": float(spread),
                         "unit": (units[p] if unit is None else unit).to_string()})

        for kind, table in (("component", self.components), ("spectrum", self.spectra)):
            for name, est in table.items():
                for i, p in enumerate(PARAMS):
                    add(kind, name, p, est.values[i], est.errors[i])
        for view, sp in self.spreads.items():
            for c, (vals, errs) in enumerate(zip(sp["channels"], sp["errors"], strict=True)):
                for i, p in enumerate(PARAMS):
                    add("channel", f"{view}[{c}]", p, vals[i], errs[i], sp["spread"][i])
        if self.acn is not None:
            add("acn", "even-odd correlated power", "power", self.acn["power"],
                self.acn["error"], unit=self.unit**2)
        add("exponent", "all components", "exponent", self.exponent,
            np.nan if self.exponent_err is None else self.exponent_err, unit=u.one)
        if self.pixel_terms is not None:  # status and note are in the pixel table itself
            for r in self.pixel_terms.table:
                add("pixel", r["pixels"], r["term"], r["value"], r["error"],
                    unit=u.Unit(r["unit"]) if r["unit"] else u.one)
        if self.check is not None:
            self._check_rows(add)
        t = Table(rows=rows)
        t.meta.update({"darks": self.darks, "segments": self.ngroups, "unit": str(self.unit),
                       "gain": (list(self.gain) if isinstance(self.gain, tuple)
                                else self.gain),
                       "marks": list(self.marks), "spectra": dict(SPECTRA),
                       "acn_test": f"ACN found when the even-odd correlated power is above "
                                   f"zero by > {ACN_SIGMAS:g} standard errors"})
        if self.check is not None:
            t.meta["check"] = {k: v for k, v in self.check.meta.items()}
        if self.acn is not None:
            t.meta["acn"] = {k: (list(v) if isinstance(v, tuple) else v)
                             for k, v in self.acn.items()}
        return t

    def _check_rows(self, add):
        """Rows ``slope_scatter`` (name ``N=...``), ``band_power`` and ``power_spectrum``
        (name ``k=...``, rad/pixel): measured, predicted, predicted without the telegraph
        pixels, and their ratio (`~spherex_reduce.analysis.characterize.check.compare`)."""
        meta = self.check.meta
        for r in self.check:
            q = r["quantity"]
            unit = u.Unit(meta["power_unit"] if q != "slope_scatter" else meta["unit"])
            name = f"k={r['k']:.4g}" if q == "power_spectrum" else f"N={r['frames']}"
            add(q, name, "measured", r["measured"], r["error"], unit=unit)
            add(q, name, "predicted", r["predicted"], np.nan, unit=unit)
            add(q, name, "predicted_without_telegraph", r["predicted_streams"], np.nan,
                unit=unit)
            add(q, name, "ratio", r["ratio"], r["error"] / r["predicted"], spread=r["target"],
                unit=u.one)

    def summary(self):
        """Lines for a terminal: each component, the ACN verdict, the marks."""
        lines = []
        for name, est in self.components.items():
            scope, vis = LAYOUT[name]
            terms = ", ".join(f"{p} = {v:.3g} ± {e:.2g}" for p, v, e in
                              zip(PARAMS, est.values, est.errors, strict=True))
            lines.append(f"{name:>15} ({scope}, {vis}): {terms}")
        if self.acn is not None:
            verdict = "found" if self.acn["found"] else "ruled out"
            lines.append(f"ACN {verdict}: even-odd correlated power {self.acn['power']:.3g} ± "
                         f"{self.acn['error']:.2g} ({self.acn['z']:.1f} sigma; found above "
                         f"{ACN_SIGMAS:g})")
        if self.pixel_terms is not None:
            for r in self.pixel_terms.table:
                if r["term"] in PIXEL_SUMMARY and r["status"] == "fitted":
                    lines.append(f"{r['term']} ({r['pixels']}): {r['value']:.4g} ± "
                                 f"{r['error']:.2g} {r['unit']}")
        if self.check is not None:
            sc = self.check[self.check["quantity"] == "slope_scatter"]
            ratios = ", ".join(f"N={r['frames']}: {r['ratio']:.3f}" for r in sc)
            lines.append(f"slope scatter measured / predicted ({self.check.meta['pairs']} "
                         f"pair(s) of darks): {ratios}")
            band = self.check[self.check["quantity"] == "band_power"]
            if len(band):
                lines.append(f"band power measured / forecast: {band['ratio'][0]:.3f}")
        lines.extend(f"note: {m}" for m in self.marks)
        return lines


def group_drift(components, schedule):
    """What the correlated noise of ``components`` (scene mappings) adds per read (the
    darks' unit squared) to the per-pixel fit's white read noise, averaged over the
    light-sensitive pixels.

    The fit (`~spherex_reduce.analysis.faint_telegraph`) takes out the drift common to the
    pixels read together (one row of one channel and one column parity:
    `~spherex_reduce.analysis.faint_telegraph.common_labels`); what a drift does *within*
    the row, about that mean, is the same at every read and so is fitted as white.  For a
    group of ``n`` pixels at sample offsets ``o`` its variance about the group's mean is
    ``Σ_ij D(o_i − o_j) / (2 n²)``, ``D`` the structure function of the correlated terms
    (``beta``, ``gamma``) the light-sensitive pixels see, and the fit, which divides a
    member's terms by ``1 − 2/n`` for what the mean takes of its own white noise, holds
    ``n/(n − 1)`` of it: ``Σ_ij D / (2 n (n − 1))``.  On NGHXRG's correlated pink (256²,
    64-column outputs) 3.2 ADU² of the fit's 30.4, against its read noise's 27.1.

    Examples
    --------
    >>> from spherex_reduce import DetectorGeometry, ReadoutSchedule
    >>> from spherex_reduce.analysis.characterize.result import group_drift
    >>> s = ReadoutSchedule(DetectorGeometry(64, 64, 1, ref_border=4), nframes=4)
    >>> group_drift([{"name": "w", "alpha": 1e-3}], s)     # white noise: none
    0.0
    >>> group_drift([{"name": "pink", "beta": 1.0}], s) > 0
    True
    """
    comps = [NoiseComponent(c["name"], beta=c.get("beta", 0.0), gamma=c.get("gamma", 0.0),
                            exponent=c.get("exponent", 1.3))
             for c in components if c.get("visibility", "pixels") in ("pixels", "both")
             and (c.get("beta", 0.0) or c.get("gamma", 0.0))]
    if not comps:
        return 0.0
    g = schedule.geometry.frame  # the readout frame: offsets in the row read
    offs, chan = g.column_offsets(), g.channel_of_column()
    light = ~g.reference_column_mask()
    parity = np.arange(g.ncols) % 2
    total = count = 0.0
    for c in range(g.nchannels):
        for p in (0, 1):
            o = offs[(chan == c) & light & (parity == p)]
            if o.size < MIN_GROUP:
                continue
            lags, pairs = np.unique(np.abs(o[:, None] - o[None, :]), return_counts=True)
            d = sum(comp.structure_function(lags, g.pixel_rate) for comp in comps)
            total += float(np.sum(pairs * d)) / (2.0 * (o.size - 1))  # n x 1/(2n(n-1))
            count += o.size
    return total / count if count else 0.0


def seen_white(components):
    """The white level (``alpha`` summed) of the components (scene mappings) the array's
    pixels see (visibility ``pixels`` or ``both``).

    Examples
    --------
    >>> from spherex_reduce.analysis.characterize.result import seen_white
    >>> seen_white([{"name": "a", "alpha": 1.0}, {"name": "b", "alpha": 2.0,
    ...             "visibility": "phantom"}, {"name": "c", "alpha": 4.0, "visibility": "both"}])
    5.0
    """
    return float(sum(c.get("alpha", 0.0) for c in components
                     if c.get("visibility", "pixels") in ("pixels", "both")))


def hold_white(components, variance, schedule):
    """Set the ``channel`` component's white level so that what the light-sensitive pixels
    see of all ``components`` (scene mappings, changed in place) is white read noise of
    ``variance`` per read: ``Σ alpha = 2 variance / pixel_rate`` over the components the
    pixels see (clipped at 0; no ``channel`` component, nothing changes).

    Examples
    --------
    >>> from spherex_reduce import DetectorGeometry, ReadoutSchedule
    >>> from spherex_reduce.analysis.characterize.result import hold_white
    >>> s = ReadoutSchedule(DetectorGeometry(64, 64, 1), nframes=4)
    >>> comps = [{"name": "channel", "alpha": 3e-3}, {"name": "common", "alpha": 1e-3}]
    >>> hold_white(comps, 100.0, s)
    >>> comps[0]["alpha"] * s.geometry.pixel_rate / 2 + comps[1]["alpha"] * 5e4
    100.0
    """
    fs = schedule.geometry.pixel_rate
    seen = seen_white(components)
    for c in components:
        if c["name"] == "channel":
            c["alpha"] = max(c.get("alpha", 0.0) + 2.0 * float(variance) / fs - seen, 0.0)
