"""``spherex-reduce reduce``: run a pipeline config on one FITS file, or on many on dask."""

import contextlib
import sys
from pathlib import Path

from ..core._text import plural
from ..core.errors import ConfigError
from ..core.limits import MAX_WORKERS
from ..io import atomic_output, write
from ..io.config import shipped_configs
from ..io.jwst_products import write_jwst
from ..io.readers.read_files import ReadFiles, read_file_paths
from ..reduce.integrations import reduce_input
from ..reduce.provenance import provenance_rows
from ._common import check_paths, count, input_config


def add_parser(sub):
    p = sub.add_parser(
        "reduce", help="run a pipeline on raw FITS files",
        description="Reduce IN.fits with the steps of a pipeline YAML file (or a shipped "
        "config name, see show-config --list) and write OUT.fits. A file whose SCI is 4-D "
        "(integrations, groups, rows, columns) has each integration reduced as a ramp: OUT.fits "
        "holds their weighted mean and each one's image (INTSLOPE, INTERR, INTDQ). With "
        "several inputs (or "
        "--workers/--scheduler), -o names a directory: each file is reduced on dask (an "
        "embedded LocalCluster, or an existing scheduler) into OUTDIR/<stem>_reduced.fits, "
        "with a summary table OUTDIR/summary.ecsv written after each file; an output already "
        "made from the same input with this config is done (never made again, so a batch "
        "resumes), a file that fails is reported and the others finish. With --reads "
        "'DIR/read_*.fits' instead of IN.fits, the files are the reads of one ramp "
        "(--reads-dq MASK.fits: their flags).")
    p.add_argument("input", metavar="IN.fits", nargs="*",
                   help="the raw FITS file to reduce: ramps in readout order (as simulate "
                   "writes them), another system's ramps, a 4-D SCI of integrations, or a "
                   "Roman level-1 ASDF file (read with its own read pattern); "
                   "several files: each reduced on dask into the directory -o")
    p.add_argument("--reads", metavar="GLOB",
                   help="reduce one ramp stored as one file per read: the files the glob "
                   "matches (quote it), in natural order (read_2 before read_10), each one 2-D "
                   "frame; the first file's header is the exposure's")
    p.add_argument("--reads-dq", metavar="MASK.fits",
                   help="with --reads: one file of flags for every read, its DQ extension or "
                   "primary HDU (integers): 2-D (rows x columns of a read) for every read, or "
                   "3-D with one plane per read file; flagged pixels are not fitted (any bit, "
                   "or --dq-bits / input.dq_bits), with each read file's own DQ")
    p.add_argument("-c", "--config", required=True, metavar="PIPELINE.yaml",
                   help="the pipeline: a YAML file of steps, or a shipped config "
                   f"({', '.join(shipped_configs())}; show-config --list says what each "
                   "does, show-config NAME prints one to edit)")
    p.add_argument("-o", "--output", required=True, metavar="OUT.fits|OUTDIR",
                   help="the reduced FITS file to write (SCI, ERR, DQ and the steps' tables; "
                   "refused if it exists, see --overwrite); with several inputs, a directory")
    p.add_argument("--overwrite", action="store_true",
                   help="replace OUT.fits if it exists (several inputs: reduce every file "
                   "again, replacing existing outputs)")
    p.add_argument("--format", choices=("native", "jwst"), default="native",
                   help="native (default): this package's file; jwst: a JWST rate file "
                   "(rateints for a 4-D SCI) that stdatamodels' ImageModel (CubeModel) and "
                   "the JWST pipeline's stage 2 open: SCI, ERR, DQ in JWST's bits, "
                   "VAR_POISSON, VAR_RNOISE (needs fit_ramp with a read_noise); one input")
    p.add_argument("--threads", type=count(MAX_WORKERS), default=None, metavar="N",
                   help="bands of rows corrected at once (default: the cores available, "
                   "at most 4); the numbers do not depend on it")
    where = p.add_mutually_exclusive_group()
    where.add_argument("--workers", type=count(MAX_WORKERS), default=None, metavar="N",
                       help="several inputs: worker processes of the embedded dask "
                       "LocalCluster (default 2)")
    where.add_argument("--scheduler", metavar="ADDRESS",
                       help="several inputs: an existing dask scheduler (tcp://host:8786; the "
                       "files must be at the same paths on its workers); 'serial' reduces "
                       "them one after the other in this process")
    p.set_defaults(func=run)


