"""The expected power spectrum of a slope image, computed without random numbers.

The slope image of the simulator's slopes route is a Gaussian field whose
covariance is known in closed form: a pixel's slope is ``sum_k w_k x(t + k F)``
of the stream ``x`` of each noise component, so two pixels read ``L`` samples
apart within a frame have the slope covariance ``S(L)``
(`~spherex_reduce.noise.variance.slope_covariance`).  A pixel of physical row
``p`` (read in read slot ``r(p)``) and column ``j`` (sampled ``o_j`` samples
into its channel's read) is sampled at ``r(p) R + o_j`` (``R`` samples per row
read).  For a channel-scope component two pixels correlate only within one
channel (with ``acn`` only when their offsets have one parity); a common
component correlates every pair.  So the expectation of ``|FFT|²`` at
``(k_y, k_x)`` is::

    E|Y(k_y, k_x)|² = sum_m sum_d A(k_y, m) B(k_x, d) S(m R + d)

with ``A(k_y, m) = sum_{r(p) - r(p') = m} exp(-i k_y (p - p'))`` (rows ``m``
read slots apart, an autocorrelation over read slots: FFTs) and
``B(k_x, d) = sum_{o_j - o_j' = d} exp(-i k_x (j - j'))`` over the pairs of
columns that correlate (an autocorrelation over offsets: FFTs).  The double sum
is exact for the ``m`` near a singularity of ``S`` (``m R`` within
`NEAR_READS` row reads of a multiple of the frame time, where ``S`` has its
white spike and the logarithmic cusp of ``1/f``); for the others ``S(m R + d)``
is smooth in ``d`` over the channel width and is interpolated on `NODES`
Chebyshev nodes rounded to whole offsets (every node is at least three channel
widths from a cusp).  Against the exact sum over every offset the rule is off
by < 1e-7 in every bin of the paper's full-size case and < 1e-5 in the 16 x 16
scenes of the tests (measured; the tests hold it to 1e-3 per bin, 1e-4 in
band power, against a brute-force covariance of every pixel pair).  Every cell
of the Fourier plane is then binned by the spectrum's own binning, so the
forecast has the bins, normalisation and columns of
`~spherex_reduce.analysis.power_spectrum` measured on the light-sensitive
pixels (`~spherex_reduce.analysis.light`).
"""

import numpy as np
import scipy.fft
from astropy import units as u

from ..core.errors import ConfigError, SpherexReduceError
from ..noise.variance import slope_covariance
from ..reduce.pipeline import as_pipeline
from ..simulation.scene import Scene, load_scene
from .case import SpectrumMeasure, measure_section
from .light import light_sensitive
from .photon_noise import slope_variance_factor
from .spectrum import (
    SPHEREX_PIXEL_SCALE,
    _edges,
    rfft_weights,
    spectrum_table,
)

__all__ = ["FORECAST_STEPS", "NEAR_READS", "NODES", "forecast", "linear_steps"]

#: Row reads from a multiple of the frame time within which the sum over offsets is exact.
NEAR_READS = 4
#: Chebyshev nodes over the offsets beyond (the rule is exact for polynomials of lower degree).
NODES = 8

#: Steps the forecast propagates, with the parameter values it propagates them for.
FORECAST_STEPS = {"unchop": {}, "fit_ramp": {"weighting": "uniform"}}

_SLOPE_UNIT = u.electron / u.s
#: Name of the Poisson noise of the dark current and photocurrent in the table's columns.
_POISSON = "poisson"


