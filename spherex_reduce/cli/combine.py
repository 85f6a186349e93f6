"""``spherex-reduce combine``: a master dark from reduced exposures (ccdproc.combine)."""

from ..io import atomic_output, read, write
from ..io.header_text import header_text
from ..reduce.steps.dark import COMBINE_METHODS, combine_darks
from ._common import check_paths, nonnegative_float


def add_parser(sub):
    p = sub.add_parser(
        "combine", help="combine reduced exposures into a master dark",
        description="Combine two or more reduced 2-D exposures (e.g. slopes written by "
        "`spherex-reduce reduce`) into a master dark with ccdproc.combine (sigma-clipped "
        "average by default, uncertainty propagated), for the subtract_dark step.")
    p.add_argument("inputs", nargs="+", metavar="IN.fits",
                   help="two or more reduced 2-D images of one shape (e.g. dark slopes); "
                   "flagged (DQ) or NaN values are left out")
    p.add_argument("-o", "--output", required=True, metavar="MASTER.fits",
                   help="the master dark to write (SCI, ERR, DQ; refused if it exists, see "
                   "--overwrite)")
    p.add_argument("--method", choices=COMBINE_METHODS, default="average",
                   help="how each pixel's values are combined (default: %(default)s)")
    p.add_argument("--sigma", type=nonnegative_float, default=3.0,
                   help="clip each pixel at this many standard deviations across the "
                   "inputs (0: no clipping; default 3)")
    p.add_argument("--overwrite", action="store_true", help="replace MASTER.fits if it exists")
    p.set_defaults(func=run)


def run(args):
    check_paths(args.inputs, [args.output])
    atomic_output(args.output, args.overwrite)  # refuse before reading anything
    exposures = [read(path) for path in args.inputs]
    master = combine_darks(exposures, method=args.method, sigma=args.sigma)
    header = master.header.copy()
    for path in args.inputs:
        header.add_history(f"combine input: {header_text(path)}")
    write(master.replace(header=header), args.output, overwrite=args.overwrite)
    print(f"wrote {args.output} ({args.method} of {len(exposures)} exposures; "
          f"{master.header['NCOMB1']} pixels from one usable input, "
          f"{master.header['NCOMB0']} with none: NaN, flagged DO_NOT_USE)")
