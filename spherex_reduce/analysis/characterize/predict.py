"""What a fitted model predicts for the darks' slope images: their scatter against N and P(k).

The paper's Fig. 12a shows the standard deviation over pixels of the
reference-corrected slope image against the frame count ``N``, after an
iterative 5 σ clip, of the difference of two darks divided by √2 (the
difference removes each pixel's fixed dark-current offset).  `predict_scatter`
predicts that statistic from a `~spherex_reduce.analysis.characterize.Characterization`:

- **the streams** (every noise component, through the same pipeline):
  `~spherex_reduce.analysis.forecast.engine.stored_planes` of the model's
  scene read with the first ``N`` frames, summed over the Fourier plane less
  its ``k = 0`` cell (the image mean, which a standard deviation over pixels
  takes out), plus the Poisson noise of the dark current
  (`~spherex_reduce.analysis.forecast.engine.poisson_variance`, darks in
  electrons only).  The white level is the fit's ``white_read_noise`` where
  it has one (see below), else the per-pixel read-noise map's mean
  variance (measured on each pixel's differences with its jumps left out)
  less what the fitted correlated terms add to a read's variance there (half
  their structure function at one frame); not the streams': a telegraph
  pixel's steps stay in a stream once its line over the frames is removed and
  raise the streams' white level (12 % in variance in
  ``benchmarks/bench_characterize_heldout.py``), though in a pixel they are
  not white; the difference goes to the ``channel`` component's white term,
  or, where the model's reference pixels read quieter
  (``scene.active_read_noise``), the components keep the reference pixels'
  level and the light-sensitive pixels' own read noise is the rest.
  The map's spread adds nothing to the mean and is not modelled in the clip;
- **the telegraph pixels** found by the fit (fraction ``f``, mean amplitude
  and its spread, rate ``r`` of the light-sensitive population): a pixel
  switching between 0 and ``A`` at rate ``r`` per state has the
  autocovariance ``A²/4 exp(-2 r |Δt|)`` (the simulator's definition,
  `~spherex_reduce.simulation.telegraph`), so its least-squares slope has the
  exact variance ``E[A²]/4 Σ_jk w_j w_k exp(-2 r |t_j - t_k|)``
  (`telegraph_slope_variance`);
- **the faint telegraph pixels** (steps too close to the jumps' threshold to
  be found one by one, fitted as a population: `faint_population`): their own
  chains with their fraction, step and rate (or, without the split, their
  power times the same variance added to the core as Gaussian).  The white
  level is then the ``white_read_noise`` of the fit (the pixels' structure
  function with the drift common to the pixels read together and the faint
  telegraph taken out), which holds neither the telegraph nor that common
  drift, but does hold what the drift does about the group's mean within the
  row: that is taken out (`~spherex_reduce.analysis.characterize.result.group_drift`);
- **the clip**: a telegraph pixel that switched during the ramp can lie
  beyond 5 σ of a dark's image (the pipeline's ``sigma_clip`` step masks it
  in that dark: `predict_scatter`'s ``image_clip``) or of the difference, and
  its slope is far from Gaussian, so the clipped statistic is predicted from
  the population itself: the pixels are a mixture of the Gaussian core (the
  streams) and telegraph pixels whose slope is the core plus a telegraph
  slope drawn from the two-state chain (a fixed number of chains, drawn with
  a fixed seed and scaled to the exact variance above), each dark's image is
  clipped at the fixed point of its own mixture (a telegraph pixel kept with
  the chance its Gaussian spread leaves it within), and the clipped standard
  deviation of the difference is the fixed point of the clip applied to what
  is kept (`clipped_sigma`).  Hot pixels are left out: their fixed
  current puts them far beyond the clip of one dark's image (the pipeline's
  ``sigma_clip`` step), which is where the measurement leaves them out too
  (a pipeline without that step keeps them in the measurement, where the
  clip of the difference takes out only the brightest).
  With one dark (no difference) each pixel's dark current is fixed, so the
  fitted spread of the currents is added to the core.

`predict_spectrum` is `~spherex_reduce.analysis.forecast.forecast` of the same
scene at the darks' readout, plus the telegraph pixels' clipped variance as
white power (each pixel switches on its own).
"""