def run(args):
    if args.reads_dq is not None and args.reads is None:
        raise ConfigError("--reads-dq gives the flags of the read files of --reads GLOB: give "
                          "--reads too (a file's own flags are its DQ extension)")
    if args.reads is not None:
        _check_reads_alone(args)
    elif not args.input:
        raise ConfigError("give the input: IN.fits (one or more), or --reads GLOB")
    elif len(args.input) > 1 or args.workers is not None or args.scheduler is not None:
        if args.format != "native":
            raise ConfigError(f"--format {args.format} writes one input's product: reduce "
                              "the files one at a time")
        return _batch(args)
    pipeline, config_files = input_config(args.config)
    if args.format == "jwst":
        _check_variance_parts(pipeline)
    # one input: a file (a 4-D SCI: each integration fitted, their mean with INTSLOPE/INTERR/
    # INTDQ), or the files of one ramp stored one per read; streamed where the steps allow
    what = read_file_paths(args.reads) if args.reads is not None else args.input[0]
    inputs = what if args.reads is not None else [what]
    # the input files, the config file and any file the config names (e.g. a dark)
    check_paths([*inputs, args.reads_dq, *config_files], [args.output])
    atomic_output(args.output, args.overwrite)  # refuse before reducing
    # the read files with one mask file: a reader of them
    source = (ReadFiles(what, input=pipeline.input_options, dq=args.reads_dq,
                        **pipeline.supplied()) if args.reads_dq is not None
              else contextlib.nullcontext(what))
    with source as inp:
        result, images = reduce_input(inp, pipeline, progress=not args.quiet,
                                      threads=args.threads)
    return _written(pipeline, result, args, images)


def _written(pipeline, result, args, images=None):
    if args.format == "jwst":  # rateints of the integrations' images, else rate
        images = images or {}
        write_jwst(result, args.output, slopes=images.get("INTSLOPE"),
                   flags=images.get("INTDQ"), overwrite=args.overwrite)
    else:
        write(result, args.output, overwrite=args.overwrite, images=images)
    runs = provenance_rows(result.tables)[-len(pipeline.steps):]  # this pipeline's, in order
    status = ", ".join(f"{row['step']}={row['status']}" for row in runs)
    print(f"wrote {args.output} ({status})")
    return 0


def _check_variance_parts(pipeline):
    """``--format jwst``: a ``fit_ramp`` without ``read_noise`` has no VAR_RNOISE and
    VAR_POISSON to write; refused before reducing (any other fit is checked after)."""
    for name, params in pipeline.steps:
        if name == "fit_ramp" and params.get("read_noise") is None:
            raise ConfigError("--format jwst writes the slope variance's parts (VAR_RNOISE, "
                              "VAR_POISSON): give fit_ramp a read_noise (and gain)")


def _check_reads_alone(args):
    """``--reads GLOB`` reduces one ramp from its read files: nothing else to reduce."""
    if args.input:
        raise ConfigError(f"--reads reduces one ramp from its read files: give no IN.fits "
                          f"as well (got {args.input[0]})")
    if args.workers is not None or args.scheduler is not None:
        raise ConfigError("--reads reduces one ramp: --workers and --scheduler are for "
                          "several input files")


def _batch(args):
    """Several inputs: one output each in the directory ``-o``, reduced on dask."""
    from ..reduce.batch import SUMMARY_NAME, output_paths, run_batch
    from ..reduce.scheduler import check_scheduler, quiet_dask_logs

    if not args.verbose:  # dask's lines about connections, workers restarted or stopped
        quiet_dask_logs()
    pipeline, config_files = input_config(args.config)
    outputs = output_paths(args.input, args.output)  # refuses two inputs of one output name
    check_paths([*args.input, *config_files], [*outputs, Path(args.output) / SUMMARY_NAME])
    check_scheduler(args.scheduler, name="--scheduler")  # before any work
    res = run_batch(pipeline, args.input, args.output, scheduler=args.scheduler,
                    workers=args.workers, threads=args.threads, overwrite=args.overwrite,
                    progress=not args.quiet,
                    verify_checksum=not getattr(args, "ignore_checksum", False))
    for row in res.failed:
        named = row.error if row.input in row.error else f"{row.input}: {row.error}"
        print(f"spherex-reduce reduce: error: {named}", file=sys.stderr)
    print(f"{plural(len(args.input), 'file')}: {res.count('done')} reduced, "
          f"{res.count('skipped')} already done, {res.count('failed')} failed "
          f"({res.seconds:.1f} s)")
    print(f"wrote {res.summary}")
    if any(row.kind == "unexpected" for row in res.failed):
        return 1  # as a single file's unexpected failure (a bug)
    return 2 if res.failed else 0
