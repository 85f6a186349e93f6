"""``spherex-reduce sweep``: a parameter sweep on dask.distributed."""

import sys

from ..core._text import plural
from ..io import atomic_output
from ._common import add_dask_options, dask_run_inputs


def add_parser(sub):
    p = sub.add_parser(
        "sweep", help="simulate, reduce and measure a grid of readout parameters on dask",
        description="Run SWEEP.yaml (scene:, pipeline:, grid:, realizations:, seed:): every "
        "cell is simulated (slopes by default), reduced with the pipeline and measured "
        "(band power, P(k)). Runs on an embedded dask LocalCluster, or on an existing "
        "scheduler with --scheduler. Cells already in OUTPUT are skipped, so an interrupted "
        "sweep resumes; failed cells are reported and retried on the next run.")
    p.add_argument("input", metavar="SWEEP.yaml")
    p.add_argument("-o", "--output", required=True, metavar="RESULTS.ecsv")
    add_dask_options(p)
    p.add_argument("--plot", nargs="?", const=True, metavar="PNG",
                   help="band power against the first grid key (default: OUTPUT with .png)")
    p.add_argument("--overwrite", action="store_true",
                   help="discard OUTPUT's rows and run every cell again")
    p.add_argument("--forecast", action="store_true",
                   help="add each point's exact expected band power and P(k) (columns "
                   "band_power_forecast, power_forecast; a line in the plot); with "
                   "realizations: 0 the forecast alone, no simulation")
    p.set_defaults(func=run)


def run(args):
    from ..analysis.sweep import load_sweep, plot_sweep, run_sweep

    sweep = load_sweep(args.input)
    plot = dask_run_inputs(args, "sweep")
    atomic_output(args.output, True)  # checks the name and directory
    if plot:
        atomic_output(plot, True)  # checks the directory; the plot follows the results
    res = run_sweep(sweep, args.output, scheduler=args.scheduler, workers=args.workers,
                    overwrite=args.overwrite, progress=not args.quiet,
                    forecast=args.forecast)
    if args.forecast:
        print(f"{plural(len(sweep.points()), 'point')} forecast")
    print(f"{plural(len(sweep.cells()), 'cell')}: {res.computed} computed, {res.skipped} "
          f"already in {args.output}, {len(res.failed)} failed ({res.seconds:.1f} s)")
    for f in res.failed:
        print(f"failed cell {f['cell']}: {f['error']}", file=sys.stderr)
    print(f"wrote {args.output}")
    if plot and len(res.table):
        from ..io.plotting import save_figure

        save_figure(plot_sweep(res.table), plot, overwrite=True)
        print(f"wrote {plot}")
    return 1 if res.failed else 0
