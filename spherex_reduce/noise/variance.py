"""The analytic, aperiodic slope variance ``integral p(f) |H(f)|^2 df``.

For the least-squares slope ``sum_k w_k x(t_k)`` of a stationary stream read
at times ``t_k`` the variance is ``integral_0^{fs/2} p(f) |H(f)|^2 df`` with
``H(f) = sum_k w_k exp(2 pi i f t_k)``.  Because the weights sum to zero it
equals ``-1/2 sum_jk w_j w_k D(t_j - t_k)`` where ``D`` is the structure
function of the stream, which has closed forms for the three terms of the
paper's PSD (see `NoiseComponent.structure_function`).  This is finite for
``1/f`` and ``1/f^1.3`` noise and needs no frequency grid, so it is free of the
periodic wrap-around bias of FFT synthesis.
"""

import numpy as np
from astropy import units as u

from .components import NoiseComponent, noise_components
from .structure_functions import inv_f_structure, power_structure, white_structure

__all__ = ["SHIFT_CELLS", "expected_slope_variance", "ls_weights", "slope_covariance",
           "slope_frames"]

#: Lags times frame shifts `slope_covariance` evaluates at a time (its arrays of that size
#: stay below ~0.2 GB; only readouts with many uneven read times need more than one pass).
SHIFT_CELLS = 2**24


def ls_weights(times):
    """Uniform least-squares slope weights ``w_k`` for read times ``t_k``.

    ``sum w_k = 0`` and ``sum w_k t_k = 1``; the slope is ``sum w_k x_k``.

    Examples
    --------
    >>> from spherex_reduce.simulation import ls_weights
    >>> ls_weights([0.0, 1.0, 2.0]).tolist()
    [-0.5, 0.0, 0.5]
    """
    t = np.asarray(times, dtype=float)
    d = t - t.mean()
    return d / np.sum(d * d)


def slope_frames(schedule):
    """The frames of a schedule's least-squares slope: their weights, and their pairs by shift.

    The slope of the sample taken ``t`` samples into every frame is ``sum_k w_k
    x(t + s_k)``, frame ``k`` starting ``s_k`` samples into the exposure: ``k F``
    (``F`` samples per frame), or, with ``read_times``, the read's time at the
    pixel rate rounded to a whole sample (a stream is only sampled there); the
    weights are the uniform least-squares ones of the frames' times (`ls_weights`
    of the ``read_times`` themselves, which the ramp fit takes).

    Parameters
    ----------
    schedule : `~spherex_reduce.ReadoutSchedule`

    Returns
    -------
    w : `numpy.ndarray`
        The weight of every frame, ``(nframes,)``, 1/s.
    a : `numpy.ndarray`
        ``a_i = sum w_j w_k`` over the pairs of frames with ``s_j - s_k`` equal to
        ``shifts[i]``.
    shifts : `numpy.ndarray` of int
        The distinct shifts ``s_j - s_k`` (samples), increasing: ``-(n - 1) F ... (n -
        1) F`` for evenly spaced frames.

    Examples
    --------
    >>> from spherex_reduce import ReadoutSchedule
    >>> from spherex_reduce.noise.variance import slope_frames
    >>> s = ReadoutSchedule(nframes=3, read_times=[0.0, 2.0, 6.0])   # s, at 100 kHz
    >>> w, a, shifts = slope_frames(s)
    >>> w.round(4).tolist(), (shifts // 100000).tolist()
    ([-0.1429, -0.0357, 0.1786], [-6, -4, -2, 0, 2, 4, 6])
    >>> a.round(4).tolist()
    [-0.0255, -0.0064, 0.0051, 0.0536, 0.0051, -0.0064, -0.0255]
    """
    n, big_f, fs = schedule.nframes, schedule.frame_samples, schedule.geometry.pixel_rate
    if schedule.read_times is None:  # every shift a multiple of the frame
        w = ls_weights(np.arange(n) * big_f / fs)
        return w, np.correlate(w, w, mode="full"), np.arange(-(n - 1), n) * big_f
    times = np.asarray(schedule.read_times, dtype=np.float64)
    w = ls_weights(times)
    starts = np.rint(times * fs).astype(np.int64)
    shifts, pair = np.unique(np.subtract.outer(starts, starts).ravel(), return_inverse=True)
    return w, np.bincount(pair.ravel(), weights=np.outer(w, w).ravel()), shifts


def _as_components(noise):
    if isinstance(noise, NoiseComponent):
        return [noise]
    if isinstance(noise, str):
        return list(noise_components(noise).values())
    if isinstance(noise, dict):
        return list(noise.values())
    if hasattr(noise, "colnames"):  # an astropy Table
        import tempfile
        from pathlib import Path

        with tempfile.TemporaryDirectory() as d:
            p = Path(d) / "t.ecsv"
            noise.write(p, format="ascii.ecsv")
            return list(noise_components(str(p)).values())
    return list(noise)


