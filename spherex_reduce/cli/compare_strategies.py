"""``spherex-reduce compare-strategies``: judge correction strategies on one noise and sky."""

from pathlib import Path

from ..io import atomic_output
from ..limits import MAX_WORKERS
from ._common import check_paths, count, named_files


def add_parser(sub):
    p = sub.add_parser(
        "compare-strategies",
        help="reduce the same simulated noise and injected sky with several pipelines; "
        "residual noise, white floor, sky transfer",
        description="Run COMPARE.yaml (scene:, sky:, pipelines:, realizations:, seed:, "
        "measure:): each realisation's scene is simulated once, a Gaussian random sky is "
        "added to its light-sensitive pixels, and every pipeline reduces that same exposure. "
        "Per pipeline and realisation: the 5-20' band power of reduced - sky, its excess over "
        "the noise model's white floor, and the fraction of the sky kept (cross-spectrum). "
        "Runs on an embedded dask LocalCluster, or an existing scheduler with --scheduler.")
    p.add_argument("input", metavar="COMPARE.yaml")
    p.add_argument("-o", "--output", required=True, metavar="RESULTS.ecsv")
    p.add_argument("--plot", nargs="?", const=True, metavar="PNG",
                   help="residual P(k) and sky transfer T(k) per pipeline (default: OUTPUT "
                   "with .png)")
    p.add_argument("--scheduler", metavar="ADDRESS",
                   help="dask scheduler address (tcp://host:8786); 'serial' runs in-process")
    p.add_argument("--workers", type=count(MAX_WORKERS), default=2,
                   help="worker processes of the embedded LocalCluster (default 2)")
    p.add_argument("--overwrite", action="store_true", help="replace OUTPUT (and the plot)")
    p.set_defaults(func=run)


def run(args):
    from ..analysis.compare import compare_strategies, format_summary, load_comparison
    from ..analysis.scheduler import check_scheduler, quiet_dask_logs
    from ..config import load_yaml

    if not args.verbose:  # dask's INFO lines about workers and connections
        quiet_dask_logs()
    comparison = load_comparison(args.input)
    plot = args.plot
    if plot is True:
        plot = str(Path(args.output).with_suffix(".png"))
    # the comparison file, and the scene and pipeline files it names
    named = load_yaml(args.input, "comparison")[0]
    check_paths([args.input, *named_files(named, Path(args.input).parent)],
                [args.output, plot])
    for path in (args.output, plot):
        if path:
            atomic_output(path, args.overwrite)  # refuse an existing output before any work
    check_scheduler(args.scheduler, name="--scheduler")
    res = compare_strategies(comparison, args.output, plot=plot, scheduler=args.scheduler,
                             workers=args.workers, overwrite=args.overwrite,
                             progress=not args.quiet)
    print(format_summary(res.table))
    print(f"wrote {args.output}" + (f" and {plot}" if plot else "") +
          f" ({res.seconds:.1f} s)")
    return 0
