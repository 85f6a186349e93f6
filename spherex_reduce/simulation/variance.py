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

from .components import NoiseComponent, load_noise_table, noise_components

__all__ = ["expected_slope_variance", "ls_weights"]


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
    Uniform least-squares weights over the frame times ``k * T_frame``; the
    stream is the aperiodic stationary process with the one-sided PSD ``p(f)``
    sampled at the pixel rate (no wrap-around).

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
    fs = schedule.geometry.pixel_rate
    F = schedule.frame_samples
    w = ls_weights(np.arange(n) * F / fs)
    # a_d = sum_k w_k w_{k+d}, d >= 1
    a = np.array([np.dot(w[:-d], w[d:]) for d in range(1, n)])
    c = schedule.phantom_reads
    total = 0.0
    for comp in comps:
        if kind == "pixels":
            groups = [np.array([0])]
        elif comp.acn:
            # even/odd realisations: phantom sample i takes parity (i - c) % 2
            i = np.arange(c)
            groups = [i[(i - c) % 2 == p] for p in (0, 1)]
        else:
            groups = [np.arange(c)]
        for grp in groups:
            if grp.size == 0:
                continue
            scale = 1.0 if kind == "pixels" else (grp.size / c) ** 2
            diff = (grp[:, None] - grp[None, :]).ravel()
            offsets, counts = np.unique(diff, return_counts=True)
            pw = counts / grp.size**2
            lags = np.arange(1, n)[:, None] * F + offsets[None, :]
            d = comp.structure_function(lags, fs)  # (n-1, n_offsets)
            # lag 0 frames: within-read offsets (phantom averaging); D(0) = 0
            d0 = comp.structure_function(offsets, fs)
            total += scale * (-np.sum(a[:, None] * d * pw)
                              - 0.5 * np.sum(w * w) * np.sum(d0 * pw))
    return total * unit


def _table_names():  # pragma: no cover - convenience for the docs
    return list(load_noise_table()["name"])
