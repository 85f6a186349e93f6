"""The photon noise of a slope image: the Zodiacal-light line of the paper's Fig. 13.

`photon_noise_power` is the flat spatial power of the Poisson noise of
up-the-ramp slopes (`slope_variance_factor` for a least-squares fit),
`photon_noise_label` the legend that names the photocurrent and the time.
"""

from astropy import units as u

from ..core.errors import SpherexReduceError

__all__ = ["photon_noise_label", "photon_noise_power", "slope_variance_factor"]


def slope_variance_factor(nframes):
    """Photon-noise variance of a least-squares up-the-ramp slope, in units of ``i / t_frame``.

    For ``N`` reads spaced ``t_frame`` apart of a Poisson charge accumulating
    at ``i`` e/s, the uniformly weighted least-squares slope has variance
    ``6 (N² + 1) / (5 N (N² − 1)) · i / t_frame`` (the photon term of the
    standard up-the-ramp noise formula; ``N = 2`` gives ``i / t_frame``).

    Examples
    --------
    >>> from spherex_reduce.analysis import slope_variance_factor
    >>> slope_variance_factor(2)
    1.0
    >>> round(slope_variance_factor(74), 5)
    0.01622
    """
    n = int(nframes)
    if n < 2:
        raise SpherexReduceError(f"a slope needs nframes >= 2, got {nframes}")
    return 6 * (n**2 + 1) / (5 * n * (n**2 - 1))


def photon_noise_power(photocurrent=1 * u.electron / u.s, integration_time=None, *,
                       nframes=None, schedule=None):
    """White spatial power of the photon noise of a slope image (paper Fig. 13).

    Every pixel's slope carries independent Poisson noise, so the spectrum is
    flat at the slope variance (image unit² · pixel²).

    Parameters
    ----------
    photocurrent : `~astropy.units.Quantity`
        Signal in e/s (e.g. Zodiacal light ≈ 1 e/s); plain numbers are e/s.
    integration_time : `~astropy.units.Quantity`, optional
        Total time ``T`` (s).  Without ``nframes`` the slope is taken as the
        charge collected over ``T`` divided by ``T`` (variance ``i / T``).
    nframes : int, optional
        Reads up the ramp ``N``: the slope is the least-squares fit to ``N``
        reads ``T / N`` apart (variance `slope_variance_factor` ``· i N / T``,
        about 1.2 ``i / T`` for large ``N``).
    schedule : `~spherex_reduce.ReadoutSchedule`, optional
        Takes ``N`` and ``T`` from the schedule.

    Returns
    -------
    power : `~astropy.units.Quantity`
        In (photocurrent unit)² · pixel².

    Examples
    --------
    >>> from astropy import units as u
    >>> from spherex_reduce.analysis import photon_noise_power
    >>> photon_noise_power(1 * u.electron / u.s, 112 * u.s)
    <Quantity 0.00892857 electron2 pix2 / s2>
    >>> photon_noise_power(1 * u.electron / u.s, 111.74 * u.s, nframes=74).round(5)
    <Quantity 0.01074 electron2 pix2 / s2>
    """
    i = u.Quantity(photocurrent, u.electron / u.s) if not isinstance(
        photocurrent, u.Quantity) else photocurrent
    if schedule is not None:
        nframes = schedule.nframes if nframes is None else nframes
        integration_time = schedule.integration_time if integration_time is None \
            else integration_time
    if integration_time is None:
        raise SpherexReduceError("photon_noise_power needs integration_time or a schedule")
    t = u.Quantity(integration_time, u.s)
    if t.value <= 0:
        raise SpherexReduceError(f"integration_time must be positive, got {t}")
    charge_rate = i.to(u.electron / u.s)
    if nframes is None:
        var = charge_rate.value / t.value
    else:
        tframe = t.value / int(nframes)
        var = slope_variance_factor(nframes) * charge_rate.value / tframe
    return (var * (u.electron / u.s) ** 2).to(i.unit**2) * u.pix**2


def photon_noise_label(photocurrent=1 * u.electron / u.s, integration_time=None, *,
                       nframes=None, schedule=None):
    """Legend of a photon-noise line: the photocurrent and the time it is integrated for.

    Takes the arguments of `photon_noise_power`.

    Examples
    --------
    >>> from astropy import units as u
    >>> from spherex_reduce.analysis import photon_noise_label
    >>> photon_noise_label(1 * u.electron / u.s, 111.74 * u.s, nframes=74)
    'photon noise of 1 e/s over 112 s (N = 74)'
    """
    if schedule is not None:
        nframes = schedule.nframes if nframes is None else nframes
        integration_time = schedule.integration_time if integration_time is None \
            else integration_time
    i = u.Quantity(photocurrent, u.electron / u.s)
    text = f"photon noise of {i.to_value(u.electron / u.s):.3g} e/s"
    if integration_time is not None:
        text += f" over {u.Quantity(integration_time, u.s).to_value(u.s):.3g} s"
    return text + (f" (N = {int(nframes)})" if nframes else "")
