"""Structure functions of the PSD terms, and the cosine integrals they are made of.

The structure function of a sampled stream with one-sided PSD ``p(f)`` is
``D(lag) = 2 * integral_0^{fs/2} p(f) (1 - cos(2 pi f lag / fs)) df``;
for the three terms of a `~spherex_reduce.noise.NoiseComponent` (unit
coefficient each) it is `white_structure`, `inv_f_structure` and
`power_structure`, in closed form or with the cosine integrals `cin` and
`g_power`.  `~spherex_reduce.noise.NoiseComponent.structure_function`, the
slope statistics (`spherex_reduce.noise.variance`) and the read covariance
(`spherex_reduce.noise.read_covariance`) are made of them.
"""

import functools

import numpy as np

__all__ = ["cin", "g_power", "inv_f_structure", "power_structure", "white_structure"]


def _integer_parity(lag):
    """``cos(pi lag)`` where ``lag`` is an integer (``sin(pi lag) = 0`` there), else NaN."""
    li = lag.astype(np.int64)
    out = 1.0 - 2.0 * (li & 1)
    out[li != lag] = np.nan
    return out


def white_structure(lag, fs):
    """Structure function of the white term for ``alpha = 1``.

    ``fs (1 - sinc(lag))``: ``fs`` at every integer lag > 0.

    Parameters
    ----------
    lag : array_like
        Non-negative lags (``|lag|``), in samples.
    fs : float
        Sample rate, Hz.

    Returns
    -------
    `numpy.ndarray`
        In e² per unit ``alpha`` (e²/Hz).

    Examples
    --------
    >>> import numpy as np
    >>> from spherex_reduce.noise.structure_functions import white_structure
    >>> np.round(white_structure(np.array([0.0, 0.5, 1.0, 2.0]), 2.0), 6).tolist()
    [0.0, 0.72676, 2.0, 2.0]
    """
    shape, lag = np.shape(lag), np.ravel(lag)
    out = np.where(lag > 0, fs, 0.0)
    frac = np.flatnonzero(lag != np.floor(lag))  # sinc vanishes at non-zero integers
    out[frac] -= fs * np.sinc(lag[frac])
    return out.reshape(shape)


def inv_f_structure(lag):
    """Structure function of the ``1/f`` term for ``beta = 1``: ``2 Cin(pi lag)``.

    Parameters
    ----------
    lag : array_like
        Non-negative lags (``|lag|``), in samples.

    Returns
    -------
    `numpy.ndarray`
        In e² per unit ``beta`` (e²).

    Examples
    --------
    ``2 Cin(pi) = 2 * integral_0^pi (1 - cos t) / t dt``:

    >>> import numpy as np
    >>> from spherex_reduce.noise.structure_functions import inv_f_structure
    >>> np.round(inv_f_structure(np.array([0.0, 1.0, 2.0])), 6).tolist()
    [0.0, 3.296555, 4.875307]
    """
    shape, lag = np.shape(lag), np.ravel(lag)
    out = np.zeros_like(lag)
    nz = lag > 0
    out[nz] = 2 * cin(np.pi * lag[nz], _integer_parity(lag[nz]))
    return out.reshape(shape)


def power_structure(lag, fs, e):
    """Structure function of the power-law term for ``gamma = 1`` and exponent ``e``.

    Parameters
    ----------
    lag : array_like
        Non-negative lags (``|lag|``), in samples.
    fs : float
        Sample rate, Hz.
    e : float
        Exponent of the power law, ``0 < e < 3``, ``e != 1``.

    Returns
    -------
    `numpy.ndarray`
        In e² per unit ``gamma``.

    Examples
    --------
    >>> import numpy as np
    >>> from spherex_reduce.noise.structure_functions import power_structure
    >>> np.round(power_structure(np.array([0.0, 1.0, 2.0]), 2.0, 1.3), 6).tolist()
    [0.0, 4.024146, 6.772901]
    """
    shape, lag = np.shape(lag), np.ravel(lag)
    out = np.zeros_like(lag)
    nz = lag > 0
    x = lag[nz]
    z = np.pi * x
    z_e1 = z ** (e - 1)  # (2 pi x / fs)^(e-1) = (2 / fs)^(e-1) z^(e-1)
    out[nz] = 2 * (2 / fs) ** (e - 1) * z_e1 * g_power(z, e, _integer_parity(x), z_e1)
    return out.reshape(shape)


