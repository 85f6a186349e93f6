"""A fitted model against darks: the slope scatter against N (paper Fig. 12a) and the reduced P(k).

`DarkScatter` measures, dark by dark as they are read, what
`~spherex_reduce.analysis.characterize.predict` predicts: every dark is
reduced by the pipeline with its first ``N`` reads for each ``N`` of a grid
(`~spherex_reduce.analysis.characterize.predict.frame_grid`), the darks are
taken in pairs (first and second, third and fourth, ...; an odd one out is
left out) and of each pair the difference of the light-sensitive slope images
over √2 is the paper's statistic: its standard deviation over pixels after an
iterative 5 σ clip (`astropy.stats.sigma_clipped_stats`; pixels the pipeline
masks in either dark, such as hot pixels, left out).  One dark alone is
measured as it is.  At the darks' readout the P(k) and the 5–20′ band power of
that difference (its clipped pixels masked) are measured too.  The numbers
are the means over pairs, their errors the pairs' scatter (one pair: the
clipped pixels' standard error, which leaves out the correlated noise).

`compare` puts both side by side;
`~spherex_reduce.analysis.characterize.run.check_model` does it on held-out darks.
"""

from concurrent.futures import ThreadPoolExecutor, as_completed

import numpy as np
from astropy import units as u
from astropy.nddata import CCDData
from astropy.stats import SigmaClip
from astropy.table import Table

from ...core.errors import SpherexReduceError
from ...core.exposure import Exposure, first_frames_schedule
from ...io.sources import MemorySource
from ...reduce.options import default_threads
from ...reduce.steps.clipping import clipped_pixels
from ..light import light_sensitive_image
from ..spectrum import band_power, power_spectrum
from .predict import CLIP_SIGMA, frame_grid, predict_scatter, predict_spectrum

__all__ = ["BAND_TARGET", "SCATTER_TARGET", "DarkScatter", "compare", "reduction_pipeline"]

#: Issue 33's targets on held-out darks: the slope scatter within 5 %, the band power 10 %.
SCATTER_TARGET = 0.05
BAND_TARGET = 0.10
#: Frame counts reduced at once (threads), the cores shared between their bands: one
#: reduction's serial parts (its reference estimate, its image's clip) overlap another's
#: bands.  Memory: each holds its bands in flight and its slope image.
SCATTER_THREADS = 2


def reduction_pipeline(config):
    """The pipeline darks are reduced by: ``config`` (a `~spherex_reduce.Pipeline`, a
    shipped name, a path or a mapping), or the paper's (``spherex-default``) for None."""
    from ...reduce.pipeline import Pipeline, as_pipeline

    if config is None:
        return Pipeline.from_yaml("spherex-default")
    return as_pipeline(config)


def _check_count(source, n):
    """Refuse (`~spherex_reduce.core.errors.SpherexReduceError`) a raw dark that cannot be
    cut to its first ``n`` reads (`~spherex_reduce.io.sources.Source.first_frames`), before
    any is cut."""
    if n < 2:
        raise SpherexReduceError(f"slope scatter: {n} reads of a dark have no slope")
    if not source.context.ramp:
        raise SpherexReduceError("slope scatter: first frames: the dark holds an image, not "
                                 "ramps")
    try:
        first_frames_schedule(source.context.schedule, n)
    except ValueError as exc:  # grouped reads, more reads than the dark's
        raise SpherexReduceError(f"slope scatter: {exc}") from None


def _image(pipeline, exposure, threads=None):
    """The light-sensitive slope image, NaN where masked (float32, as the pipeline's
    slopes), and its unit (``threads``: the reduction's bands at once, as
    `~spherex_reduce.Pipeline.run`)."""
    red = pipeline.run(exposure, threads=threads)
    if red.is_ramp:
        raise SpherexReduceError("slope scatter: the pipeline gives ramps, not a slope image "
                                 "(it has no fit_ramp step)")
    img = light_sensitive_image(red)
    data = np.array(img.data, dtype=np.float32)  # held per frame count: half the memory
    if img.mask is not None:
        data[np.asarray(img.mask, dtype=bool)] = np.nan
    return data, img.unit


