"""``spherex-reduce demo``: the package's main job on built-in defaults."""

from pathlib import Path


def add_parser(sub):
    p = sub.add_parser("demo", help="simulate, reduce and measure on built-in defaults",
                       description="Run the package end to end on built-in inputs and write "
                       "FITS files, a table and plots to a directory.")
    p.add_argument("-o", "--output", default="spherex-demo", metavar="DIR",
                   help="output directory (default: %(default)s)")
    p.add_argument("--overwrite", action="store_true", help="replace files in DIR")
    p.set_defaults(func=run)


def run(args):
    from ..demo import run_demo

    out = Path(args.output)
    for line in run_demo(out, overwrite=args.overwrite, progress=not args.quiet):
        print(line)
