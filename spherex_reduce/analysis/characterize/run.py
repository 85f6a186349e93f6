"""`characterize`: raw darks in, a noise model (a scene) with uncertainties out."""

import itertools

import numpy as np
from astropy import units as u

from ...core.errors import SpherexReduceError
from ...core.exposure import Exposure
from ...io.sources import open_input
from ..faint_telegraph import common_labels
from ..pixel_terms import PixelSums, pixel_rows
from .check import DarkScatter, compare, reduction_pipeline
from .result import Characterization, seen_white
from .spectra import dark_spectra, fit_spectra, pool
from .streams import MIN_FRAMES, dark_streams, pooled_boxes, shot_white

__all__ = ["characterize", "check_model", "dark_sources"]

#: Frames of a segment when darks are split to see their scatter (`characterize`).
SEGMENT_FRAMES = 5
#: Segments one dark alone is split into: the jackknife over K has K − 1 degrees of freedom.
TARGET_SEGMENTS = 8


def _pipeline(config):
    """The `~spherex_reduce.Pipeline` of ``config`` (None: none)."""
    from ...reduce.pipeline import as_pipeline

    return None if config is None else as_pipeline(config)


def dark_sources(inputs, pipeline):
    """``(label, source)`` of every raw dark of ``inputs`` (each integration of a 4-D file
    is one), one at a time, opened with ``pipeline``'s sections (None: as they are): a
    `~spherex_reduce.io.sources.Source`, from which a raw file is read band by band of
    reads, never whole (`~spherex_reduce.io.sources.open_input`).

    Examples
    --------
    >>> from spherex_reduce.io.examples import example_raw_exposure
    >>> from spherex_reduce.analysis.characterize.run import dark_sources
    >>> [(label, source.where) for label, source in dark_sources(example_raw_exposure(), None)]
    [('exposure in memory', 'memory')]
    """
    for label, source, _, _ in _darks(inputs, pipeline):
        yield label, source
        del source  # released before the next dark is read


def _darks(inputs, pipeline):
    """`dark_sources`' ``(label, source)``, whether another dark is known to follow (a
    list of inputs, or an integration of a 4-D file before its last), and whether the dark
    is known to be the last (the last integration of a list's last input)."""
    if isinstance(inputs, (str, Exposure)) or hasattr(inputs, "__fspath__"):
        inputs = [inputs]
    listed = isinstance(inputs, (list, tuple))
    for i, what in enumerate(inputs):
        opened = open_input(what) if pipeline is None else pipeline.open(what)
        with opened as inp:
            ks = [None] if inp.integrations is None else range(inp.integrations)
            for k in ks:
                more = (listed and i < len(inputs) - 1) or (k is not None and k < ks[-1])
                yield (inp.label if k is None else f"{inp.label}[{k}]",
                       inp.source(integration=k), more, listed and not more)
        del what, opened, inp  # an exposure given in memory is released before the next


