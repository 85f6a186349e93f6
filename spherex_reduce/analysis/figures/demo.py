"""The demonstration run behind ``spherex-reduce demo``: the paper's case end to end."""

import os
from pathlib import Path

from astropy import units as u
from astropy.table import Table

from ...io import atomic_output, write
from ...io.plotting import plot_images, plot_read_order, save_figure
from .. import (
    SpectrumMeasure,
    as_pipeline,
    band_label,
    band_theta,
    photon_noise_label,
    photon_noise_power,
    run_case,
)
from ..spectrum import SPECTRUM_COLUMNS
from .plots import plot_spectra

__all__ = ["PRODUCTS", "RAW_PRODUCTS", "run_demo"]

#: Files the demo writes into its output directory.
PRODUCTS = (
    "reduced_chopped.fits", "reduced_unchopped.fits", "spectra.ecsv", "spectra.png",
    "images.png", "read_order.png",
)
#: The raw files it simulates and reduces from, kept only when asked (``keep_raw``:
#: 1.28 GB each at full size).
RAW_PRODUCTS = ("raw_chopped.fits", "raw_unchopped.fits")


def _scene(size, nframes, skip, seed):
    nch = max(1, min(32, size // 64))
    return {
        "geometry": {"nrows": size, "ncols": size, "nchannels": nch, "ref_border": 4},
        "readout": {"skip": skip, "ref_reads": 32, "ref_mode": "distributed",
                    "phantom_reads": 4, "nframes": nframes},
        "output": {"mode": "ramps"},
        "seed": seed,
    }


def run_demo(outdir, overwrite=False, progress=True, size=2048, nframes=74, seed=2024,
             keep_raw=False):
    """Simulate, reduce and measure the paper's case; yields lines of a summary.

    Two exposures with every noise term of the paper's Table 2 are simulated
    as raw ramps: the paper's readout (S = 24, r = 32 distributed, c = 4) and
    the same array read in physical row order (S = 1).  The first is reduced
    with the shipped ``spherex-default`` pipeline (phantom and reference
    correction), the second with the shipped ``phantom-only`` (no reference
    correction).  Their spatial power
    spectra are compared with the photon noise of 1 e/s Zodiacal light over
    the integration.

    Parameters
    ----------
    outdir : path
        Directory for the products (:data:`PRODUCTS`); created if needed.
    overwrite : bool
        Replace existing products; otherwise an existing one stops the demo
        before any work.
    progress : bool
        Show progress bars.
    size : int
        Array size in pixels (2048 = SPHEREX; smaller for a quick look).
    nframes : int
        Frames up the ramp (74 in the paper).
    seed : int
        Seed of both simulations.
    keep_raw : bool
        Keep the simulated raw files (:data:`RAW_PRODUCTS`) in ``outdir``;
        otherwise each is simulated into a temporary file there, reduced and
        removed.
    """
    outdir = Path(outdir)
    outdir.mkdir(parents=True, exist_ok=True)
    products = (*RAW_PRODUCTS, *PRODUCTS) if keep_raw else PRODUCTS
    for name in products:  # refuse before doing any work
        atomic_output(outdir / name, overwrite)
    cases = {"chopped": (24, as_pipeline("spherex-default")),
             "unchopped": (1, as_pipeline("phantom-only"))}
    spectra, reduced, summary, measures = {}, {}, {}, {}
    for label, (skip, pipeline) in cases.items():
        # simulated into a file and reduced from it, frame by frame: full size fits in memory
        raw = outdir / (f"raw_{label}.fits" if keep_raw else f".raw_{label}.{os.getpid()}.fits")
        try:
            case = run_case(_scene(size, nframes, skip, seed), {label: pipeline},
                            SpectrumMeasure(), seed=seed, raw_path=raw,
                            overwrite=overwrite or not keep_raw, progress=progress, keep=True)
        finally:
            if not keep_raw:
                raw.unlink(missing_ok=True)
        result, measured = case.reduced[label], case.measured[label]
        write(result, outdir / f"reduced_{label}.fits", overwrite=overwrite)
        reduced[label] = result
        spectra[label] = measured["spectrum"]
        summary[label] = measured["band_power"]  # as ``spherex-reduce spectrum`` measures it
        measures[label] = measured
        if label == "chopped":
            schedule = result.schedule
            yield schedule.summary()
        yield (f"{label}: simulated raw ramps (S={skip}), reduced with {pipeline.source}; "
               f"band power = {summary[label]:.4g}")
    photon = photon_noise_power(1 * u.electron / u.s, schedule=schedule)
    table = Table({"k": spectra["chopped"]["k"], "theta": spectra["chopped"]["theta"]})
    for label, t in spectra.items():
        for name in ("power", "power_err"):
            table[f"{name}_{label}"] = t[name]
            table[f"{name}_{label}"].description = (f"{SPECTRUM_COLUMNS[name]}; the {label} "
                                                    "case")
    table["nmodes"] = spectra["chopped"]["nmodes"]
    for name in ("k", "theta", "nmodes"):
        table[name].description = SPECTRUM_COLUMNS[name]
    # numbers as ``spectrum`` and ``forecast`` write them: floats, in the unit of the power
    # columns, named by band_power_unit
    unit = table["power_chopped"].unit
    table.meta.update({
        "band": band_label(),
        "band_theta_exact": band_theta(),
        **{f"{name}_{label}": _value(measured[name], unit)
           for label, measured in measures.items() for name in ("band_power", "band_power_err")},
        "band_power_unit": unit.to_string(),
        "photon_noise_power": _value(photon, unit),
        "photon_noise": "1 e/s Zodiacal light, least-squares slope over the schedule's reads "
                        f"({schedule.nframes} reads, {schedule.integration_time:.4g})",
    })
    with atomic_output(outdir / "spectra.ecsv", overwrite) as tmp:
        table.write(tmp, format="ascii.ecsv")
    labels = {"chopped": "S=24, r=32 distributed, phantom + reference corrected",
              "unchopped": "S=1, phantom corrected only"}
    fig = plot_spectra({labels[k]: v for k, v in spectra.items()}, photon=photon,
                       photon_label=photon_noise_label(1 * u.electron / u.s, schedule=schedule),
                       title=f"{size}x{size}, N={nframes}: spatial power spectra")
    save_figure(fig, outdir / "spectra.png", overwrite)
    save_figure(_images(reduced, labels), outdir / "images.png", overwrite)
    save_figure(plot_read_order(schedule), outdir / "read_order.png", overwrite)
    ratio = (summary["unchopped"] / summary["chopped"]).decompose().value
    yield (f"band power {band_label()}: {summary['unchopped']:.4g} uncorrected -> "
           f"{summary['chopped']:.4g} with chopping and reference correction "
           f"({ratio:.1f}x lower); photon noise of 1 e/s: {photon:.4g}")
    for name in products:
        yield f"wrote {outdir / name}"


def _value(quantity, unit):
    """A band power for the table's meta: its value in ``unit``, or None (YAML null)."""
    return None if quantity is None else float(u.Quantity(quantity).to_value(unit))


def _images(reduced, labels):
    """The reduced images side by side, on one grey scale (block means if large)."""
    return plot_images({labels[k]: e.to_ccddata() for k, e in reduced.items()},
                       title="reduced slope images, one grey scale (1–99 % of both)")