class DarkScatter:
    """The slope scatter against N and the reduced P(k) of darks, added one at a time.

    Parameters
    ----------
    pipeline : `~spherex_reduce.Pipeline`
        The reduction (`reduction_pipeline`).
    nframes : int
        The darks' frames (the grid runs from 2 to all).
    frames : sequence of int, optional
        The frame counts (default `~spherex_reduce.analysis.characterize.predict.frame_grid`).
    measure : dict, optional
        ``bins``, ``kmin``, ``kmax`` of the P(k) and band power (default the paper's band,
        30 bins).

    Examples
    --------
    >>> from spherex_reduce.io.examples import example_raw_exposure
    >>> from spherex_reduce.analysis.characterize.check import DarkScatter, reduction_pipeline
    >>> d = DarkScatter(reduction_pipeline(None), 6, frames=[2, 6], measure={"kmin": 0.2,
    ...                 "kmax": 1.0, "bins": 4})
    >>> d.add(example_raw_exposure())
    >>> m = d.result()
    >>> m["frames"].tolist(), m["pairs"], m["differenced"]
    ([2, 6], 0, False)
    """

    def __init__(self, pipeline, nframes, frames=None, measure=None):
        self.pipeline = pipeline
        self.frames = list(frame_grid(nframes) if frames is None else frames)
        if self.frames[-1] != nframes:
            self.frames.append(nframes)
        m = {"bins": 30, **(measure or {})}
        self.bins = int(m["bins"])
        self.band = {k: m[k] for k in ("kmin", "kmax") if k in m}
        self._held = None
        self._stats = []  # per pair (or the single dark): sigma per N, P(k), band power
        self.unit = None

    def _images(self, source, each=None):
        """The slope image of ``source`` at every frame count, in the order of
        ``self.frames``; or, given ``each``, None: ``each(n, image)`` is called in this
        thread with each image as it is done, while the others are reduced, and the image
        is not kept.  A failure cancels the frame counts not yet started."""
        counts = list(dict.fromkeys(self.frames))
        for n in counts:  # every frame count refused before any work
            _check_count(source, n)
        nthreads = min(SCATTER_THREADS, default_threads(), len(counts))
        bands = max(1, default_threads() // nthreads)  # each reduction's band threads

        def image(n):  # each cut made when reduced, let go with its image
            return _image(self.pipeline, source.first_frames(n), threads=bands)

        done = {}

        def got(n, result):
            if n == self.frames[-1]:
                self.unit = result[1]
            if each is None:
                done[n] = result[0]
            else:
                each(n, result[0])

        if nthreads <= 1:
            for n in counts:
                got(n, image(n))
        else:  # the longest first, so that the threads end together
            longest = sorted(counts, reverse=True)
            with ThreadPoolExecutor(nthreads, thread_name_prefix="spherex-reduce-scatter") as pool:
                work = {pool.submit(image, n): n for n in longest}
                try:
                    for fut in as_completed(work):
                        got(work[fut], fut.result())
                except BaseException:
                    pool.shutdown(cancel_futures=True)
                    raise
        return None if each is not None else [done[n] for n in self.frames]

    def add(self, dark):
        """Reduce ``dark`` at every frame count; every second dark closes a pair.

        ``dark`` is a raw `~spherex_reduce.Exposure` or a
        `~spherex_reduce.io.sources.Source`: a raw file's source is reduced band by
        band of rows from its first ``N`` reads (the pipeline's passes,
        `~spherex_reduce.Pipeline.run`), never read whole unless a step needs the
        whole exposure.  A pair's statistics at each frame count are taken as its
        second image is done, while the others are reduced, and both images are let
        go (a failure drops the pair).
        """
        source = MemorySource(dark) if isinstance(dark, Exposure) else dark
        if self._held is None:
            self._held = self._images(source)
            return
        held = dict(zip(self.frames, self._held, strict=True))
        self._held = None  # each first image let go once its pair is measured
        stats = {}

        def each(n, image):  # the pair's difference at n, over sqrt(2)
            stats[n] = self._scatter((held.pop(n).astype(np.float64) - image) / np.sqrt(2.0),
                                     last=n == self.frames[-1])

        self._images(source, each)
        self._stats.append(self._combine([stats[n] for n in self.frames]))

    def _measure(self, images):
        """`_combine` of the statistics of ``images`` (float64), one per frame count."""
        last = len(images) - 1
        return self._combine([self._scatter(img, last=i == last)
                              for i, img in enumerate(images)])

    def _scatter(self, img, last=False):
        """``(sigma, kept, P(k) and band power or None)`` of one image: its standard
        deviation over the finite pixels that astropy's sigma clip keeps, and (the last
        frame count's) its P(k) and band power with the pixels clipped masked."""
        clipper = SigmaClip(sigma=CLIP_SIGMA, maxiters=None, cenfunc="median", stdfunc="std")
        ok = np.isfinite(img)
        keep = ok & ~clipped_pixels(img, ok, clipper)
        sigma = float(np.std(img[keep])) if keep.any() else np.nan
        spectra = None
        if last:
            masked = CCDData(np.where(keep, img, 0.0), unit=self.unit, mask=~keep)
            spectra = (power_spectrum(masked, bins=self.bins),
                       band_power(masked, return_error=True, **self.band))
        return sigma, int(np.count_nonzero(keep)), spectra

    def _combine(self, per_count):
        """The statistics of one pair (or the single dark) from `_scatter`'s per frame
        count."""
        spec, band = per_count[-1][2]
        return {"sigma": np.array([s[0] for s in per_count]),
                "kept": np.array([s[1] for s in per_count]),
                "k": np.asarray(u.Quantity(spec["k"]).value),
                "power": np.asarray(u.Quantity(spec["power"]).value),
                "band": float(band[0].value), "band_err": float(band[1].value),
                "power_unit": u.Quantity(spec["power"]).unit}

    def result(self):
        """The measurements: ``frames``, ``sigma`` and ``sigma_err`` (slope unit), ``k``,
        ``power`` (P(k) at all frames), ``band_power`` and ``band_power_err``, ``pairs``,
        ``differenced``, ``unit``."""
        stats, differenced = self._stats, True
        if not stats and self._held is not None:  # one dark: measured as it is
            stats = [self._measure([a.astype(np.float64) for a in self._held])]
            differenced = False
        if not stats:
            raise SpherexReduceError("slope scatter: no dark measured")
        sig = np.array([s["sigma"] for s in stats])
        k = len(stats)
        if k > 1:
            err = sig.std(axis=0, ddof=1) / np.sqrt(k)
            bands = np.array([s["band"] for s in stats])
            band_err = float(bands.std(ddof=1) / np.sqrt(k))
        else:
            err = sig[0] / np.sqrt(2 * np.maximum(stats[0]["kept"] - 1, 1))
            band_err = stats[0]["band_err"]
        return {"frames": np.array(self.frames), "sigma": sig.mean(axis=0), "sigma_err": err,
                "k": stats[0]["k"], "power": np.mean([s["power"] for s in stats], axis=0),
                "band_power": float(np.mean([s["band"] for s in stats])),
                "band_power_err": band_err, "pairs": len(self._stats),
                "differenced": differenced, "unit": self.unit,
                "power_unit": stats[0]["power_unit"], "bins": self.bins, "band": self.band}


def compare(model, measured, pipeline):
    """The measured slope scatter, P(k) and band power beside what ``model`` predicts.

    Parameters
    ----------
    model : `~spherex_reduce.analysis.characterize.Characterization`
    measured : dict
        `DarkScatter.result`.
    pipeline : `~spherex_reduce.Pipeline`
        The pipeline the darks were reduced by.

    Returns
    -------
    `~astropy.table.Table`
        One row per quantity: ``quantity`` (``slope_scatter`` at each ``frames``,
        ``band_power``, ``power_spectrum`` at each ``k``), ``frames``, ``k``
        (rad/pixel, NaN for the scatter), ``measured``, ``error``, ``predicted``,
        ``predicted_streams`` (without the telegraph pixels), ``ratio``
        (measured / predicted), ``target`` (relative, NaN for P(k) bins) and
        ``within``; ``meta`` says the statistic, the pairs and the telegraph
        population.
    """
    frames = [int(n) for n in measured["frames"]]
    clip = next((float(params["sigma"]) for name, params in pipeline.steps
                 if name == "sigma_clip"), None)  # the pipeline's clip of each image
    pred = predict_scatter(model, pipeline, frames, differenced=measured["differenced"],
                           image_clip=clip)
    measure = {"bins": measured["bins"], **measured["band"]}
    spec = predict_spectrum(model, pipeline, measure, excess=pred["telegraph_excess"][-1])
    unit = measured["unit"]
    rows = []

    def add(q, n, k, m, e, p, ps, target):
        ratio = m / p if p > 0 else np.nan
        rows.append((q, n, k, m, e, p, ps, ratio, target,
                     bool(np.isfinite(target) and abs(ratio - 1) <= target)))

    for i, n in enumerate(frames):
        add("slope_scatter", n, np.nan, measured["sigma"][i], measured["sigma_err"][i],
            pred["sigma"][i], pred["sigma_streams"][i], SCATTER_TARGET)
    add("band_power", frames[-1], np.nan, measured["band_power"], measured["band_power_err"],
        spec.meta["band_power"], spec.meta["band_power"] - spec.meta["telegraph_white"],
        BAND_TARGET)
    pk = u.Quantity(spec["power"]).value
    pks = u.Quantity(spec["power_streams"]).value
    for i, k in enumerate(measured["k"]):
        add("power_spectrum", frames[-1], k, measured["power"][i], np.nan, pk[i], pks[i],
            np.nan)
    t = Table(rows=rows, names=("quantity", "frames", "k", "measured", "error", "predicted",
                                "predicted_streams", "ratio", "target", "within"),
              dtype=(str, int, float, float, float, float, float, float, float, bool))
    how = ("difference of two darks / sqrt(2)" if measured["differenced"]
           else "one dark as it is (no second dark to difference)")
    t.meta.update({
        "statistic": f"standard deviation over the light-sensitive pixels after an iterative "
                     f"{CLIP_SIGMA:g} sigma clip, of the {how}, reduced by "
                     f"{pipeline.config.get('name', 'pipeline')} ("
                     f"{', '.join(name for name, _ in pipeline.steps)})",
        "pairs": int(measured["pairs"]), "unit": str(unit),
        "power_unit": str(measured["power_unit"]),
        "telegraph": (None if pred["telegraph"] is None else
                      dict(zip(("fraction", "amplitude", "amplitude_spread", "rate"),
                               map(float, pred["telegraph"]), strict=True))),
        "telegraph_note": pred["note"],
        "faint_telegraph": (None if pred["faint"] is None else
                            dict(zip(("power", "rate", "white", "fraction", "amplitude"),
                                     pred["faint"], strict=True)))})
    return t