def forecast(scene, pipeline=None, measure=None, *, pixel_scale=SPHEREX_PIXEL_SCALE,
             nodes=NODES):
    """Expected power spectrum ``P(k)`` of a scene's reduced slope image.

    What ``SpectrumMeasure(**measure)`` measures on average, over realisations
    of ``simulate(scene, mode="slopes")`` reduced by ``pipeline``, on the
    light-sensitive pixels of the image in physical row order.  No random
    numbers.

    Parameters
    ----------
    scene : `~spherex_reduce.simulation.Scene`, dict, YAML text or path
        The scene (`~spherex_reduce.simulation.load_scene`); its channels as
        columns of the array, without windows.
    pipeline : `~spherex_reduce.Pipeline`, shipped name, path or dict, optional
        The reduction (`~spherex_reduce.reduce.pipeline.as_pipeline`); None:
        the slope image as simulated.  Every step must be one the forecast
        knows as linear (`FORECAST_STEPS`): so far ``unchop`` and ``fit_ramp``
        with uniform weights.
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
        component (zero for one the pixels do not see) and ``power_poisson``
        for the Poisson noise of the scene's dark current and photocurrent
        (white, `~spherex_reduce.analysis.slope_variance_factor`), if any.  ``meta`` as
        `~spherex_reduce.analysis.power_spectrum`'s, with ``band_power`` (the
        paper's band, e/s squared), ``variance`` (the mean of ``P`` over the
        whole plane: the pixel variance) and ``forecast`` (what was forecast).

    Raises
    ------
    SpherexReduceError
        A scene term that is neither Gaussian noise of the readout nor the
        Poisson noise of a current (hot pixels, telegraph noise), channels not as
        columns, a window, or reference pixels inside the light-sensitive
        rectangle.
    ConfigError
        A scene that has no slope image (fewer than 2 frames, or groups); a
        pipeline step the forecast does not know (the message names it) or a
        measure that is not linear (``mask_sources``).

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
    sc = scene if isinstance(scene, Scene) else load_scene(scene)
    steps = linear_steps(pipeline)
    m = _measure(measure)
    sc.check_mode("slopes")
    _check_terms(sc.terms)
    s = sc.schedule
    g = s.geometry
    if g.window is not None or not g.layout.identity:
        raise SpherexReduceError("forecast: only full arrays with channels as columns are "
                                 "forecast so far")
    rows, cols = light_sensitive(g)
    if g.reference_pixel_mask()[rows, cols].any():
        raise SpherexReduceError("forecast: reference pixels inside the light-sensitive "
                                 "rectangle (channel_border) are not forecast so far")
    ny, nx = rows.stop - rows.start, cols.stop - cols.start
    parts = _component_planes(s, rows, cols, [c for c in sc.components if c.seen_by_pixels
                                              and not c.is_zero], nodes)
    shot = _poisson_variance(sc)
    if shot:  # white: the same in every cell
        parts[_POISSON] = np.full((ny, nx // 2 + 1), shot * ny * nx)
    unit = _SLOPE_UNIT**2
    shape = (ny, nx)
    edges = _edges(m.bins, ny, nx)
    exclude_horizontal = bool(m.exclude_horizontal)
    total = sum(parts.values()) if parts else np.zeros((ny, nx // 2 + 1))
    table = spectrum_table(total, shape, edges, unit, 1.0, pixel_scale, exclude_horizontal)
    names = [c.name for c in sc.components] + ([_POISSON] if shot else [])
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
        "forecast": "expected P(k) of the slope image, no reduction",
        "pipeline": " > ".join(steps) if steps else "none",
        "band_kmin": float(m.kmin), "band_kmax": float(m.kmax),
        "band_power": float(u.Quantity(band["power"])[0].value) if len(band) else None,
        "variance": float(np.sum(total * full) / (ny * nx) ** 2),
    })
    return table


def linear_steps(pipeline):
    """The names of a pipeline's steps, refused in one line if the forecast does not know one.

    Parameters
    ----------
    pipeline : `~spherex_reduce.Pipeline`, shipped name, path, dict or None

    Returns
    -------
    list of str

    Raises
    ------
    ConfigError
        A step not in `FORECAST_STEPS`, or one with parameter values the
        forecast does not propagate (the message names the step and value).

    Examples
    --------
    >>> from spherex_reduce.analysis.noise_forecast import linear_steps
    >>> linear_steps({"steps": [{"unchop": {}}, {"fit_ramp": {}}]})
    ['unchop', 'fit_ramp']
    """
    if pipeline is None:
        return []
    p = as_pipeline(pipeline)
    names = []
    for i, item in enumerate(p.config["steps"]):
        (name, params), = item.items()
        if name not in FORECAST_STEPS:
            raise ConfigError(f"forecast: steps[{i}].{name} ({p.source}) is not forecast so "
                              f"far; forecast steps: {', '.join(FORECAST_STEPS)}")
        for key, value in FORECAST_STEPS[name].items():
            if params.get(key, value) != value:
                raise ConfigError(f"forecast: steps[{i}].{name}.{key}: {params[key]!r} is "
                                  f"not forecast; only {value!r}")
        names.append(name)
    return names


def _measure(measure):
    """A `SpectrumMeasure` from a measure, a ``measure:`` mapping or None (refusing the
    non-linear ``mask_sources``)."""
    if not isinstance(measure, SpectrumMeasure):
        measure = SpectrumMeasure(**measure_section(measure, "forecast"))
    if measure.mask_sources:
        raise ConfigError("forecast: measure.mask_sources: masking sources is not linear "
                          "and cannot be forecast")
    return measure


def _component_planes(s, rows, cols, comps, nodes):
    """``{name: E|FFT|²}`` on the rfft2 grid of the light-sensitive image for each component.

    Only the ``k_y >= 0`` half of ``A`` is computed: ``A(-k_y, m)`` is its conjugate, so
    with ``Q = sum_d B S`` the two halves are ``Re A Re Q -/+ Im A Im Q``.
    """
    g = s.geometry
    ny, nx = rows.stop - rows.start, cols.stop - cols.start
    rs, width, frame = s.row_samples, g.channel_width, s.frame_samples
    a = _row_pairs(s, rows)  # (ny // 2 + 1, 2 * slots)
    slots = a.shape[1] // 2
    m = np.arange(-(slots - 1), slots)
    dist = np.min(np.abs(m[:, None] * rs - np.array([-frame, 0, frame])[None, :]), axis=1)
    near = dist < NEAR_READS * rs
    a_near, a_far = a[:, m[near] % a.shape[1]], a[:, m[~near] % a.shape[1]]
    del a
    d = np.arange(-(width - 1), width)
    interp, dnodes = _chebyshev_rule(width - 1, nodes)
    pairs = _column_pairs(g, cols, nx)  # {"channel": B, "common": B}, (nkx, 2 width - 1)
    lags = np.concatenate([(m[near][:, None] * rs + d[None, :]).ravel(),
                           (m[~near][:, None] * rs + dnodes[None, :]).ravel()])
    lags, inverse = np.unique(np.abs(lags), return_inverse=True)  # S is even
    cov = slope_covariance(comps, s, lags)[:, inverse.ravel()] if comps else None
    nnear = near.sum() * d.size
    neg = np.arange(1, (ny - 1) // 2 + 1)  # k_y index i < 0 is the mirror of ny - i
    parts = {}
    for i, comp in enumerate(comps):
        b = pairs[comp.scope].copy()
        if comp.acn:
            b[:, d % 2 != 0] = 0.0
        s_near = cov[i, :nnear].reshape(near.sum(), d.size)
        s_far = cov[i, nnear:].reshape((~near).sum(), dnodes.size)
        half = [(a_near, s_near @ b.T), (a_far @ s_far, (b @ interp).T)]
        re = sum(x.real @ q.real for x, q in half)
        im = sum(x.imag @ q.imag for x, q in half)
        p = np.empty((ny, re.shape[1]))
        p[:re.shape[0]] = re - im
        p[ny - neg] = re[neg] + im[neg]
        parts[comp.name] = p
    return parts


def _poisson_variance(scene):
    """Slope variance (e/s)² of the Poisson noise of the dark current and photocurrent, the
    same in every light-sensitive pixel (0 without it)."""
    t = scene.terms
    rate = t["dark_current"] + t["photocurrent"]
    if not (t["poisson"] and rate > 0):
        return 0.0
    s = scene.schedule
    return rate * slope_variance_factor(s.nframes) * s.geometry.pixel_rate / s.frame_samples


def _check_terms(terms):
    """Refuse the scene terms that add noise other than Gaussian readout and Poisson noise."""
    rtn = terms.get("rtn") or {}
    named = [name for name, on in (
        ("hot pixels", terms["hot_pixel_fraction"] > 0),
        ("telegraph noise", rtn.get("fraction", 0) > 0 and rtn.get("amplitude", 0) > 0),
    ) if on]
    if named:
        raise SpherexReduceError(f"forecast: the scene has {', '.join(named)}; only the "
                                 "readout's noise and Poisson noise are forecast so far")


def _row_pairs(schedule, rows):
    """``A(k_y, m)`` for ``k_y = 2 pi i / ny`` (``i = 0 ... ny // 2``) and read-slot lag ``m``
    (index ``m mod 2 slots``): the autocorrelation over read slots of ``exp(-i k_y p)``."""
    s = schedule
    slot = (s.starts - s.phantom_reads) // s.row_samples
    slots = int(slot.max()) + 1
    first = s.read_of_row()[rows]
    if np.any(first < 0) or np.any(s.is_reference[first]):
        raise SpherexReduceError("forecast: a light-sensitive row is not read as an active row")
    ny = rows.stop - rows.start
    ky = 2 * np.pi * np.arange(ny // 2 + 1) / ny
    g = np.zeros((ky.size, 2 * slots), dtype=complex)
    g[:, slot[first]] = np.exp(-1j * ky[:, None] * np.arange(ny)[None, :])
    f = scipy.fft.fft(g, axis=1, workers=-1)
    f = f.real**2 + f.imag**2
    return scipy.fft.ifft(f, axis=1, workers=-1)


def _column_pairs(geometry, cols, nx):
    """``B(k_x, d)`` of the channel and common scopes, ``d = -(width - 1) ... width - 1``:
    the autocorrelation over offsets of ``sum_{o_j = o} exp(-i k_x j)``, summed over
    channels (channel scope) or of the sum over channels (common scope)."""
    width, nch = geometry.channel_width, geometry.nchannels
    j = np.arange(cols.start, cols.stop)
    off, chan = geometry.column_offsets()[j], geometry.channel_of_column()[j]
    kx = 2 * np.pi * np.fft.rfftfreq(nx)
    e = np.zeros((nch, kx.size, width), dtype=complex)
    np.add.at(e, (chan, slice(None), off), np.exp(-1j * np.outer(j - cols.start, kx)))
    n = 2 * width
    d = np.arange(-(width - 1), width) % n

    def corr(x):
        f = scipy.fft.fft(x, n, axis=-1)
        return scipy.fft.ifft(f.real**2 + f.imag**2, axis=-1)[..., d]

    return {"channel": corr(e).sum(axis=0), "common": corr(e.sum(axis=0))}


def _chebyshev_rule(half, n):
    """``(L, nodes)``: ``f(d) ≈ sum_i L[d, i] f(nodes[i])`` for ``d = -half ... half``, the
    interpolating polynomial on ``n`` Chebyshev nodes of ``[-half, half]`` rounded to whole
    offsets (a stream is only defined at whole samples: its white part is a spike there)."""
    d = np.arange(-half, half + 1)
    if int(n) >= d.size:
        return np.eye(d.size), d
    nodes = np.unique(np.rint(half * np.cos(np.pi * (np.arange(n) + 0.5) / n)).astype(int))
    cheb = np.polynomial.chebyshev.chebvander
    rule = np.linalg.solve(cheb(nodes / half, nodes.size - 1).T,
                           cheb(d / half, nodes.size - 1).T).T
    return rule, nodes
