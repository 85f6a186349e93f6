"""``spherex-reduce compare-strategies``: judge correction strategies on one noise and sky."""

from ..io import atomic_output
from ._common import add_dask_options, dask_run_inputs


def add_parser(sub):
    p = sub.add_parser(
        "compare-strategies",
        help="reduce the same simulated noise and injected sky with several pipelines; "
        "residual noise, white floor, sky transfer",
        description="Run COMPARE.yaml (scene:, sky:, pipelines:, realizations:, seed:, "
        "measure:): each realisation's scene is simulated once, a Gaussian random sky is "
        "added to its light-sensitive pixels, and every pipeline reduces that same exposure "
        "and the exposure without the sky. Per pipeline and realisation: the 5–20′ band power "
        "of reduced - sky, its excess over the noise model's white floor, and the fraction of "
        "the sky kept (cross-spectrum of the difference of the two reductions with the sky). "
        "Runs on an embedded dask LocalCluster, or an existing scheduler with --scheduler.")
    p.add_argument("input", metavar="COMPARE.yaml")
    p.add_argument("-o", "--output", required=True, metavar="RESULTS.ecsv")
    p.add_argument("--plot", nargs="?", const=True, metavar="PNG",
                   help="residual P(k) and sky transfer T(k) per pipeline (default: OUTPUT "
                   "with .png)")
    add_dask_options(p)
    p.add_argument("--overwrite", action="store_true", help="replace OUTPUT (and the plot)")
    p.set_defaults(func=run)


def run(args):
    from ..analysis.compare import compare_strategies, format_summary, load_comparison

    comparison = load_comparison(args.input)
    plot = dask_run_inputs(args, "comparison")
    for path in (args.output, plot):
        if path:
            atomic_output(path, args.overwrite)  # refuse an existing output before any work
    res = compare_strategies(comparison, args.output, plot=plot, scheduler=args.scheduler,
                             workers=args.workers, overwrite=args.overwrite,
                             progress=not args.quiet)
    print(format_summary(res.table))
    print(f"wrote {args.output}" + (f" and {plot}" if plot else "") +
          f" ({res.seconds:.1f} s)")
    return 0
