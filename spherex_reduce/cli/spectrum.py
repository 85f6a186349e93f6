"""``spherex-reduce spectrum``: the spatial power spectrum P(k) of an image."""

import logging
from pathlib import Path

import numpy as np
from astropy import units as u
from astropy.table import join

from ..core.errors import SpherexReduceError
from ..io import atomic_output
from ._common import (
    add_config_option,
    all_or_nothing,
    check_paths,
    count,
    finite_float,
    input_config,
    nonnegative_float,
    plot_path,
    positive_float,
)

log = logging.getLogger(__name__)

_DEFAULT_TINT = 111.74  # s: N = 74 frames of 1.51 s (paper Table 3)


def add_parser(sub):
    p = sub.add_parser(
        "spectrum", help="azimuthally averaged power spectrum P(k) of an image",
        description="Measure P(k) of IMAGE.fits (k in rad/pixel, k = 2π·pixel scale/θ), write "
        "it as ECSV (columns k theta power power_err nmodes; in the meta the 5–20′ band power, "
        "null with a warning when no Fourier mode of the image falls in the band, and "
        "band_theta_exact, the θ range the band's k limits give on the pixel scale) and "
        "optionally plot it with the band shaded and the photon-noise line. Images in "
        "readout order are un-chopped first; an image in this package's format is measured "
        "on its light-sensitive pixels (the reference pixels left out).")
    p.add_argument("input", metavar="IMAGE.fits")
    p.add_argument("-o", "--output", required=True, metavar="SPECTRUM.ecsv")
    add_config_option(p)
    p.add_argument("--plot", nargs="?", const=True, metavar="PNG",
                   help="draw P(k) (default name: the output with .png)")
    p.add_argument("--compare", metavar="OTHER.fits",
                   help="a second image measured on the same bins (columns *_compare)")
    p.add_argument("--bins", type=count(10_000), default=30, help="log-spaced k bins (default 30)")
    p.add_argument("--pixel-scale", type=positive_float, default=6.2, metavar="ARCSEC",
                   help="pixel scale in arcsec (default 6.2, SPHEREx)")
    p.add_argument("--kmin", type=finite_float, default=0.03, help="band lower edge (rad/pixel)")
    p.add_argument("--kmax", type=finite_float, default=0.13, help="band upper edge (rad/pixel)")
    p.add_argument("--mask-sources", action="store_true",
                   help="mask sources and hot pixels (photutils segmentation) first")
    p.add_argument("--exclude-horizontal", action="store_true",
                   help="leave out the k_y = 0 axis of the Fourier plane (paper Fig. 6)")
    p.add_argument("--photocurrent", type=nonnegative_float, default=1.0, metavar="E_PER_S",
                   help="photocurrent of the photon-noise line in e/s (default 1, Zodiacal "
                   "light); 0 for none")
    p.add_argument("--integration-time", type=positive_float, default=None, metavar="S",
                   help="integration time of the photon-noise line (default: from the file, "
                   f"else {_DEFAULT_TINT} s)")
    p.add_argument("--overwrite", action="store_true", help="replace existing outputs")
    p.set_defaults(func=run)


def _measure(image, args, path, bins=None):
    """P(k) of ``image``, its band power and error, and None; or, when no Fourier mode of the
    image is in the band, P(k), None, None and why (logged as a warning)."""
    from ..analysis import EmptyBandError, band_power, power_spectrum

    scale = args.pixel_scale * u.arcsec
    kw = {"pixel_scale": scale, "mask_sources": args.mask_sources,
          "exclude_horizontal": args.exclude_horizontal}
    table = power_spectrum(image, bins=args.bins if bins is None else bins, **kw)
    try:
        band, err = band_power(image, args.kmin, args.kmax, return_error=True, **kw)
    except EmptyBandError as exc:
        log.warning("%s: band power missing: %s", path, exc)
        return table, None, None, str(exc)
    return table, band, err, None


def check_band(kmin, kmax):
    """Refuse a band whose ``--kmin`` is not below its ``--kmax`` (rad/pixel).

    Raises
    ------
    SpherexReduceError
        Naming both options.

    Examples
    --------
    >>> from spherex_reduce.cli.spectrum import check_band
    >>> check_band(0.03, 0.13)
    >>> check_band(0.2, 0.1)
    Traceback (most recent call last):
    ...
    spherex_reduce.core.errors.SpherexReduceError: --kmin (0.2) must be below --kmax (0.1)
    """
    if kmin >= kmax:
        raise SpherexReduceError(f"--kmin ({kmin}) must be below --kmax ({kmax})")


def band_meta(kmin, kmax, pixel_scale, band, err, unit):
    """The band's entries of a P(k) table's meta, as ``spectrum`` and ``forecast`` write them.

    Parameters
    ----------
    kmin, kmax : float
        The band, rad/pixel.
    pixel_scale : float
        Arcsec per pixel.
    band, err : `~astropy.units.Quantity` or None
        The band power and its standard error (None: missing, written as null).
    unit : `~astropy.units.Unit`
        The unit of ``power``.

    Returns
    -------
    dict
        ``band`` (the nominal band), ``band_kmin``, ``band_kmax``,
        ``band_theta_exact`` (the θ the k limits give), ``band_power``,
        ``band_power_err``, ``band_power_unit``.

    Examples
    --------
    >>> from astropy import units as u
    >>> from spherex_reduce.cli.spectrum import band_meta
    >>> unit = u.electron**2 / u.s**2 * u.pix**2
    >>> m = band_meta(0.03, 0.13, 6.2, 2.5e-3 * unit, 1e-4 * unit, unit)
    >>> m["band"], m["band_power"], m["band_power_unit"]
    ('5–20′ (0.03 ≤ k ≤ 0.13 rad/pixel)', 0.0025, 'electron2 pix2 / s2')
    """
    from ..analysis import band_label, band_theta

    scale = pixel_scale * u.arcsec
    return {"band": band_label(kmin, kmax, scale), "band_kmin": kmin, "band_kmax": kmax,
            "band_theta_exact": band_theta(kmin, kmax, scale), "band_power": _value(band),
            "band_power_err": _value(err), "band_power_unit": u.Unit(unit).to_string()}