import numpy as np
from astropy import units as u
from scipy.special import ndtr

from ...core.errors import SpherexReduceError
from ...noise.components import NoiseComponent
from ...noise.variance import ls_weights
from ..faint_telegraph import telegraph_covariance
from ..forecast.engine import (
    active_white_variance,
    forecast,
    poisson_variance,
    prepare_forecast,
    stored_planes,
)
from ..forecast.populations import clipped_sigma
from ..spectrum import rfft_weights
from .result import group_drift, hold_white, seen_white

__all__ = ["CLIP_SIGMA", "clipped_sigma", "faint_population", "frame_grid", "predict_scatter",
           "predict_spectrum", "telegraph_population", "telegraph_slope_variance"]

#: The clip of the slope scatter, in standard deviations (the paper's 5).
CLIP_SIGMA = 5.0
#: Telegraph chains drawn to predict the clip (fixed seed: the prediction is deterministic).
TELEGRAPH_CHAINS = 20000
#: Points of the frame-count grid from 2 reads to all (`frame_grid`).
GRID_POINTS = 10


def frame_grid(nframes, points=GRID_POINTS):
    """Frame counts from 2 to ``nframes``, spaced evenly in log (distinct integers).

    Examples
    --------
    >>> from spherex_reduce.analysis.characterize.predict import frame_grid
    >>> frame_grid(74, 6)
    [2, 4, 8, 17, 36, 74]
    """
    if nframes < 2:
        raise SpherexReduceError(f"slope scatter: a dark of {nframes} reads has no slope")
    grid = np.unique(np.rint(np.geomspace(2, nframes, max(2, int(points)))).astype(int))
    return [int(n) for n in grid]


def telegraph_slope_variance(times, rate):
    """Variance of the least-squares slope of a two-state telegraph of unit step.

    Parameters
    ----------
    times : array_like
        Read times (s).
    rate : float
        Switching rate of each state (Hz); ``inf``: a new coin toss at every read.

    Returns
    -------
    float
        ``1/4 Σ_jk w_j w_k exp(-2 rate |t_j - t_k|)`` in 1/s² (times the step²
        for a step ``A``): the telegraph's autocovariance is ``A²/4 exp(-2 rate
        |Δt|)``, and ``w`` the uniform least-squares weights
        (`~spherex_reduce.noise.variance.ls_weights`).

    Examples
    --------
    A telegraph faster than the reads is white noise of variance 1/4:

    >>> import numpy as np
    >>> from spherex_reduce.analysis.characterize.predict import telegraph_slope_variance
    >>> t = np.arange(10) * 1.5
    >>> w = t - t.mean()
    >>> bool(np.isclose(telegraph_slope_variance(t, np.inf), 0.25 / np.sum(w**2)))
    True
    """
    t = np.asarray(times, dtype=np.float64)
    w = ls_weights(t)
    return float(w @ telegraph_covariance(t, rate) @ w)


def telegraph_population(model):
    """The light-sensitive telegraph pixels the fit found: ``(fraction, amplitude mean,
    amplitude spread, rate)`` in the darks' unit and Hz, or None (with the reason) when
    the model has none it can predict from."""
    pt = model.pixel_terms
    if pt is None:
        return None, "the per-pixel terms were not fitted"
    try:
        rows = {k: pt.row(f"telegraph_{k}", "active")
                for k in ("fraction", "amplitude", "amplitude_spread", "rate")}
    except KeyError as exc:
        return None, str(exc)
    if rows["fraction"]["status"] != "fitted":
        return None, f"no telegraph light-sensitive pixels ({rows['fraction']['note']})"
    for k in ("amplitude", "rate"):
        if rows[k]["status"] != "fitted":
            return None, f"telegraph {k} not fitted ({rows[k]['note']})"
    spread = rows["amplitude_spread"]
    return (rows["fraction"]["value"], rows["amplitude"]["value"],
            spread["value"] if spread["status"] == "fitted" else 0.0,
            rows["rate"]["value"]), ""


