"""``spherex-reduce demo``: the package's main job on built-in defaults."""

from pathlib import Path

from ._common import count


def add_parser(sub):
    p = sub.add_parser(
        "demo", help="simulate, reduce and measure the paper's case on built-in defaults",
        description="Simulate raw ramps of the paper's readout (S=24, r=32, c=4, N=74) and of "
        "the same array read without chopping, reduce both, and write the reduced images "
        "(FITS), the spatial power spectra (ECSV) and plots to a directory (137 MB at full "
        "size: two 68 MB reduced files). The raw files are simulated into the directory "
        "and removed once reduced unless --keep-raw (2 x 1.28 GB at full size).")
    p.add_argument("-o", "--output", default="spherex-demo", metavar="DIR",
                   help="output directory (default: %(default)s)")
    p.add_argument("--size", type=count(2**16), default=2048,
                   help="array size in pixels, a multiple of 64 (default: %(default)s)")
    p.add_argument("--nframes", type=count(10_000), default=74,
                   help="frames up the ramp (default: 74)")
    p.add_argument("--seed", type=int, default=2024, help="simulation seed")
    p.add_argument("--overwrite", action="store_true", help="replace files in DIR")
    p.add_argument("--keep-raw", action="store_true",
                   help="keep the simulated raw files raw_chopped.fits and raw_unchopped.fits")
    p.set_defaults(func=run)


def run(args):
    from ..analysis.figures.demo import run_demo
    from ..core.errors import SpherexReduceError
    from ..core.limits import check_size

    if args.size < 64 or args.size % 64:
        raise SpherexReduceError(f"--size must be a multiple of 64, >= 64; got {args.size}")
    if args.nframes < 2:
        raise SpherexReduceError(f"--nframes must be >= 2 to fit a slope; got {args.nframes}")
    # a few float64 images of the array at once (the ramps are streamed frame by frame)
    check_size(8 * 8 * args.size**2, f"--size {args.size} (a {args.size} x {args.size} array)")
    for line in run_demo(Path(args.output), overwrite=args.overwrite, progress=not args.quiet,
                         size=args.size, nframes=args.nframes, seed=args.seed,
                         keep_raw=args.keep_raw):
        print(line, flush=True)
