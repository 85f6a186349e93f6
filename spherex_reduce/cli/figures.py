"""``spherex-reduce figures``: reproduce the paper's simulated figures with a report."""

from ..core.limits import MAX_WORKERS
from ._common import count


def add_parser(sub):
    p = sub.add_parser(
        "figures", help="reproduce the paper's simulated figures (PNG + Markdown report)",
        description="Simulate, reduce and measure the paper's Figs. 4-10 and 12a; write PNGs, "
        "figures.ecsv (the numbers) and report.md (whether each claim holds, with numbers). "
        "The full version uses the paper's sizes and 5 realisations per point on a dask "
        "LocalCluster; --quick runs a reduced version in under a minute.")
    p.add_argument("-o", "--output", required=True, metavar="DIR")
    p.add_argument("--quick", action="store_true", help="reduced sizes, serial, < 1 minute")
    p.add_argument("--realizations", type=count(1000), default=None,
                   help="realisations per point (default 5; 1 with --quick)")
    p.add_argument("--scheduler", metavar="ADDRESS",
                   help="dask scheduler address; 'serial' runs in-process")
    p.add_argument("--workers", type=count(MAX_WORKERS), default=2,
                   help="LocalCluster worker processes (default 2)")
    p.add_argument("--overwrite", action="store_true", help="replace files in DIR")
    p.add_argument("--forecast", action="store_true",
                   help="also draw the exact expectation (forecast) of Figs. 6-9 as curves "
                   "beside the Monte Carlo points, and judge the claims of Figs. 6-8 on it")
    p.set_defaults(func=run)


def run(args):
    from ..analysis.figures.reproduce import make_figures
    from ..reduce.scheduler import check_scheduler

    check_scheduler(args.scheduler, name="--scheduler")  # before any work
    if not args.verbose:  # dask's INFO lines about workers and connections
        from ..reduce.scheduler import quiet_dask_logs

        quiet_dask_logs()
    report = make_figures(args.output, quick=args.quick, realizations=args.realizations,
                          scheduler=args.scheduler, workers=args.workers,
                          overwrite=args.overwrite, progress=not args.quiet,
                          log=(lambda line: None) if args.quiet else print,
                          forecast=args.forecast)
    print(f"wrote {report}")
