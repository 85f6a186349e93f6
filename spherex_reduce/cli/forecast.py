"""``spherex-reduce forecast``: the expected P(k) of a scene's reduced slope image."""

import contextlib
import math
import threading
from pathlib import Path

from astropy import units as u

from ..core.errors import FormatError
from ._common import (
    all_or_nothing,
    check_paths,
    count,
    input_config,
    nonnegative_float,
    plot_path,
    positive_float,
)
from .spectrum import band_meta, check_band

#: What the table's ``source`` says when no scene file is given.
PAPER_CASE = "the paper's case (every scene key at its default)"
#: The unit of P(k) and the band power of a slope image.
_POWER = u.electron**2 / u.s**2 * u.pix**2


def add_parser(sub):
    p = sub.add_parser(
        "forecast", help="expected P(k) of a scene reduced by a pipeline, exact, no simulation",
        description="Compute the expected P(k) of the slope image of SCENE.yaml (as "
        "simulate takes it; default: the paper's case) reduced by the pipeline -c, total and "
        "per noise component, without random numbers, and write it as ECSV with the columns "
        "and meta of spectrum's output (power_<component> columns added; band_power in the "
        "meta, band_power_err the standard error one realisation's band power would have), "
        "so the two tables line up bin by bin. Every pipeline step must be linear: a step "
        "the forecast cannot propagate is refused, naming it.")
    p.add_argument("scene", metavar="SCENE.yaml", nargs="?", default=None,
                   help="scene file (default: the paper's case)")
    p.add_argument("-c", "--config", required=True, metavar="PIPELINE.yaml",
                   help="the reduction, as reduce -c takes it: a pipeline YAML file or a "
                   "shipped config name (e.g. spherex-default; unchop for the uncorrected "
                   "image)")
    p.add_argument("-o", "--output", required=True, metavar="FORECAST.ecsv")
    p.add_argument("--plot", nargs="?", const=True, metavar="PNG",
                   help="draw P(k), total and per component (default name: the output with "
                   ".png)")
    p.add_argument("--compare", metavar="MEASURED.ecsv",
                   help="a spectrum output drawn over the forecast with its error bars, its "
                   "band power compared on the terminal; it must have been measured in the "
                   "forecast's band, with its --exclude-horizontal and on an image of its "
                   "shape (refused otherwise)")
    p.add_argument("--bins", type=count(10_000), default=None,
                   help="log-spaced k bins (default: a sweep measure's, 30)")
    p.add_argument("--kmin", type=nonnegative_float, default=None,
                   help="band lower edge, rad/pixel (default: the paper's band, 5–20′)")
    p.add_argument("--kmax", type=nonnegative_float, default=None,
                   help="band upper edge, rad/pixel (default: the paper's band)")
    p.add_argument("--exclude-horizontal", action="store_true",
                   help="leave out the k_y = 0 axis of the Fourier plane (paper Fig. 6)")
    p.add_argument("--pixel-scale", type=positive_float, default=6.2, metavar="ARCSEC",
                   help="pixel scale in arcsec, for θ (default 6.2, SPHEREx)")
    p.add_argument("--overwrite", action="store_true", help="replace existing outputs")
    p.set_defaults(func=run)


