"""``spherex-reduce characterize``: fit a noise model (a scene) to raw darks."""

from pathlib import Path

from ...io import atomic_output
from ...io.readers.read_files import read_file_paths
from .._common import all_or_nothing, check_paths, count, input_config, positive_float

#: More log bins than this resolve nothing a Welch PSD holds.
MAX_BINS = 1000
#: More segments per dark than this leave too few frames in each to matter.
MAX_SEGMENTS = 4096


def add_parser(sub):
    p = sub.add_parser(
        "characterize", help="fit a noise model (a scene) to raw darks: per channel and "
        "common, ACN, what the phantom sees",
        description="Fit the noise the simulator models to raw darks (any input reduce "
        "reads; every integration of a 4-D file is a dark): per channel and common to all "
        "channels, the white, 1/f and 1/f^exponent terms seen by the light-sensitive pixels, "
        "by the phantom reads and by both, alternating column noise (ACN) found or ruled "
        "out, and the reference pixels' levels, each with an uncertainty from the scatter "
        "between darks (or segments of frames). MODEL.yaml is a scene in the darks' unit "
        "that simulate, forecast, sweep and design-readout take as it is. A dark stored "
        "one file per read is --reads 'DIR/read_*.fits' (once per dark).")
    p.add_argument("inputs", metavar="DARK.fits", nargs="*")
    p.add_argument("--reads", metavar="GLOB", action="append", default=[],
                   help="one dark stored as one file per read: the files the glob matches "
                   "(quote it), in natural order (read_2 before read_10), as reduce --reads; "
                   "give it once per dark")
    p.add_argument("-c", "--config", required=True, metavar="CONFIG.yaml",
                   help="pipeline YAML file or shipped config name whose input:, geometry: "
                   "and readout: sections say how to read the darks (unit, gain, keywords "
                   "they lack), as for reduce -c; its steps reduce the darks for the slope "
                   "scatter and P(k) they are compared on")
    p.add_argument("-o", "--output", required=True, metavar="MODEL.yaml")
    p.add_argument("--report", metavar="R.ecsv",
                   help="every fitted number with its uncertainty, per component, spectrum "
                   "and channel")
    p.add_argument("--plot", metavar="P.png", help="the measured spectra and their fits, "
                   "the slope scatter against N and the reduced P(k), measured and predicted")
    p.add_argument("--no-scatter", action="store_true",
                   help="do not measure the darks' slope scatter and P(k) (each dark is "
                   "reduced once per frame count for them)")
    p.add_argument("--check", nargs="+", metavar="DARK", default=None,
                   help="held-out darks (not fitted): their slope scatter against N and "
                   "reduced P(k), measured with the config's steps, against what the model "
                   "predicts (printed; in the report and plot instead of the fitted darks')")
    p.add_argument("--exponent", type=positive_float, default=1.3,
                   help="exponent of the third term of every component (default 1.3, the "
                   "paper's)")
    p.add_argument("--fit-exponent", action="store_true",
                   help="fit the exponent on the light-sensitive pixels' spectrum")
    p.add_argument("--segments", type=count(MAX_SEGMENTS), default=None,
                   help="split each dark into this many runs of frames, each left out in "
                   "turn for the jackknife errors (default: each dark whole; one dark alone "
                   "is split into up to 8 runs of 5 frames or more)")
    p.add_argument("--nbins", type=count(MAX_BINS), default=30,
                   help=f"log frequency bins per spectrum (default 30, at most {MAX_BINS})")
    p.add_argument("--overwrite", action="store_true", help="replace existing outputs")
    p.set_defaults(func=run)


def run(args):
    from ...analysis.characterize import characterize
    from ...core.errors import ConfigError

    if not args.inputs and not args.reads:
        raise ConfigError("give the darks: DARK.fits (one or more), or --reads GLOB (a dark "
                          "stored one file per read, once per dark)")
    ramps = [read_file_paths(pattern) for pattern in args.reads]
    pipeline, config_files = input_config(args.config)
    outputs = [args.output, args.report, args.plot]
    check_paths([*args.inputs, *(f for files in ramps for f in files), *(args.check or []),
                 *config_files], outputs)
    for path in outputs:
        if path:
            atomic_output(path, args.overwrite)
    exponent = None if args.fit_exponent else args.exponent
    model = characterize([*args.inputs, *ramps], pipeline, exponent=exponent,
                         segments=args.segments, nbins=args.nbins,
                         scatter=args.check is None and not args.no_scatter)
    if args.check is not None:
        from ...analysis.characterize import check_model

        model.check = check_model(model, args.check, pipeline)
    with all_or_nothing(outputs, args.overwrite) as (tmp, tmp_report, tmp_plot):
        Path(tmp).write_text(model.to_yaml())
        if args.report:
            model.report().write(tmp_report, format="ascii.ecsv")
        if args.plot:
            from ...analysis.characterize.figure import plot_characterization
            from ...io.plotting import save_figure

            save_figure(plot_characterization(model), tmp_plot)
    for line in model.summary():
        print(line)
    if model.check is not None:
        print(f"{'held-out darks' if args.check else 'the darks'}: "
              f"{model.check.meta['statistic']}")
        for r in model.check[model.check["quantity"] != "power_spectrum"]:
            print(f"{r['quantity']} N={r['frames']}: measured {r['measured']:.4g} ± "
                  f"{r['error']:.2g}, predicted {r['predicted']:.4g} (without telegraph "
                  f"{r['predicted_streams']:.4g}), ratio {r['ratio']:.3f}, within "
                  f"{r['target']:.0%}: {'yes' if r['within'] else 'no'}")
    for path in outputs:
        if path:
            print(f"wrote {path}")
