"""``spherex-reduce fit-noise``: fit α + β/f + γ/f^1.3 to the streams of a raw file."""

from pathlib import Path

from ..io import atomic_output
from ._common import (
    add_config_option,
    all_or_nothing,
    check_paths,
    count,
    input_config,
    positive_float,
)

#: More log bins than this resolve nothing a Welch PSD holds, and take minutes.
MAX_BINS = 1000


def add_parser(sub):
    p = sub.add_parser(
        "fit-noise", help="fit the noise model of paper eq. 1 to a raw file's reference "
        "and phantom streams",
        description="Take the reference-pixel and phantom streams of RAW.fits (ramps in readout "
        "order) in time order, estimate their PSDs (Welch, within frames) and fit "
        "p(f) = alpha + beta/f + gamma/f^exponent for the pixel-rate process, with "
        "uncertainties (how the paper's Table 2 was made).")
    p.add_argument("input", metavar="RAW.fits")
    p.add_argument("-o", "--output", required=True, metavar="FIT.ecsv")
    add_config_option(p)
    p.add_argument("--plot", nargs="?", const=True, metavar="PNG",
                   help="draw the PSDs and fits (default name: the output with .png)")
    p.add_argument("--exponent", type=positive_float, default=1.3,
                   help="exponent of the third term (default 1.3, the paper's)")
    p.add_argument("--fit-exponent", action="store_true",
                   help="fit the exponent too (per stream, error from Δχ² = 1)")
    p.add_argument("--nbins", type=count(MAX_BINS), default=30,
                   help=f"log frequency bins per spectrum (default 30, at most {MAX_BINS})")
    p.add_argument("--nperseg", type=count(2**24), default=None,
                   help="Welch segment length in row reads (default: a power of two <= reads "
                   "per frame)")
    p.add_argument("--no-acn", dest="acn", action="store_false",
                   help="use all reference columns as one stream (default: even and odd "
                   "columns apart, right with or without alternating column noise)")
    p.add_argument("--overwrite", action="store_true", help="replace existing outputs")
    p.set_defaults(func=run)


def run(args):
    from ..analysis import fit_raw_noise
    from ..io import read

    plot = args.plot
    if plot is True:
        plot = str(Path(args.output).with_suffix(".png"))
    pipeline, config_files = input_config(args.config)
    check_paths([args.input, *config_files], [args.output, plot])
    for path in (args.output, plot):
        if path:
            atomic_output(path, args.overwrite)
    from ..core.errors import SpherexReduceError

    if args.nperseg is not None and args.nperseg < 4:
        raise SpherexReduceError(f"--nperseg must be >= 4 row reads, got {args.nperseg}")
    exposure = read(args.input) if pipeline is None else pipeline.read(args.input)
    exponent = None if args.fit_exponent else args.exponent
    table = fit_raw_noise(exposure, exponent=exponent, nperseg=args.nperseg,
                          nbins=args.nbins, acn=args.acn)
    fits_ = table.meta.pop("fits")
    table.meta["source"] = str(args.input)
    if pipeline is not None:
        table.meta["config"] = pipeline.source
    if "SXRCKBAD" in exposure.header:  # read with --ignore-checksum: say so in the output
        table.meta["input_checksum_failed"] = str(exposure.header["SXRCKBAD"])
    with all_or_nothing([args.output, plot], args.overwrite) as (tmp, tmp_plot):
        table.write(tmp, format="ascii.ecsv")
        if plot:
            from ..analysis.plots import plot_noise_fit
            from ..io.plotting import save_figure

            label = "fitted" if exponent is None else exponent
            save_figure(plot_noise_fit(fits_, title=f"{Path(args.input).name}: stream PSDs "
                                       f"and fits (exponent {label})"), tmp_plot)
    for row in table:
        print(f"{row['stream']:>9}: alpha = {row['alpha']:.3g} ± {row['alpha_err']:.2g}, "
              f"beta = {row['beta']:.3g} ± {row['beta_err']:.2g}, "
              f"gamma = {row['gamma']:.3g} ± {row['gamma_err']:.2g}, "
              f"exponent = {row['exponent']:.3g}"
              + (f" ± {row['exponent_err']:.2g} " if row["exponent_err"] else " ")
              + f"(chi2/dof = {row['chi2']:.1f}/{row['dof']})")
    print(f"wrote {args.output}")
    if plot:
        print(f"wrote {plot}")