def _value(quantity):
    """A band power for the table's meta: its value, or None (YAML null) when missing."""
    return None if quantity is None else float(quantity.value)


def _text(band, err):
    return "missing" if band is None else f"{band.value:.4g} ± {err.value:.2g} {band.unit}"


def _photon(image, args):
    from ..analysis import photon_noise_label, photon_noise_power

    if not args.photocurrent:
        return None, None
    if not (image.unit or u.one).is_equivalent(u.electron / u.s):
        return None, None
    nframes = image.meta.get("NFRAMES")
    tint = args.integration_time
    if tint is None:
        tint = image.meta.get("INTTIME") or _DEFAULT_TINT
    kw = {"nframes": nframes if nframes and nframes >= 2 else None}
    power = photon_noise_power(args.photocurrent * u.electron / u.s, tint * u.s, **kw)
    label = photon_noise_label(args.photocurrent * u.electron / u.s, tint * u.s, **kw)
    return power.to(image.unit**2 * u.pix**2), label


def run(args):
    from ..analysis.io import read_image

    check_band(args.kmin, args.kmax)
    plot = plot_path(args)
    pipeline, config_files = input_config(args.config)
    check_paths([args.input, args.compare, *config_files], [args.output, plot])
    for path in (args.output, plot):
        if path:
            atomic_output(path, args.overwrite)
    image = read_image(args.input, pipeline=pipeline, light=True)
    table, band, err, missing = _measure(image, args, args.input)
    table.meta.update({"source": str(args.input),
                       **band_meta(args.kmin, args.kmax, args.pixel_scale, band, err,
                                   u.Quantity(table["power"]).unit)})
    band_text = table.meta["band"]
    if missing:
        table.meta["band_power_missing"] = missing
    if pipeline is not None:
        table.meta["config"] = pipeline.source
    if "SXRCKBAD" in image.meta:  # read with --ignore-checksum: say so in the output
        table.meta["input_checksum_failed"] = str(image.meta["SXRCKBAD"])
    photon, photon_label = _photon(image, args)
    if photon is not None:
        table.meta["photon_noise_power"] = float(photon.value)
        table.meta["photocurrent_e_per_s"] = args.photocurrent
    lines = [f"{args.input}: band power {band_text} = {_text(band, err)}"]
    spectra = {Path(args.input).name: table}
    if args.compare:
        other = read_image(args.compare, pipeline=pipeline, light=True)
        if not (other.unit or u.one).is_equivalent(image.unit or u.one):
            raise SpherexReduceError(
                f"--compare: {args.compare} is in {other.unit or 'no unit'}, but {args.input} "
                f"is in {image.unit or 'no unit'}; compare images of the same quantity")
        edges = np.unique(np.concatenate([table["k_lo"], table["k_hi"]]))
        ot, oband, oerr, omissing = _measure(other, args, args.compare, bins=edges)
        spectra[Path(args.compare).name] = ot
        sub = ot["k_lo", "power", "power_err", "nmodes"]
        for c in ("power", "power_err", "nmodes"):
            sub.rename_column(c, f"{c}_compare")
        meta = table.meta
        table = join(table, sub, keys="k_lo", join_type="left")
        table.sort("k")
        table.meta.update(meta)
        table.meta.update({"compare": str(args.compare), "band_power_compare": _value(oband),
                           "band_power_compare_err": _value(oerr)})
        if omissing:
            table.meta["band_power_compare_missing"] = omissing
        if "SXRCKBAD" in other.meta:
            table.meta["compare_checksum_failed"] = str(other.meta["SXRCKBAD"])
        ratio = ""
        if band is not None and oband is not None:
            ratio = f" (ratio {(band / oband).to_value(u.one) if oband.value else np.inf:.3g})"
        lines.append(f"{args.compare}: band power = {_text(oband, oerr)}{ratio}")
    if photon is not None:
        lines.append(f"photon noise of {args.photocurrent:g} e/s: {photon.value:.4g} {photon.unit}")
    with all_or_nothing([args.output, plot], args.overwrite) as (tmp, tmp_plot):
        table.write(tmp, format="ascii.ecsv")
        if plot:
            from ..analysis.figures.plots import plot_spectra
            from ..io.plotting import save_figure, unit_label

            title = "P(k), band power missing" if band is None else \
                f"P(k), band power {band.value:.3g} {unit_label(band.unit)}"
            fig = plot_spectra(spectra, band=(args.kmin, args.kmax), photon=photon,
                               photon_label=photon_label, title=title,
                               pixel_scale=args.pixel_scale * u.arcsec)
            save_figure(fig, tmp_plot)
    lines.append(f"wrote {args.output}")
    if plot:
        lines.append(f"wrote {plot}")
    print("\n".join(lines))
