"""The expected power spectrum of a reduced slope image, computed without random numbers.

The slope image of the simulator's slopes route is a Gaussian field whose
covariance is known in closed form: a pixel's slope is ``sum_k w_k x(t + k F)``
of the stream ``x`` of each noise component, so two samples taken ``L``
samples apart within a frame have the slope covariance ``S(L)``
(`~spherex_reduce.noise.variance.slope_covariance`).  Every reduction the
forecast propagates (the steps whose class declares its noise effect,
`~spherex_reduce.analysis.forecast.steps.forecast_steps`: un-chopping,
phantom subtraction, reference correction by the mean of the reference
pixels or a ``wiener`` drift estimate, uniform least-squares slopes, pair
differences) is linear and subtracts from a pixel combinations of
samples of the same streams, so ``E|FFT|²`` of the reduced image is a sum over
pairs of reads of ``S`` at their lags, weighted by the phases of the pixels
and samples involved: `spherex_reduce.analysis.forecast.rows` computes it with
FFTs over read slots and offsets, exactly near the singularities of ``S`` and
with a Chebyshev rule over offsets elsewhere (off by < 1e-7 per bin in the
paper's full-size case, < 1e-5 in the 16 x 16 scenes of the tests, which hold
it to 1e-3 per bin and 1e-4 in band power against a brute-force covariance
of every pixel, phantom sample and reference pixel).  Every cell of the
Fourier plane is then binned by the spectrum's own binning, so the forecast
has the bins, normalisation and columns of
`~spherex_reduce.analysis.power_spectrum` measured on the light-sensitive
pixels (`~spherex_reduce.analysis.light`).
"""

import functools

import numpy as np
from astropy import units as u

from ...core.errors import ConfigError, SpherexReduceError
from ...noise.variance import slope_frames
from ...simulation.scene import Scene, load_scene
from ..case import SpectrumMeasure, measure_section
from ..light import light_sensitive
from ..spectrum import (
    BAND_KMAX,
    BAND_KMIN,
    SPHEREX_PIXEL_SCALE,
    k_bin_edges,
    k_grid,
    rfft_weights,
    spectrum_table,
)
from .layout import frame_cells, transposed
from .populations import POPULATIONS, clipped_populations, population_variances, shot_factor
from .rows import NODES, Cells, component_planes
from .steps import reduction

__all__ = ["active_white_variance", "add_white_parts", "band_power_forecast", "forecast",
           "forecast_measure", "forecast_tables",
           "poisson_variance", "prepare_forecast", "stored_planes"]

_SLOPE_UNIT = u.electron / u.s
#: Name of the Poisson noise of the dark current and photocurrent in the table's columns.
_POISSON = "poisson"
#: Name of the light-sensitive pixels' own white read noise (``scene.active_read_noise``).
_ACTIVE = "active_white"
#: Name of what the mask of a clip moves between scales (`populations`).
_MASKED = "masked"
#: The table's columns of the forecast's own parts, after the components', in order.
_OWN_PARTS = (_POISSON, _ACTIVE, *POPULATIONS, _MASKED)