def run(args):
    from ..analysis import forecast
    from ..analysis.case import SpectrumMeasure, measure_section
    from ..simulation import load_scene

    plot = plot_path(args)
    given = {key: getattr(args, key) for key in ("bins", "kmin", "kmax")
             if getattr(args, key) is not None}
    if args.exclude_horizontal:
        given["exclude_horizontal"] = True
    check_band(given.get("kmin", SpectrumMeasure.kmin), given.get("kmax", SpectrumMeasure.kmax))
    measure = SpectrumMeasure(**measure_section(given, "forecast"))
    pipeline, config_files = input_config(args.config)
    check_paths([args.scene, args.compare, *config_files], [args.output, plot])
    with all_or_nothing([args.output, plot], args.overwrite) as (tmp, tmp_plot):
        scene = load_scene(args.scene)
        measured = measured_band = None
        if args.compare:
            measured, measured_band = _read_measured(args.compare)
            _check_measured_like(measured.meta, args.compare, measure)
        scale = args.pixel_scale * u.arcsec
        with _ticking(not args.quiet):
            table = forecast(scene, pipeline, measure, pixel_scale=scale)
        if measured is not None:
            _check_measured_like(measured.meta, args.compare, measure, table.meta["shape"])
        unit = u.Quantity(table["power"]).unit
        band = err = None
        if table.meta["band_power"] is not None:
            band, err = table.meta["band_power"] * unit, table.meta["band_power_err"] * unit
        table.meta.update({
            "source": PAPER_CASE if args.scene is None else str(args.scene),
            **band_meta(measure.kmin, measure.kmax, args.pixel_scale, band, err, unit),
            "config": pipeline.source,
        })
        if band is None:
            table.meta["band_power_missing"] = "no Fourier mode of the image is in the band"
        lines = [f"{table.meta['source']} reduced by {pipeline.source}: forecast band power "
                 f"{table.meta['band']} = {_text(band, err)}; pixel variance "
                 f"{table.meta['variance']:.4g} {(unit / u.pix**2).to_string()}"]
        if measured is not None:
            lines.append(_comparison(measured_band, args.compare, band, unit))
        table.write(tmp, format="ascii.ecsv")
        if plot:
            from ..analysis import photon_noise_label, photon_noise_power
            from ..analysis.figures.plots import plot_forecast
            from ..io.plotting import save_figure

            zodi = 1 * u.electron / u.s  # the spectrum plot's photon-noise line, over this scene
            fig = plot_forecast(table, measured, measured_label=Path(args.compare).name
                                if measured is not None else None, pixel_scale=scale,
                                photon=photon_noise_power(zodi, schedule=scene.schedule),
                                photon_label=photon_noise_label(zodi, schedule=scene.schedule))
            save_figure(fig, tmp_plot)
    lines.append(f"wrote {args.output}")
    if plot:
        lines.append(f"wrote {plot}")
    print("\n".join(lines))


def _text(band, err):
    if band is None:
        return "missing (no Fourier mode of the image is in the band)"
    return f"{band.value:.4g} {band.unit} (one realisation: ± {err.value:.2g})"


def _read_measured(path):
    """A ``spectrum`` output (``k``, ``power``, ``power_err`` with units) and its band power
    and standard error in `_POWER` (None: missing), or FormatError naming the file and key."""
    from astropy.table import Table

    try:
        table = Table.read(path, format="ascii.ecsv")
    except (ValueError, TypeError, KeyError, IndexError, UnicodeError) as exc:
        raise FormatError(f"--compare: {path}: not an ECSV table: {exc}") from None
    missing = [c for c in ("k", "power", "power_err") if c not in table.colnames]
    if missing:
        raise FormatError(f"--compare: {path}: no column {', '.join(missing)}; expected "
                          "the output of spectrum")
    for name, unit in (("k", u.rad / u.pix), ("power", _POWER), ("power_err", _POWER)):
        if not (table[name].unit or u.one).is_equivalent(unit):
            raise FormatError(f"--compare: {path}: column {name} is in "
                              f"{table[name].unit or 'no unit'}, expected {unit}")
    return table, _measured_band(table.meta, path)


def _measured_band(meta, path):
    """``(band_power, band_power_err)`` of a ``spectrum`` output's meta in `_POWER` (None:
    missing), or FormatError naming the file and the key."""
    text = meta.get("band_power_unit")
    try:
        unit = _POWER if text is None else u.Unit(text)
    except (ValueError, TypeError):
        raise FormatError(f"--compare: {path}: band_power_unit: {text!r} is not a unit; "
                          f"expected {_POWER}") from None
    if not unit.is_equivalent(_POWER):
        raise FormatError(f"--compare: {path}: band_power_unit: {unit}, expected {_POWER}")
    out = []
    for key in ("band_power", "band_power_err"):
        value = meta.get(key)
        if value is not None and (isinstance(value, bool) or not isinstance(value, (int, float))
                                  or not math.isfinite(value) or value < 0):
            raise FormatError(f"--compare: {path}: {key}: expected a number >= 0 or null, "
                              f"got {value!r}")
        out.append(None if value is None else (value * unit).to_value(_POWER))
    return tuple(out)