def expected_slope_variance(noise, schedule, *, kind="pixels"):
    """Per-pixel variance of the ramp-fitted slope, predicted without simulating.

    Parameters
    ----------
    noise : `NoiseComponent`, list or dict of them, table name or `~astropy.table.Table`
        The noise model; components not seen by ``kind`` contribute nothing.
        A table name such as ``'spherex-table2'`` means all its components.
    schedule : `~spherex_reduce.ReadoutSchedule`
        Frame time, number of frames, pixel rate and phantom reads.
    kind : {'pixels', 'phantom'}
        ``'pixels'``: the slope of one pixel (every pixel has the same
        variance, since all are read once per frame at the same spacing).
        ``'phantom'``: the slope of one read's phantom value (the mean of the
        ``c`` phantom samples; for a component with ``acn`` the samples of
        each parity see an independent realisation, as in the simulator).

    Returns
    -------
    `~astropy.units.Quantity`
        Variance in (e/s)².

    Notes
    -----
    Uniform least-squares weights over the frame times (``k * T_frame``, or
    the schedule's ``read_times``: `slope_frames`); the stream is the aperiodic
    stationary process with the one-sided PSD ``p(f)`` sampled at the pixel rate
    (no wrap-around).

    Examples
    --------
    >>> from spherex_reduce import ReadoutSchedule, expected_slope_variance
    >>> from spherex_reduce.simulation import NoiseComponent
    >>> s = ReadoutSchedule(nframes=2)
    >>> white = NoiseComponent("white", alpha=2e-3)
    >>> v = expected_slope_variance(white, s)    # 2 * 100 e^2 / T_frame^2
    >>> round(float(v.value), 3), v.unit
    (87.715, Unit("electron2 / s2"))
    >>> round(float(expected_slope_variance("spherex-table2", ReadoutSchedule()).value), 5)
    0.00169
    """
    if kind not in ("pixels", "phantom"):
        raise ValueError(f"kind must be 'pixels' or 'phantom', got {kind!r}")
    comps = [c for c in _as_components(noise) if not c.is_zero and
             (c.seen_by_pixels if kind == "pixels" else c.seen_by_phantom)]
    unit = u.electron**2 / u.s**2
    n = schedule.nframes
    if n < 2 or not comps:
        return (np.nan if n < 2 else 0.0) * unit
    if kind == "phantom" and schedule.phantom_reads == 0:
        return np.nan * unit
    c = schedule.phantom_reads
    i = np.arange(c)
    total = 0.0
    for comp in comps:
        if kind == "pixels":
            groups = [np.array([0])]
        elif comp.acn:
            # even/odd realisations: phantom sample i takes parity (i - c) % 2
            groups = [i[(i - c) % 2 == p] for p in (0, 1)]
        else:
            groups = [i]
        for grp in groups:
            if grp.size == 0:
                continue
            # the mean of the group's samples, weighted by its share of the c samples
            diff = (grp[:, None] - grp[None, :]).ravel()
            offsets, counts = np.unique(np.abs(diff), return_counts=True)
            cov = slope_covariance(comp, schedule, offsets)[0]
            scale = 1.0 if kind == "pixels" else (grp.size / c) ** 2
            total += scale * np.sum(cov * counts) / grp.size**2
    return total * unit


def slope_covariance(noise, schedule, lags):
    """Covariance of the ramp-fitted slopes of two samples ``lags`` apart within a frame.

    The slope of the sample taken ``t`` samples into every frame is
    ``y(t) = sum_k w_k x(t + s_k)`` (frame ``k`` starting ``s_k`` samples in: ``k
    F`` for ``F`` samples per frame, or at its ``read_times`` entry; least-squares
    weights ``w_k``: `slope_frames`); for a stationary stream ``x`` it is a
    stationary process in ``t`` with the covariance::

        C(L) = Cov(y(t), y(t + L)) = -1/2 sum_jk w_j w_k D(L + s_j - s_k)

    where ``D`` is the structure function of ``x`` (the weights sum to zero,
    so ``1/f`` noise needs no low-frequency cut-off).  Exact and aperiodic:
    no frequency grid.

    Parameters
    ----------
    noise : `NoiseComponent`, list or dict of them, table name or `~astropy.table.Table`
        The components (each gets its own row; scope and visibility are not
        looked at).
    schedule : `~spherex_reduce.ReadoutSchedule`
        Frames, frame samples (or read times) and pixel rate.
    lags : array_like of int
        Lags in samples.

    Returns
    -------
    `numpy.ndarray`, shape ``(n_components, *lags.shape)``
        Covariances in (e/s)² (plain floats).

    Examples
    --------
    >>> from spherex_reduce import ReadoutSchedule
    >>> from spherex_reduce.simulation import NoiseComponent, slope_covariance
    >>> s = ReadoutSchedule(nframes=2)
    >>> white = NoiseComponent("white", alpha=2e-3)
    >>> pink = NoiseComponent("pink", beta=1e-2)
    >>> c = slope_covariance([white, pink], s, [0, 1, 100000])   # lags in samples
    >>> round(float(c[0, 0]), 3), abs(round(float(c[0, 1]), 3))  # white: uncorrelated
    (87.715, 0.0)
    >>> [round(float(v), 4) for v in c[1]]                         # 1/f: correlated
    [0.1197, 0.1052, 0.0011]
    """
    comps = _as_components(noise)
    lags = np.asarray(lags, dtype=float)
    fs = schedule.geometry.pixel_rate
    _, a, shifts = slope_frames(schedule)
    flat = lags.reshape(1, -1)
    step = max(1, SHIFT_CELLS // shifts.size)
    out = np.zeros((len(comps), flat.size))
    for lo in range(0, flat.size, step):  # one pass unless many uneven read times
        x = np.abs(flat[:, lo:lo + step] + shifts[:, None])
        basis = {}
        for i, comp in enumerate(comps):
            for key, coef in (("alpha", comp.alpha), ("beta", comp.beta),
                              (("gamma", comp.exponent), comp.gamma)):
                if not coef:
                    continue
                if key not in basis:
                    if key == "alpha":
                        d = white_structure(x, fs)
                    elif key == "beta":
                        d = inv_f_structure(x)
                    else:
                        d = power_structure(x, fs, key[1])
                    basis[key] = -0.5 * (a @ d)
                out[i, lo:lo + step] += coef * basis[key]
    return out.reshape(len(comps), *lags.shape)