def forecast(scene, pipeline=None, measure=None, *, pixel_scale=SPHEREX_PIXEL_SCALE,
             nodes=NODES):
    """Expected power spectrum ``P(k)`` of a scene's reduced slope image.

    What ``SpectrumMeasure(**measure)`` measures on average, over realisations
    of ``simulate(scene, mode="slopes")`` reduced by ``pipeline``, on the
    light-sensitive pixels of the stored image in physical row order
    (`~spherex_reduce.analysis.light.light_sensitive_image`).  No random
    numbers.

    Parameters
    ----------
    scene : `~spherex_reduce.simulation.Scene`, dict, YAML text or path
        The scene (`~spherex_reduce.simulation.load_scene`); its channels as
        columns or rows of the array (``channels: rows``: the stored image is
        the readout frame's transpose, and so is its spectrum's plane), without
        windows.
    pipeline : `~spherex_reduce.Pipeline`, shipped name, path or dict, optional
        The reduction (`~spherex_reduce.reduce.pipeline.as_pipeline`); None:
        the slope image as simulated.  Every step must be one the forecast
        knows as linear (its class declares so:
        `~spherex_reduce.analysis.forecast.steps.forecast_steps`): ``unchop``,
        ``subtract_phantom``, ``correct_reference`` with the ``mean``, ``acn``
        (forecast unclipped, with or without side columns) or ``wiener``
        strategy, ``fit_ramp`` with uniform weights, ``sigma_clip`` (forecast
        as no clipping of Gaussian noise; the pixel populations it masks
        through it) and ``pair_difference`` (the identity; a detector's fixed
        pattern cancels); the shipped
        pipelines but ``median`` are.
    measure : `~spherex_reduce.analysis.case.SpectrumMeasure` or dict, optional
        ``kmin``, ``kmax`` (the band of ``band_power``, rad/pixel), ``bins`` and
        ``exclude_horizontal``, as a sweep's ``measure:`` (default: the
        paper's band, 30 bins); ``mask_sources`` is refused (not linear).
    pixel_scale : `~astropy.units.Quantity`
        As `~spherex_reduce.analysis.power_spectrum`.
    nodes : int
        Chebyshev nodes of the rule over column offsets (see the module notes).

    Returns
    -------
    `~astropy.table.Table`
        The columns of `~spherex_reduce.analysis.power_spectrum`: ``power`` is
        the expected ``P(k)`` in (e/s)² pix², ``power_err`` the standard error
        one realisation's bin would have; then ``power_<name>`` for every noise
        component (zero for one the reduced pixels do not see: a component only
        the phantom samples see is seen once phantom values are subtracted) and ``power_poisson``
        for the Poisson noise of the scene's dark current and photocurrent
        (white, `poisson_variance`), if any; ``power_active_white`` for the
        light-sensitive pixels' own white read noise (`active_white_variance`), if
        any; ``power_dark_spread``,
        ``power_hot_pixels``, ``power_telegraph`` for the scene's pixel populations
        and ``power_masked`` for what a clip's mask of them moves between scales
        (`~spherex_reduce.analysis.forecast.populations`), if any.  ``meta`` as
        `~spherex_reduce.analysis.power_spectrum`'s, with ``band_power`` (the
        paper's band, e/s squared), ``band_power_err`` (the standard error of
        one realisation's band power as `~spherex_reduce.analysis.band_power`
        computes it, from the expected ``P`` instead of the measured
        ``|FFT|²``), ``variance`` (the mean of ``P`` over the
        whole plane: the pixel variance) and ``forecast`` (what was forecast).

    Raises
    ------
    SpherexReduceError
        Channels as quadrants, a window, or reference pixels inside the
        light-sensitive rectangle.
    ConfigError
        A scene that has no slope image (fewer than 2 frames, or groups); a
        pipeline step the forecast does not know (the message names it) or a
        measure that is not linear (``mask_sources``); a clip of the pixel
        populations it cannot follow
        (`~spherex_reduce.analysis.forecast.populations`).
    ResourceError
        A forecast whose arrays this machine cannot hold (estimated before any
        is allocated).

    Warns
    -----
    AstropyUserWarning
        Telegraph noise of reference pixels under a reference correction: left out.

    Examples
    --------
    >>> from spherex_reduce.analysis import forecast
    >>> scene = {"geometry": {"nrows": 64, "ncols": 64, "nchannels": 4, "ref_border": 4},
    ...          "readout": {"nframes": 8, "phantom_reads": 0},
    ...          "noise": {"components": [{"name": "w", "alpha": 2e-3}]}}
    >>> t = forecast(scene, measure={"bins": 4})
    >>> [round(float(p), 1) for p in t["power"].value]   # white: flat, the pixel variance
    [1861.9, 1861.9, 1861.9, 1861.9]
    >>> round(t.meta["variance"], 1)
    1861.9
    """
    return forecast_tables(scene, pipeline, [measure], pixel_scale=pixel_scale,
                           nodes=nodes)[0]


def forecast_tables(scene, pipeline, measures, *, pixel_scale=SPHEREX_PIXEL_SCALE,
                    nodes=NODES):
    """`forecast` of one scene and pipeline for several measures, its planes computed once.

    Parameters
    ----------
    scene, pipeline, pixel_scale, nodes
        As `forecast`.
    measures : sequence of `~spherex_reduce.analysis.case.SpectrumMeasure`, dict or None
        Each as `forecast`'s ``measure``.

    Returns
    -------
    list of `~astropy.table.Table`
        ``forecast(scene, pipeline, m)`` for every ``m`` of ``measures``, in order.

    Examples
    --------
    >>> from spherex_reduce.analysis.forecast.engine import forecast, forecast_tables
    >>> scene = {"geometry": {"nrows": 64, "ncols": 64, "nchannels": 4, "ref_border": 4},
    ...          "readout": {"nframes": 8, "phantom_reads": 0}}
    >>> t4, t1 = forecast_tables(scene, None, [{"bins": 4}, {"bins": 1}])
    >>> len(t4), len(t1), bool((t1["power"] == forecast(scene, None, {"bins": 1})["power"]).all())
    (4, 1, True)
    """
    ms = [forecast_measure(m) for m in measures]
    return _tables(prepare_forecast(scene, pipeline), ms, pixel_scale, nodes)