def faint_population(model):
    """The faint telegraph pixels the fit found as a population
    (`~spherex_reduce.analysis.faint_telegraph`): ``(power, rate, white, fraction,
    step)`` (the pixels' mean squared step, Hz, what it adds to the mean read-noise
    variance, and its split, NaN where not fitted), or None."""
    pt = model.pixel_terms
    try:
        rows = [pt.row(f"faint_telegraph_{k}", "active")
                for k in ("power", "rate", "white", "fraction", "amplitude")]
    except (KeyError, AttributeError):
        return None
    if any(r["status"] != "fitted" for r in rows[:3]):
        return None
    return tuple(float(r["value"]) if r["status"] == "fitted" else np.nan for r in rows)


def _chains(times, rate, n, rng):
    """``(n, nreads)`` states (0 or 1) of a symmetric two-state telegraph read at ``times``."""
    p = -np.expm1(-2.0 * rate * np.diff(times)) / 2.0
    flips = rng.random((n, len(times) - 1)) < p
    start = rng.random((n, 1)) < 0.5
    return np.concatenate([start, start ^ np.logical_xor.accumulate(flips, axis=1)], axis=1)


def _telegraph_slopes(times, population, n=TELEGRAPH_CHAINS, seed=0):
    """Draws ``(2, n)`` of a telegraph pixel's slope in two darks (its amplitude,
    independent states), scaled so their mean square is the exact variance
    (`telegraph_slope_variance`)."""
    _, mean, spread, rate = population
    rng = np.random.default_rng(seed)
    w = ls_weights(times)
    amp = np.abs(rng.normal(mean, spread, n)) if spread > 0 else np.full(n, mean)
    y = np.array([amp * (_chains(times, rate, n, rng) @ w) for _ in range(2)])
    exact = (mean**2 + spread**2) * telegraph_slope_variance(times, rate)
    ms = np.mean(y * y)
    return y * np.sqrt(exact / ms) if ms > 0 else y


def _kept(y, variance, cut):
    """Chance that a value ``N(y, variance)`` is within ``±cut`` (1 without a cut)."""
    if cut is None:
        return np.ones_like(y)
    s = np.sqrt(variance)
    return ndtr((cut - y) / s) - ndtr((-cut - y) / s)


def _scene(model, nframes, single):
    """The model's scene read with its first ``nframes`` frames, in slopes mode, with the
    terms the forecast takes (the dark current and its Poisson noise, the light-sensitive
    pixels' own white read noise)."""
    sc = model.scene()
    readout = dict(sc["readout"])
    readout["nframes"] = int(nframes)
    if readout.get("read_times") is not None:
        readout["read_times"] = list(readout["read_times"])[:nframes]
    if readout.get("groups") is not None or readout.get("frames_per_group", 1) != 1:
        raise SpherexReduceError("slope scatter: grouped readouts are not predicted "
                                 "(reads averaged in groups)")
    white = _read_noise_white(model)
    own = _read_noise_white(model, "white_read_noise")
    terms = sc.pop("scene", {}) or {}
    # the light-sensitive pixels' own white read noise, which the reference pixels do not
    # see: where the model has it, the components hold the reference pixels' white level
    active = float(terms.get("active_read_noise", 0.0))
    if white is not None:
        g, s = model.schedule.geometry, model.schedule
        comps = sc["noise"]["components"]
        if own is not None:  # the fit's white read noise holds the drift about the mean
            # of the pixels read together (`group_drift`), which the components hold too
            light = own - group_drift(comps, s)
        else:  # the map's variance of a read holds half the structure function at one
            # frame of the correlated terms (a pixel's differences are a frame apart)
            light = white - sum(
                0.5 * float(NoiseComponent(c["name"], beta=c["beta"], gamma=c["gamma"],
                                           exponent=c["exponent"])
                            .structure_function(s.frame_samples, g.pixel_rate))
                for c in comps if c.get("visibility", "pixels") in ("pixels", "both"))
        level = seen_white(comps) * g.pixel_rate / 2
        if active and light > level:  # the reference pixels' level stays; the rest is theirs
            active = float(np.sqrt(light - level))
        else:
            active = 0.0
            hold_white(comps, light, s)
    kept = {"dark_current": float(terms.get("dark_current", 0.0)),
            "poisson": model.unit == u.electron}
    if active:
        kept["active_read_noise"] = active
    sc.update(readout=readout, output={"mode": "slopes"}, scene=kept)
    spread = 0.0
    if single and model.pixel_terms is not None:
        row = model.pixel_terms.row("dark_current_spread", "active")
        spread = row["value"] if row["status"] == "fitted" else 0.0
    return sc, spread