def _check_measured_like(meta, path, measure, shape=None):
    """Refuse (FormatError, one line) a ``spectrum`` output measured in another band, with or
    without the horizontal axis unlike the forecast's ``measure``, or (``shape`` given: the
    forecast's light-sensitive image) on an image of another shape: its band power would be
    compared with a forecast of something else."""
    keys = ("band_kmin", "band_kmax", "exclude_horizontal", "shape")
    missing = [k for k in keys if k not in meta]
    if missing:
        raise FormatError(f"--compare: {path}: no {', '.join(missing)} in its meta; expected "
                          "the output of spectrum, which records the band and options it "
                          "measured with")
    for key in ("band_kmin", "band_kmax"):
        value = meta[key]
        if isinstance(value, bool) or not isinstance(value, (int, float)) \
                or not math.isfinite(value):
            raise FormatError(f"--compare: {path}: {key}: expected a number, got {value!r}")
    if not isinstance(meta["exclude_horizontal"], bool):
        raise FormatError(f"--compare: {path}: exclude_horizontal: expected true or false, got "
                          f"{meta['exclude_horizontal']!r}")
    kmin, kmax = meta["band_kmin"], meta["band_kmax"]
    if not (math.isclose(kmin, measure.kmin, rel_tol=1e-9)
            and math.isclose(kmax, measure.kmax, rel_tol=1e-9)):
        raise FormatError(f"--compare: {path} was measured in the band {kmin:g} to {kmax:g} "
                          f"rad/pixel, the forecast's is {measure.kmin:g} to {measure.kmax:g}: "
                          f"give the forecast --kmin {kmin:g} --kmax {kmax:g}")
    if meta["exclude_horizontal"] != bool(measure.exclude_horizontal):
        measured, forecast = ("with", "without") if meta["exclude_horizontal"] else \
            ("without", "with")
        raise FormatError(f"--compare: {path} was measured {measured} --exclude-horizontal, "
                          f"the forecast {forecast}: give it to both or neither")
    got = meta["shape"]
    if shape is not None and (not isinstance(got, list) or list(got) != list(shape)):
        what = (" x ".join(map(str, got)) if isinstance(got, list) else repr(got))
        raise FormatError(f"--compare: {path} was measured on a {what} image, the forecast is "
                          f"of the scene's {shape[0]} x {shape[1]} light-sensitive pixels")


def _comparison(measured_band, path, band, unit):
    """The terminal line comparing a measured band power and its error (`_POWER`) with the
    forecast ``band`` (a Quantity in ``unit``, or None)."""
    value, err = measured_band
    if band is None or value is None or not err:
        return f"{path}: no band power to compare"
    value, err = (value * _POWER).to_value(unit), (err * _POWER).to_value(unit)
    return (f"{path}: measured band power {value:.4g} ± {err:.2g}: {value / band.value:.4g}× "
            f"the forecast ({(value - band.value) / err:+.1f} standard errors)")


@contextlib.contextmanager
def _ticking(enabled):
    """The seconds spent so far, on a terminal, once the block has taken a second."""
    from ..reduce.progress import terminal_bar

    bar = terminal_bar(enabled, desc="forecast", leave=False, delay=1.0,
                       bar_format="{desc}: {elapsed}")
    stop = threading.Event()
    refresh = getattr(bar, "refresh", None)  # None: no bar (not a terminal, or -q)

    shown = []

    def tick():
        if not stop.wait(1.0):
            while not stop.wait(0.5):
                refresh()
                shown.append(True)

    thread = threading.Thread(target=tick, daemon=True)
    if refresh is not None:
        thread.start()
    try:
        yield
    finally:
        stop.set()
        if refresh is not None:
            thread.join()
        if shown:  # a bar drawn by refresh alone is not erased by close
            bar.clear()
        bar.close()