def _segments(nframes, segments):
    """Frame slices each dark is split into (`SEGMENT_FRAMES` frames at least)."""
    if segments is None:
        segments = max(1, min(nframes // SEGMENT_FRAMES, TARGET_SEGMENTS))
    segments = int(segments)
    if segments < 1 or nframes // segments < MIN_FRAMES:
        raise SpherexReduceError(f"segments: {segments} segments of a dark of {nframes} reads "
                                 f"leave fewer than {MIN_FRAMES} reads in one")
    edges = np.linspace(0, nframes, segments + 1).round().astype(int)
    return [slice(a, b) for a, b in itertools.pairwise(edges)]


def characterize(inputs, config=None, *, exponent=1.3, segments=None, nbins=30,
                 nperseg=None, pixels=True, scatter=False):
    """Fit a noise model to raw darks: a scene the simulator, the forecast and the readout
    design take as it is.

    Parameters
    ----------
    inputs : path, `~spherex_reduce.Exposure`, or a list or iterator of them
        Raw darks in any layout ``reduce`` reads (`~spherex_reduce.io.sources.open_input`;
        every integration of a 4-D file is a dark).  One readout and one unit.  They
        are read one at a time and released once their spectra are taken (an iterator
        of exposures is held one at a time too).
    config : str, dict or `~spherex_reduce.Pipeline`, optional
        A pipeline config whose ``input:``, ``geometry:`` and ``readout:`` say how to
        read the files (unit, gain, keywords they lack).
    exponent : float or None
        The exponent of the third term of every component (the paper's 1.3);
        None fits it on the light-sensitive pixels' spectrum.
    segments : int, optional
        Split each dark into this many runs of frames, each left out in turn
        by the jackknife (default: 1, each dark whole; one dark alone is split
        into up to 8 runs of 5 frames at least).  Runs of one dark are not
        quite independent: on the round trip their errors came out up to 1.9
        times too small for the correlated terms, so the model says so.
    nbins : int
        Logarithmic frequency bins per spectrum.
    nperseg : int, optional
        Welch segment in row reads (default: a power of two <= reads per frame).
    pixels : bool
        Also fit the per-pixel terms (read noise, dark current, hot and telegraph
        pixels, the first read's offset: `~spherex_reduce.analysis.pixel_terms`),
        summed dark by dark as they are read; the scene holds those the simulator
        takes (``scene:``), and the streams leave out what they hold (each dark's
        pixels with a jump or hot, `~spherex_reduce.analysis.pixel_terms.PixelSums.add`;
        the dark current's shot noise,
        `~spherex_reduce.analysis.characterize.streams.shot_white`), so the model
        holds it once.  Darks it cannot take (ADU without a gain, no unit) are
        marked in one line, the stream model kept (of every pixel).
    scatter : bool
        Also (the command line does; it costs a reduction of each dark per frame
        count) measure the darks' slope scatter against the frame count and their
        reduced P(k) (`~spherex_reduce.analysis.characterize.check.DarkScatter`: each
        dark reduced by the config's pipeline, ``spherex-default`` without one, at
        each frame count of a grid from 2 reads to all) and set them beside what the
        fitted model predicts (`~spherex_reduce.analysis.characterize.predict`) in
        ``check``; what cannot be measured or predicted is marked in one line.

    Returns
    -------
    `~spherex_reduce.analysis.characterize.Characterization`

    Raises
    ------
    SpherexReduceError
        Darks of different readouts or units, not raw ramps, or too few darks
        and reads to see a scatter (one dark of fewer than 10 reads).

    Examples
    --------
    >>> from spherex_reduce.io.examples import example_raw_exposure
    >>> from spherex_reduce.analysis.characterize import characterize
    >>> model = characterize(example_raw_exposure(), segments=2)
    >>> model.ngroups, [c["name"] for c in model.scene()["noise"]["components"]][:1]
    (2, ['channel'])
    """
    pipeline = _pipeline(config)
    gain = None if pipeline is None else pipeline.input_options.gain  # applied as read
    # each dark's streams (a full-size dark's ~160 MB) are reduced to their spectra (a few
    # MB) once the dark is released: the Welch transforms, several times the streams' size,
    # are not made beside the dark, and no dark's streams are held beside the next dark
    darks, spectra, each = [], [], []
    schedule = unit = alone = None
    sums, terms, pixel_mark = None, None, None
    reducer, measured, scatter_mark = None, None, None
    if scatter:
        try:
            reducer = reduction_pipeline(pipeline)
        except SpherexReduceError as exc:
            scatter_mark = str(exc)
    left_out = 0  # pixels left out of the streams (their noise is the per-pixel terms')
    # a dark known to be followed by another (a list of inputs, the integrations of a 4-D
    # file) is not split into its runs of frames: they are needed only for a dark alone
    for label, source, more, last in _darks(inputs, pipeline):
        drop, runs = None, []
        if pixels and pixel_mark is None:  # first: the streams leave out what it holds
            sums, drop, pixel_mark = _add_pixels(sums, source, gain)
            left_out += 0 if drop is None else int(drop.sum())
        readout, of = source.context.schedule, source.context.unit
        if schedule is None:
            schedule, unit = readout, of
            if schedule.nframes < MIN_FRAMES:
                raise SpherexReduceError(
                    f"every term: a dark of {schedule.nframes} reads cannot be characterised "
                    f"(a straight line is removed across at least {MIN_FRAMES} reads)")
            cuts = _segments(schedule.nframes, 1 if segments is None else segments)
            if segments is None and schedule.nframes >= 2 * SEGMENT_FRAMES and not more:
                runs = _segments(schedule.nframes, None)  # its runs, if it stays alone
        elif readout != schedule or of != unit:
            raise SpherexReduceError(f"{label}: another readout or unit ({of}) than the "
                                     f"first dark ({unit}): one model is of one readout")
        else:
            alone = None
        if last and sums is not None and pixel_mark is None:
            # no dark follows: fitted, its sums let go before this dark's reductions
            terms, pixel_mark = _fit_pixels(sums)
            sums = None
        # read band by band of reads: the dark is never whole in memory (a raw file's)
        held = dark_streams(source, cuts + runs, leave_out=drop)
        held, runs = held[:len(cuts)], held[len(cuts):]
        darks.append(label)
        del drop
        if runs:
            alone = ([dark_spectra(st, schedule, nperseg) for st in runs],
                     [st.boxes for st in runs])
        spectra.extend(dark_spectra(st, schedule, nperseg) for st in held)
        each.extend(st.boxes for st in held)
        del runs, held  # the streams (~0.16 GB at full size) before the scatter's reductions
        if reducer is not None and scatter_mark is None:  # reduced band by band of rows
            measured, scatter_mark = _add_scatter(measured, reducer, source)
        del source
    if not darks:
        raise SpherexReduceError("no dark to characterise")
    nframes = schedule.nframes
    split = alone is not None
    if split:  # one dark: the scatter of its runs of frames
        spectra, each = alone
    del alone
    if len(spectra) < 2:
        raise SpherexReduceError(
            f"uncertainties: one dark of {nframes} reads gives no scatter to estimate them "
            f"from; give 2 or more darks, or a dark of >= {2 * SEGMENT_FRAMES} reads")
    boxes = pooled_boxes(each)
    if pixels and pixel_mark is None and terms is None:  # darks of an iterator
        terms, pixel_mark = _fit_pixels(sums)
    sums = None  # its per-pixel sums (~0.55 GB at full size) are fitted: released
    shot = 0.0
    if terms is not None:  # its dark current's shot noise is the per-pixel terms', not the streams'
        shot = _shot(terms, schedule, _segments(nframes, None) if split else cuts)

    def fits(keep):
        return fit_spectra(pool([spectra[i] for i in keep]), pooled_boxes([each[i] for i in keep]),
                           schedule, exponent, nbins, shot=shot)

    every = range(len(spectra))
    full = fits(every)
    jack = [fits([j for j in every if j != i]) for i in every]
    model = Characterization.build(full, jack, boxes, schedule, unit or u.one, darks,
                                   exponent_fitted=exponent is None,
                                   segmented=split or (segments or 1) > 1, gain=gain)
    model.pixel_terms = terms
    _mark_faint_white(model)
    reference = model.reference_white_mark()
    if reference is not None:
        model.marks.append(reference)
    if pixel_mark is not None:
        also = (f"; the streams of the darks before left out their {left_out} pixels with "
                "a jump or hot" if left_out else "")
        model.marks.append(f"per-pixel terms: not fitted: {pixel_mark}{also}")
    if measured is not None and scatter_mark is None:
        try:
            model.check = compare(model, measured.result(), reducer)
        except SpherexReduceError as exc:
            scatter_mark = str(exc)
    if scatter_mark is not None:
        model.marks.append(f"slope scatter and P(k): not compared: {scatter_mark}")
    return model


def _mark_faint_white(model):
    """Say in one line that the scene's channel white level is the pixels' own, not the
    streams', where a faint telegraph population was fitted (`Characterization.faint_white`)."""
    white = model.faint_white()
    channel = model.components.get("channel")
    if white is None or channel is None:
        return
    scene = model.scene()
    comps = scene["noise"]["components"]
    if any(c["name"] == "channel" for c in comps):
        active = (scene.get("scene") or {}).get("active_read_noise", 0.0)
        level = seen_white(comps) + 2.0 * active**2 / model.schedule.geometry.pixel_rate
        model.marks.append(
            f"channel.alpha: the streams' {channel.values[0]:.4g} holds part of the faint "
            f"telegraph population's steps, which scene.rtn holds; the scene takes the pixels' "
            f"white read noise less the components' drift within a row ({np.sqrt(white):.4g} "
            f"{model.unit}): a white level of {level:.4g} on the light-sensitive pixels")


def _fit_pixels(sums):
    """``(terms, mark)``: the per-pixel terms fitted to ``sums``, or the reason they cannot
    be (then ``terms`` None)."""
    try:
        return sums.fit(), None
    except SpherexReduceError as exc:
        return None, str(exc)


def _shot(terms, schedule, cuts):
    """The white level (one sample's, as ``alpha``) that the dark current of the per-pixel
    ``terms`` gives the light-sensitive streams of the runs of frames ``cuts``, the mean over
    them (their spectra are pooled alike), in the fraction of the row reads that read
    light-sensitive pixels."""
    row = terms.row("dark_current", "active")
    if row["status"] != "fitted" or not row["value"] > 0:
        return 0.0
    rate = row["value"] / terms.gain  # unit^2 / s
    starts = schedule.frame_starts.to_value(u.s)
    white = np.mean([shot_white(rate, starts[cut], schedule.geometry.pixel_rate)
                     for cut in cuts])
    return float(white * np.mean(~schedule.is_reference))


def _add_scatter(measured, reducer, source):
    """``(measured, mark)``: the slope scatter with the dark of ``source`` added, or the
    reason it cannot be (then ``measured`` None)."""
    try:
        if measured is None:
            measured = DarkScatter(reducer, source.context.schedule.nframes)
        measured.add(source)
    except SpherexReduceError as exc:
        return None, str(exc)
    return measured, None


def check_model(model, darks, config=None, frames=None, measure=None):
    """A fitted model against held-out darks: measured and predicted, side by side.

    Parameters
    ----------
    model : `~spherex_reduce.analysis.characterize.Characterization`
        Fitted on other darks of the same readout.
    darks : path, `~spherex_reduce.Exposure`, or a list or iterator of them
        The held-out raw darks, read as `characterize` reads them (2 or more: the
        differences of pairs are measured, as the paper does).
    config : str, dict or `~spherex_reduce.Pipeline`, optional
        How to read and reduce them (default: ``spherex-default``, the paper's).
    frames : sequence of int, optional
        Frame counts (default: 2 to all,
        `~spherex_reduce.analysis.characterize.predict.frame_grid`).
    measure : dict, optional
        ``bins``, ``kmin``, ``kmax`` (rad/pixel) of the P(k) and band power.

    Returns
    -------
    `~astropy.table.Table`
        `~spherex_reduce.analysis.characterize.check.compare`'s: the slope scatter at
        each frame count, the band power and P(k), measured and predicted.

    Raises
    ------
    SpherexReduceError
        No dark, darks of another readout than the model's, or what the pipeline or
        the forecast cannot take.

    Examples
    --------
    >>> from spherex_reduce.io.examples import example_raw_exposure
    >>> from spherex_reduce.analysis.characterize import characterize, check_model
    >>> model = characterize(example_raw_exposure(), segments=2)
    >>> t = check_model(model, [example_raw_exposure(seed=2), example_raw_exposure(seed=3)],
    ...                 measure={"kmin": 0.2, "kmax": 1.0, "bins": 4})
    >>> t.meta["pairs"], sorted(set(t["quantity"].tolist()))
    (1, ['band_power', 'power_spectrum', 'slope_scatter'])
    """
    reader = _pipeline(config)
    reducer = reduction_pipeline(reader)
    acc = None
    fitted = {d for d in model.darks if not d.startswith("exposure in memory")}  # files
    for label, source in dark_sources(darks, reader):  # reduced band by band of rows
        schedule, unit = source.context.schedule, source.context.unit
        if schedule != model.schedule:
            raise SpherexReduceError(f"{label}: another readout than the model's darks")
        if (unit or u.one) != model.unit:
            raise SpherexReduceError(f"{label}: in {unit}, the model's darks in "
                                     f"{model.unit}: give both in one unit (input: gain)")
        if label in fitted:
            raise SpherexReduceError(f"{label}: a dark the model was fitted to; the check "
                                     "is on held-out darks")
        if acc is None:
            acc = DarkScatter(reducer, schedule.nframes, frames, measure)
        acc.add(source)
        del source
    if acc is None:
        raise SpherexReduceError("check: no dark given")
    return compare(model, acc.result(), reducer)


def _add_pixels(sums, source, gain):
    """``(sums, leave_out, mark)``: the per-pixel sums with the dark of ``source`` added (its
    rows in physical order, a band of rows at a time: the dark is not held whole) and the
    pixels whose noise they hold (`~spherex_reduce.analysis.pixel_terms.PixelSums.add`), or
    the reason they cannot be (then ``sums`` and ``leave_out`` None)."""
    ctx = source.context
    s = ctx.schedule
    try:
        rows = pixel_rows(s, ctx.ramp, ctx.order)
        rows = np.arange(source.nrows) if rows is None else rows  # physical: as stored
        if sums is None:
            sums = PixelSums(s.frame_starts.to(u.s), reference=s.geometry.reference_pixel_mask(),
                             gain=None if ctx.unit != u.adu else gain,
                             labels=common_labels(s.geometry))
        drop = sums.add_rows(source.take, (s.nframes, source.nrows, s.geometry.ncols),
                             ctx.unit, rows)
    except SpherexReduceError as exc:
        return None, None, str(exc)
    return sums, drop, None