def _tables(prepared, measures, pixel_scale, nodes):
    """The tables of `forecast_tables` from `prepare_forecast`'s ``prepared``."""
    sc, red, rows, cols, comps = prepared
    parts, (ny, nx) = stored_planes(sc, red, rows, cols, comps, nodes)
    add_white_parts(sc, red, parts, (ny, nx))
    return [_forecast_table(sc, red, parts, (ny, nx), m, pixel_scale) for m in measures]


def add_white_parts(sc, red, parts, shape):
    """Add to the planes ``parts`` (name -> ``E|FFT|²`` on the rfft2 grid of ``shape``)
    the white parts: the Poisson noise of the currents (`poisson_variance`), the
    light-sensitive pixels' own read noise (`active_white_variance`), the pixel
    populations (`~spherex_reduce.analysis.forecast.populations.population_variances`,
    with the clip of ``red``) and what the clip's mask moves between scales."""
    ny, nx = shape
    for name, var in ((_POISSON, poisson_variance(sc)), (_ACTIVE, active_white_variance(sc))):
        if var:  # white: the same in every cell
            parts[name] = np.full((ny, nx // 2 + 1), var * ny * nx)
    full = np.broadcast_to(rfft_weights(nx), (ny, nx // 2 + 1))
    variance = sum(float(np.sum(p * full)) for p in parts.values()) / (ny * nx) ** 2
    pops, unmasked = population_variances(sc, red, variance)
    for name, var in pops.items():
        parts[name] = np.full((ny, nx // 2 + 1), var * ny * nx)  # white as well
    if unmasked < 1:  # the clip's mask spreads (1 - u) of the variance over every scale
        total = sum(parts.values())
        variance = float(np.sum(total * full)) / (ny * nx) ** 2
        parts[_MASKED] = (1.0 - unmasked) * (variance * ny * nx - total)


def _forecast_table(sc, red, parts, shape, m, pixel_scale):
    """The table of `forecast` for measure ``m`` from the stored planes ``parts``."""
    ny, nx = shape
    unit = _SLOPE_UNIT**2
    shape = (ny, nx)
    edges = k_bin_edges(m.bins, ny, nx)
    exclude_horizontal = bool(m.exclude_horizontal)
    total = sum(parts.values()) if parts else np.zeros((ny, nx // 2 + 1))
    table = spectrum_table(total, shape, edges, unit, 1.0, pixel_scale, exclude_horizontal)
    names = [c.name for c in sc.components] + [k for k in _OWN_PARTS if k in parts]
    for name in names:
        if name in parts:
            power = spectrum_table(parts[name], shape, edges, unit, 1.0, pixel_scale,
                                   exclude_horizontal)["power"]
        else:
            power = np.zeros(len(table)) * table["power"].unit
        table[f"power_{name}"] = u.Quantity(power)
        table[f"power_{name}"].description = f"expected P(k) of {name}"
    band = spectrum_table(total, shape, np.array([m.kmin, m.kmax]), unit, 1.0,
                          pixel_scale, exclude_horizontal)
    full = np.broadcast_to(rfft_weights(nx), (ny, nx // 2 + 1))
    table.meta.update({
        "forecast": ("expected P(k) of the slope image, "
                     + (f"reduced by {red.describe()}" if red.steps else "no reduction")),
        "pipeline": red.describe(),
        "band_kmin": float(m.kmin), "band_kmax": float(m.kmax),
        "band_power": float(u.Quantity(band["power"])[0].value) if len(band) else None,
        "band_power_err": (float(u.Quantity(band["power_err"])[0].value) if len(band)
                           else None),
        "variance": float(np.sum(total * full) / (ny * nx) ** 2),
    })
    return table


def band_power_forecast(scene, pipeline=None, kmin=BAND_KMIN, kmax=BAND_KMAX, *,
                        exclude_horizontal=False, nodes=NODES):
    """Expected band power of a scene's reduced slope image, from the band's cells only.

    The ``band_power`` of `forecast` (same scene, pipeline and band) without
    the cells of the Fourier plane outside the band: only the ``k_y`` rows and
    ``k_x`` columns that reach into ``kmin <= |k| <= kmax`` are computed, so a
    search over readouts can call it many times.

    Parameters
    ----------
    scene, pipeline
        As `forecast`.
    kmin, kmax : float
        The band, rad/pixel (default: the paper's θ = 5–20′).
    exclude_horizontal : bool
        As `~spherex_reduce.analysis.power_spectrum`.
    nodes : int
        As `forecast`.

    Returns
    -------
    float
        The expected band power, (e/s)² pix² (the unit of ``P(k)``).

    Raises
    ------
    SpherexReduceError, ConfigError
        As `forecast`; `~spherex_reduce.core.errors.SpherexReduceError` also when
        the band holds no Fourier mode of the image.

    Examples
    --------
    >>> from spherex_reduce.analysis import forecast
    >>> from spherex_reduce.analysis.forecast.engine import band_power_forecast
    >>> scene = {"geometry": {"nrows": 64, "ncols": 64, "nchannels": 4, "ref_border": 4},
    ...          "readout": {"skip": 4, "ref_reads": 8, "nframes": 8, "phantom_reads": 2}}
    >>> band = band_power_forecast(scene, "spherex-default", 0.2, 1.0)
    >>> full = forecast(scene, "spherex-default", {"kmin": 0.2, "kmax": 1.0}).meta["band_power"]
    >>> abs(band / full - 1) < 1e-12
    True
    """
    prepared = sc, red, rows, cols, comps = prepare_forecast(scene, pipeline)
    if red.clip is not None and clipped_populations(sc.terms):  # the whole plane's variance
        measure = forecast_measure({"kmin": kmin, "kmax": kmax, "bins": 1,
                                    "exclude_horizontal": exclude_horizontal})
        return float(_tables(prepared, [measure], SPHEREX_PIXEL_SCALE, nodes)[0]
                     .meta["band_power"])
    frame, flip, (ny, nx) = _frames(sc.schedule.geometry, rows, cols)
    sy, sx = _band_cells(ny, nx, float(kmin), float(kmax), bool(exclude_horizontal))
    if not sy.size:
        raise SpherexReduceError(f"forecast: no Fourier mode of the {ny} x {nx} image has "
                                 f"{kmin} <= |k| <= {kmax}")
    fy, fx = frame_cells(sy, sx, frame, flip)
    cells = Cells(np.unique(fy), np.unique(fx))
    parts = component_planes(sc.schedule, rows, cols, comps, red, nodes, cells)
    pick = np.searchsorted(cells.ky, fy), np.searchsorted(cells.kx, fx)
    w = rfft_weights(nx)[sx]
    power = sum(np.sum(p[pick] * w) for p in parts.values()) / np.sum(w) / (ny * nx)
    pops, _ = population_variances(sc, red)
    white = poisson_variance(sc) + active_white_variance(sc)
    return float(power + white + sum(pops.values()))  # white as well


@functools.lru_cache(maxsize=8)
def _band_cells(ny, nx, kmin, kmax, exclude_horizontal):
    """The stored rfft2 cells ``(rows, columns)`` of an ``(ny, nx)`` image in the band (kept:
    a search asks for the same band hundreds of times)."""
    idx = k_grid(ny, nx, (kmin, kmax), exclude_horizontal)[0]
    cells = np.nonzero((idx == 0).reshape(ny, nx // 2 + 1))
    for a in cells:
        a.flags.writeable = False
    return cells


def _frames(geometry, rows, cols):
    """The light-sensitive rectangle's shape in the readout frame, whether the stored image
    is its transpose (`~spherex_reduce.analysis.forecast.layout.transposed`), and the
    stored image's shape."""
    frame = (rows.stop - rows.start, cols.stop - cols.start)
    flip = transposed(geometry)
    return frame, flip, (frame[::-1] if flip else frame)


def stored_planes(sc, red, rows, cols, comps, nodes=NODES, summed=False):
    """Each component's expected ``|FFT|²`` on the rfft2 grid of the stored light-sensitive image.

    The engine's readout-frame plane, transposed for channels as rows.

    Parameters
    ----------
    sc, red, rows, cols, comps
        As `prepare_forecast` returns them.
    nodes : int
        Quadrature nodes of the engine.
    summed : bool
        Return the sum over the components only, each component's plane added in order
        and let go: the planes are not each copied into the stored image's layout (at
        full size ~17 MB a component).

    Returns
    -------
    planes : dict of `numpy.ndarray`
        ``E|FFT|²`` by component name, shape ``(ny, nx // 2 + 1)``; with ``summed``,
        ``{"total": plane}`` (an empty dict without components).
    shape : tuple of int
        ``(ny, nx)`` of the stored light-sensitive image.

    Examples
    --------
    White noise: the mean of the plane over the grid is the pixel variance.

    >>> from spherex_reduce.analysis.forecast.engine import prepare_forecast, stored_planes
    >>> scene = {"geometry": {"nrows": 64, "ncols": 64, "nchannels": 4, "ref_border": 4},
    ...          "readout": {"nframes": 8, "phantom_reads": 0}, "scene": {"photocurrent": 1.0},
    ...          "noise": {"components": [{"name": "w", "alpha": 2e-3}]}}
    >>> planes, (ny, nx) = stored_planes(*prepare_forecast(scene, None))
    >>> (ny, nx), round(float(planes["w"].mean()) / (ny * nx), 1)
    ((56, 56), 1861.9)
    """
    frame, flip, (ny, nx) = _frames(sc.schedule.geometry, rows, cols)
    cells = frame_cells(*np.indices((ny, nx // 2 + 1)), frame, flip)
    parts = component_planes(sc.schedule, rows, cols, comps, red, nodes)
    if not summed:
        return {name: p[cells] for name, p in parts.items()}, (ny, nx)
    total = None
    for name in list(parts):  # in order: the numbers of the planes' sum
        p = parts.pop(name)
        total = p if total is None else np.add(total, p, out=total)
    return ({} if total is None else {"total": total[cells]}), (ny, nx)


def prepare_forecast(scene, pipeline):
    """What a forecast needs of a scene and a pipeline, refusing what is not forecast.

    Parameters
    ----------
    scene : `~spherex_reduce.simulation.Scene`, dict, str or `pathlib.Path`
        The scene (in slopes mode), or what `~spherex_reduce.simulation.load_scene` loads.
    pipeline : `~spherex_reduce.Pipeline`, str, dict or None
        The pipeline (its steps linear).

    Returns
    -------
    tuple
        The scene, the pipeline's `~spherex_reduce.analysis.forecast.steps.Reduction`,
        the light-sensitive rows and columns (slices of the readout frame) and
        the components the reduced image sees.

    Raises
    ------
    SpherexReduceError
        Quadrants, windows, or reference pixels inside the light-sensitive rectangle.

    Examples
    --------
    >>> from spherex_reduce.analysis.forecast.engine import prepare_forecast
    >>> scene = {"geometry": {"nrows": 64, "ncols": 64, "nchannels": 4, "ref_border": 4},
    ...          "readout": {"nframes": 8, "phantom_reads": 0}, "scene": {"photocurrent": 1.0},
    ...          "noise": {"components": [{"name": "w", "alpha": 2e-3}]}}
    >>> sc, red, rows, cols, comps = prepare_forecast(scene, None)
    >>> rows, cols, [c.name for c in comps]
    (slice(4, 60, None), slice(4, 60, None), ['w'])
    """
    sc = scene if isinstance(scene, Scene) else load_scene(scene)
    sc = sc.in_electrons("forecast")  # a scene in adu, with its gain
    clash = sorted({c.name for c in sc.components} & set(_OWN_PARTS))
    if clash:
        raise ConfigError(f"noise.components: {clash[0]!r} is the name of one of the forecast's "
                          f"own columns (power_{clash[0]}); rename the component")
    red = reduction(pipeline)
    sc.check_mode("slopes")
    g = sc.schedule.geometry  # the readout frame, where the engine works
    if g.window is not None or g.layout.channels == "quadrants":
        raise SpherexReduceError("forecast: only full arrays with channels as columns or rows "
                                 "are forecast so far, not quadrants (four flipped blocks side "
                                 "by side) nor windows")
    rows, cols = light_sensitive(g)  # the frame's rectangle: the stored one transposed
    if g.reference_pixel_mask()[rows, cols].any():
        raise SpherexReduceError("forecast: reference pixels inside the light-sensitive "
                                 "rectangle (channel_border) are not forecast so far")
    phantom = red.phantom or red.reference_phantom
    comps = [c for c in sc.components if not c.is_zero
             and (c.seen_by_pixels or (phantom and c.seen_by_phantom))]
    return sc, red, rows, cols, comps


def forecast_measure(measure):
    """The `~spherex_reduce.analysis.case.SpectrumMeasure` a forecast measures, refusing in
    one line what is not linear.

    Parameters
    ----------
    measure : `~spherex_reduce.analysis.case.SpectrumMeasure`, dict or None
        A measure, a ``measure:`` mapping (as a sweep's) or None (the defaults).

    Returns
    -------
    `~spherex_reduce.analysis.case.SpectrumMeasure`

    Raises
    ------
    ConfigError
        ``mask_sources`` (a mask found from the image is not linear), or an
        unknown ``measure:`` key.

    Examples
    --------
    >>> from spherex_reduce.analysis.forecast.engine import forecast_measure
    >>> forecast_measure({"bins": 8}).bins
    8
    >>> forecast_measure({"mask_sources": True})
    Traceback (most recent call last):
    ...
    spherex_reduce.core.errors.ConfigError: forecast: measure.mask_sources: masking ...
    """
    if not isinstance(measure, SpectrumMeasure):
        measure = SpectrumMeasure(**measure_section(measure, "forecast"))
    if measure.mask_sources:
        raise ConfigError("forecast: measure.mask_sources: masking sources is not linear "
                          "and cannot be forecast")
    return measure


def poisson_variance(scene):
    """Slope variance (e/s)² of the Poisson noise of the dark current and photocurrent.

    The same in every light-sensitive pixel (0 without it): the uniform
    least-squares slope's weights ``w`` (at the frame times or the ``read_times``:
    `~spherex_reduce.noise.variance.slope_frames`) against the covariance of the
    charge read, ``rate (min(t_j, t_k) - t_0)``.

    Parameters
    ----------
    scene : `~spherex_reduce.simulation.Scene`

    Returns
    -------
    float

    Examples
    --------
    Evenly spaced frames: ``6 (n² + 1) / (5 n (n² - 1))`` times the rate over the frame
    time (`~spherex_reduce.analysis.slope_variance_factor`).

    >>> from spherex_reduce.simulation import load_scene
    >>> from spherex_reduce.analysis.forecast.engine import poisson_variance
    >>> scene = {"geometry": {"nrows": 64, "ncols": 64, "nchannels": 4, "ref_border": 4},
    ...          "readout": {"nframes": 8, "phantom_reads": 0}, "scene": {"photocurrent": 1.0},
    ...          "noise": {"components": [{"name": "w", "alpha": 2e-3}]}}
    >>> sc = load_scene(scene)
    >>> n, t = 8, sc.schedule.frame_time.to_value("s")
    >>> bool(abs(poisson_variance(sc) / (6 * (n**2 + 1) / (5 * n * (n**2 - 1)) / t) - 1) < 1e-12)
    True
    """
    t = scene.terms
    rate = t.dark_current + t.photocurrent
    if not (t.poisson and rate > 0):
        return 0.0
    return float(rate * shot_factor(scene.schedule))


def active_white_variance(scene):
    """Slope variance (e/s)² of the light-sensitive pixels' own white read noise.

    ``scene.active_read_noise`` ``σ`` (e per read; the reference pixels do not see
    it, so no reference correction moves it) in every light-sensitive pixel: ``σ²
    Σ w_k²``, ``w`` the uniform least-squares slope's weights of the frames
    (`~spherex_reduce.noise.variance.slope_frames`); 0 without it.

    Parameters
    ----------
    scene : `~spherex_reduce.simulation.Scene`
        In electrons (`~spherex_reduce.simulation.Scene.in_electrons`).

    Returns
    -------
    float

    Examples
    --------
    Two frames one frame time ``T`` apart: the slope's variance is ``2 σ² / T²``.

    >>> from spherex_reduce.simulation import load_scene
    >>> from spherex_reduce.analysis.forecast.engine import active_white_variance
    >>> sc = load_scene({"readout": {"nframes": 2}, "scene": {"active_read_noise": 10.0}})
    >>> t = sc.schedule.frame_time.to_value("s")
    >>> round(float(active_white_variance(sc) * t**2 / (2 * 10.0**2)), 12)
    1.0
    """
    sigma = float(scene.terms.active_read_noise)
    if not sigma > 0:
        return 0.0
    w, _, _ = slope_frames(scene.schedule)
    return sigma * sigma * float(np.sum(w * w))
