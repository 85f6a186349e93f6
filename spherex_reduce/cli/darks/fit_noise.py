"""``spherex-reduce fit-noise``: fit α + β/f + γ/f^1.3 to the streams of a raw file."""

from pathlib import Path

from ...io import atomic_output
from ...io.readers.read_files import read_file_paths
from .._common import (
    add_config_option,
    all_or_nothing,
    check_paths,
    count,
    input_config,
    plot_path,
    positive_float,
)

#: More log bins than this resolve nothing a Welch PSD holds, and take minutes.
MAX_BINS = 1000
#: Largest integration index ``--integration`` takes (a 4-D file has fewer).
MAX_INTEGRATION = 2**16


def add_parser(sub):
    p = sub.add_parser(
        "fit-noise", help="fit the noise model of paper eq. 1 to a raw file's reference "
        "and phantom streams",
        description="Take the reference-pixel and phantom streams of RAW.fits (ramps in readout "
        "order) in time order, estimate their PSDs (Welch, within frames) and fit "
        "p(f) = alpha + beta/f + gamma/f^exponent for the pixel-rate process, with "
        "uncertainties (how the paper's Table 2 was made). The streams hold reference "
        "pixels and phantom values only, never a light-sensitive pixel. A file whose SCI is "
        "4-D (integrations, groups, rows, columns) has the streams of every integration "
        "fitted together (their periodograms averaged), or one with --integration. With "
        "--reads 'DIR/read_*.fits' instead of RAW.fits, the files are the reads of one ramp.")
    p.add_argument("input", metavar="RAW.fits", nargs="?")
    p.add_argument("--reads", metavar="GLOB",
                   help="fit one ramp stored as one file per read: the files the glob matches "
                   "(quote it), in natural order (read_2 before read_10), as reduce --reads")
    p.add_argument("--integration", type=count(MAX_INTEGRATION, minimum=0), default=None,
                   metavar="K", help="of a 4-D file: fit integration K only (from 0; default: "
                   "every integration, each detrended across its own frames)")
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
    from ...analysis import fit_raw_noise
    from ...core.errors import ConfigError, SpherexReduceError
    from ...io.sources import open_input

    if (args.input is None) == (args.reads is None):
        raise ConfigError("give the input: RAW.fits, or --reads GLOB (one ramp, one file per "
                          "read), not both")
    if args.reads is not None and args.integration is not None:
        raise ConfigError("--integration picks one integration of a 4-D file; --reads is "
                          "one ramp")
    plot = plot_path(args)
    pipeline, config_files = input_config(args.config)
    what = read_file_paths(args.reads) if args.reads is not None else args.input
    inputs = what if args.reads is not None else [what]
    check_paths([*inputs, *config_files], [args.output, plot])
    for path in (args.output, plot):
        if path:
            atomic_output(path, args.overwrite)
    if args.nperseg is not None and args.nperseg < 4:
        raise SpherexReduceError(f"--nperseg must be >= 4 row reads, got {args.nperseg}")
    exponent = None if args.fit_exponent else args.exponent
    checksum_failed = []
    with (open_input(what) if pipeline is None else pipeline.open(what)) as inp:
        ks = _integrations(inp, args.integration)

        def exposures():  # one integration in memory at a time
            for k in ks:
                e = inp.source(integration=k).exposure()
                if "SXRCKBAD" in e.header:  # read with --ignore-checksum: say so
                    checksum_failed.append(str(e.header["SXRCKBAD"]))
                yield e

        table = fit_raw_noise(exposures(), exponent=exponent, nperseg=args.nperseg,
                              nbins=args.nbins, acn=args.acn)
    fits_ = table.meta.pop("fits")
    table.meta["source"] = str(args.reads if args.reads is not None else args.input)
    if args.reads is not None:
        table.meta["read_files"] = len(what)
    if ks != [None]:
        table.meta["integrations"] = ks
    if pipeline is not None:
        table.meta["config"] = pipeline.source
    if checksum_failed:
        table.meta["input_checksum_failed"] = checksum_failed[0]
    name = (Path(args.input).name if args.reads is None
            else f"{len(what)} reads {Path(what[0]).name} ...")
    if ks != [None]:
        name += (f" integration {ks[0]}" if len(ks) == 1 else f" ({len(ks)} integrations)")
    with all_or_nothing([args.output, plot], args.overwrite) as (tmp, tmp_plot):
        table.write(tmp, format="ascii.ecsv")
        if plot:
            from ...analysis.figures.plots import plot_noise_fit
            from ...io.plotting import save_figure

            label = "fitted" if exponent is None else exponent
            save_figure(plot_noise_fit(fits_, title=f"{name}: stream PSDs "
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


def _integrations(inp, k):
    """The integrations to fit: ``[None]`` for one ramp, every one of a 4-D file, or ``[k]``."""
    from ...core.errors import ConfigError

    if inp.integrations is None:
        if k is not None:
            raise ConfigError(f"--integration {k}: {inp.label} is one ramp, not a 4-D file "
                              "of integrations")
        return [None]
    if k is None:
        return list(range(inp.integrations))
    if k >= inp.integrations:
        raise ConfigError(f"--integration {k}: {inp.label} has {inp.integrations} "
                          f"integrations (0 to {inp.integrations - 1})")
    return [k]
