"""``spherex-reduce reduce``: run a pipeline config on a FITS file."""

from pathlib import Path

from ..io import atomic_output, write
from ..limits import MAX_WORKERS
from ..pipeline import Pipeline
from ._common import check_paths, count, named_files


def add_parser(sub):
    p = sub.add_parser("reduce", help="run a pipeline on a raw FITS file",
                       description="Reduce IN.fits with the steps of a pipeline YAML file (or a "
                       "shipped config name, see show-config --list) and write OUT.fits.")
    p.add_argument("input", metavar="IN.fits")
    p.add_argument("-c", "--config", required=True, metavar="PIPELINE.yaml")
    p.add_argument("-o", "--output", required=True, metavar="OUT.fits")
    p.add_argument("--overwrite", action="store_true", help="replace OUT.fits if it exists")
    p.add_argument("--threads", type=count(MAX_WORKERS), default=None, metavar="N",
                   help="bands of rows corrected at once (default: the cores available, "
                   "at most 4); the numbers do not depend on it")
    p.set_defaults(func=run)


def run(args):
    pipeline = Pipeline.from_yaml(args.config)
    # the raw file, the config file and any file the config names (e.g. a dark)
    check_paths([args.input, args.config, *named_files(pipeline.steps, Path(args.config).parent)],
                [args.output])
    atomic_output(args.output, args.overwrite)  # refuse before reducing
    result = pipeline.run(args.input, progress=not args.quiet, threads=args.threads)
    write(result, args.output, overwrite=args.overwrite)
    status = ", ".join(f"{n}={result.header.get(pipeline.registry.step(n).keyword, '?')}"
                       for n, _ in pipeline.steps)
    print(f"wrote {args.output} ({status})")