def _read_noise_white(model, term="read_noise"):
    """The light-sensitive pixels' mean read-noise variance per read (the darks' unit
    squared; ``term``: that of the read-noise map, or ``white_read_noise``, its white
    part), or None without it."""
    if model.pixel_terms is None:
        return None
    try:
        row = model.pixel_terms.row(term, "active")
    except KeyError:
        return None
    return row["value"] ** 2 if row["status"] == "fitted" else None


def _stream_variance(scene, pipeline):
    """The mean over pixels of the squared deviation from the image mean, of the reduced
    slope image of ``scene`` (the forecast's plane less its ``k = 0`` cell), plus Poisson."""
    prepared = prepare_forecast(scene, pipeline)
    planes, (ny, nx) = stored_planes(*prepared, summed=True)
    total = planes["total"] if planes else np.zeros((ny, nx // 2 + 1))
    w = np.broadcast_to(rfft_weights(nx), total.shape)
    var = (float(np.sum(total * w)) - float(total[0, 0])) / (ny * nx) ** 2
    return var + poisson_variance(prepared[0]) + active_white_variance(prepared[0])


def predict_scatter(model, pipeline, frames, *, differenced=True, sigma=CLIP_SIGMA,
                    image_clip=None):
    """The slope scatter over pixels against the frame count that ``model`` predicts.

    Parameters
    ----------
    model : `~spherex_reduce.analysis.characterize.Characterization`
    pipeline : `~spherex_reduce.Pipeline`, shipped name or dict
        The reduction (its steps linear: `~spherex_reduce.analysis.forecast.forecast`).
    frames : sequence of int
        Frame counts ``N`` (the first ``N`` reads of the darks' readout).
    differenced : bool
        The statistic of the difference of two darks over √2 (True), or of one dark
        (False: each pixel's fixed dark current stays, its fitted spread is added).
    sigma : float or None
        The iterative clip (None: none).
    image_clip : float or None
        The pipeline's own iterative clip of each dark's image (its ``sigma_clip``
        step), before the difference: a telegraph pixel it masks in either dark is
        not in the statistic.

    Returns
    -------
    dict
        ``frames``; ``sigma`` (predicted, with the telegraph pixels), ``sigma_streams``
        (without them: the streams and the dark current only), ``telegraph_variance``
        (the telegraph slope variance per pixel: each population's fraction times its
        exact variance, 0 without any) and
        ``telegraph_excess`` (the clipped variance they add: white over ``k``), each
        an array in the slope unit (the darks' unit per second); ``telegraph`` the
        population used or None, ``note`` why none; ``faint`` the faint
        population's ``(power, rate, white)`` or None (`faint_population`).

    Examples
    --------
    >>> from spherex_reduce.io.examples import example_raw_exposure
    >>> from spherex_reduce.analysis.characterize import characterize
    >>> from spherex_reduce.analysis.characterize.predict import predict_scatter
    >>> model = characterize(example_raw_exposure(), segments=2)
    >>> p = predict_scatter(model, "spherex-default", [2, 6])
    >>> bool((p["sigma"][0] > p["sigma"][1] > 0))
    True
    """
    population, note = telegraph_population(model)
    faint = faint_population(model)
    out = {k: [] for k in ("sigma", "sigma_streams", "telegraph_variance",
                           "telegraph_excess")}
    for n in frames:  # one at a time: two forecasts at once went over 2 GB at full size
        sc, spread = _scene(model, n, not differenced)
        v0 = _stream_variance(sc, pipeline) + spread**2
        core = clipped_sigma([1.0], [0.0], v0, sigma)
        out["sigma_streams"].append(core)
        times = model.schedule.frame_starts.to_value(u.s)[:n]
        pops = [] if population is None else [population]
        extra = 0.0
        if faint is not None and np.isfinite(faint[3]):  # its own population of chains
            pops.append((faint[3], faint[4], 0.0, faint[1]))
        elif faint is not None:  # no split: its variance, spread over the core
            extra = faint[0] * telegraph_slope_variance(times, faint[1])
        if (not pops and faint is None) or v0 <= 0:
            out["sigma"].append(core)
            out["telegraph_variance"].append(0.0)
            out["telegraph_excess"].append(0.0)
            continue
        weights, ya, yb, var = [1.0], [0.0], [0.0], 0.0
        for i, pop in enumerate(pops):
            f = min(max(pop[0], 0.0), 1.0)
            y = _telegraph_slopes(times, pop, seed=i)
            weights = np.concatenate([weights, np.full(y.shape[1], f / y.shape[1])])
            weights[0] -= f
            ya, yb = np.concatenate([ya, y[0]]), np.concatenate([yb, y[1]])
            var += f * float(np.mean(y * y))
        weights = weights / np.sum(weights)
        # each dark's image clipped first (its telegraph pixels far out are masked)
        cut = (None if image_clip is None else
               image_clip * clipped_sigma(weights, ya, v0 + extra, image_clip))
        keep = _kept(ya, v0 + extra, cut)
        if differenced:
            keep = keep * _kept(yb, v0 + extra, cut)
            means = (ya - yb) / np.sqrt(2.0)
        else:
            means = ya
        full = clipped_sigma(weights * keep / np.sum(weights * keep), means, v0 + extra,
                             sigma)
        out["sigma"].append(full)
        out["telegraph_variance"].append(var)
        out["telegraph_excess"].append(full**2 - core**2)
    result = {k: np.asarray(v) for k, v in out.items()}
    result.update(frames=np.asarray(frames, dtype=int), telegraph=population, note=note,
                  faint=faint)
    return result


def predict_spectrum(model, pipeline, measure=None, excess=0.0):
    """`~spherex_reduce.analysis.forecast.forecast` of the model's scene (the dark current
    and the streams) at the darks' readout, plus ``excess`` (the telegraph pixels' clipped
    variance: `predict_scatter`'s ``telegraph_excess`` at every frame) as white power,
    in ``power`` and ``meta['band_power']``; ``power_streams`` keeps the forecast alone.

    Examples
    --------
    >>> from spherex_reduce.io.examples import example_raw_exposure
    >>> from spherex_reduce.analysis.characterize import characterize
    >>> from spherex_reduce.analysis.characterize.predict import predict_spectrum
    >>> model = characterize(example_raw_exposure(), segments=2)
    >>> t = predict_spectrum(model, "spherex-default", {"kmin": 0.2, "kmax": 1.0, "bins": 4})
    >>> bool(t.meta["band_power"] > 0), len(t)
    (True, 4)
    """
    sc, _ = _scene(model, model.schedule.nframes, False)
    table = forecast(sc, pipeline, measure)
    table["power_streams"] = table["power"].copy()
    extra = float(excess) * table["power"].unit
    table["power"] = table["power"] + extra
    table.meta["band_power"] = float(table.meta["band_power"] + excess)
    table.meta["telegraph_white"] = float(excess)
    return table