def cin(x, cos_x=None):
    """The cosine integral ``Cin(x) = integral_0^x (1 - cos t)/t dt``.

    Parameters
    ----------
    x : array_like
        Non-negative arguments.
    cos_x : array_like, optional
        Where finite, ``cos x`` at a multiple of pi (``sin x = 0``): there,
        for ``x >= 40``, the asymptotic series of ``Ci`` needs no
        trigonometric functions (error < 1e-11).

    Returns
    -------
    `numpy.ndarray`

    Examples
    --------
    >>> import numpy as np
    >>> from spherex_reduce.noise.structure_functions import cin
    >>> np.round(cin(np.array([1e-4, 1.0, 50.0])), 8).tolist()
    [0.0, 0.23981174, 4.49486706]
    """
    x = np.asarray(x, dtype=float)
    out = np.empty_like(x)
    small = x < 1e-3
    out[small] = x[small] ** 2 / 4
    fast = np.zeros_like(small) if cos_x is None else (x >= 40) & np.isfinite(cos_x)
    if fast.any():
        # Ci(x) = f(x) sin x - g(x) cos x,  g(x) ~ (1 - 3!/x^2 + 5!/x^4 - 7!/x^6 + 9!/x^8)/x^2
        y = 1 / x[fast] ** 2
        g = y * (1 - y * (6 - y * (120 - y * (5040 - y * 362880))))
        out[fast] = np.euler_gamma + np.log(x[fast]) + g * cos_x[fast]
    rest = ~small & ~fast
    xs = x[rest]
    from scipy import special  # here: a reduction that never integrates a PSD skips it

    out[rest] = np.euler_gamma + np.log(xs) - special.sici(xs)[1]
    return out


def g_power(z, e, cos_z=None, z_e1=None):
    """The integral ``G_e(z) = integral_0^z (1 - cos u) u^(-e) du`` for ``0 < e < 3``, ``e != 1``.

    Parameters
    ----------
    z : array_like
        Positive arguments.
    e : float
        The exponent.
    cos_z : array_like, optional
        Where finite, ``cos z`` at a multiple of pi (``sin z = 0``), which
        spares the trigonometric functions of the asymptotic series (``z >= 40``).
    z_e1 : array_like, optional
        ``z**(e - 1)`` (spares a power).

    Returns
    -------
    `numpy.ndarray`

    Examples
    --------
    >>> import numpy as np
    >>> from spherex_reduce.noise.structure_functions import g_power
    >>> np.round(g_power(np.array([1.0, 50.0]), 1.3), 8).tolist()
    [0.28309686, 2.82619648]
    """
    from scipy import special  # here: a reduction that never integrates a PSD skips it

    z = np.atleast_1d(np.asarray(z, dtype=float))
    k_e = np.pi / (2 * special.gamma(e) * np.sin(np.pi * (e - 1) / 2))
    out = np.empty_like(z)
    big = z >= 40
    zb = z[big]
    # tail T(z) = int_z^inf cos(u) u^-e du, asymptotic series
    zme = zb ** (-e) if z_e1 is None else 1 / (np.asarray(z_e1)[big] * zb)
    inv = 1 / zb
    if cos_z is None:
        s, c = np.sin(zb), np.cos(zb)
        tail = zme * (-s + inv * (e * c + inv * (e * (e + 1) * s - inv * (
            e * (e + 1) * (e + 2) * c + inv * e * (e + 1) * (e + 2) * (e + 3) * s))))
    else:  # sin z = 0 where cos z is given: the series without its sine terms
        c = np.asarray(cos_z, dtype=float)[big]
        other = np.flatnonzero(~np.isfinite(c))
        c[other] = np.cos(zb[other])
        tail = zme * (inv * (e * c - inv * (inv * (e * (e + 1) * (e + 2) * c))))
        if other.size:
            s, c, zo, io = np.sin(zb[other]), c[other], zme[other], inv[other]
            tail[other] = zo * (-s + io * (e * c + io * (e * (e + 1) * s - io * (
                e * (e + 1) * (e + 2) * c + io * e * (e + 1) * (e + 2) * (e + 3) * s))))
    out[big] = k_e - zb * zme / (e - 1) + tail
    small = np.flatnonzero(~big)
    if small.size:
        values, inverse = np.unique(z[small], return_inverse=True)
        out[small] = np.array([_g_power_quad(float(v), float(e)) for v in values])[inverse]
    return out


@functools.lru_cache(maxsize=4096)
def _g_power_quad(z, e):
    """``G_e(z)`` for ``z < 40`` by quadrature (cached: the same small lags recur)."""
    from scipy import integrate  # its import (scipy.optimize) is slow: only when needed

    if z < 1e-6:
        return z ** (3 - e) / (2 * (3 - e))
    val, _ = integrate.quad(lambda t: (1 - np.cos(t)) * t ** (-e), 0, z, limit=200,
                            epsabs=0, epsrel=1e-11)
    return val
