"""``spherex-reduce readout``: build, print, save and draw a readout schedule."""

from ..config import GEOMETRY_PARAMETERS, READOUT_PARAMETERS, load_yaml, schedule_from_config
from ..io import atomic_output
from ..schedule import DEFAULT_FRAME_OVERHEAD
from ._common import all_or_nothing, check_paths, count, positive_float

OPTIONS = [  # (flag, YAML section, key, type); counts bounded by what a schedule can hold
    ("--nrows", "geometry", "nrows", count(2**16)), ("--ncols", "geometry", "ncols", count(2**16)),
    ("--nchannels", "geometry", "nchannels", count(2**12)),
    ("--ref-border", "geometry", "ref_border", count(2**10, minimum=0)),
    ("--scan", "geometry", "scan", str), ("--pixel-rate", "geometry", "pixel_rate", positive_float),
    ("--skip", "readout", "skip", count(2**16)),
    ("--ref-reads", "readout", "ref_reads", count(2**16, minimum=0)),
    ("--ref-mode", "readout", "ref_mode", str),
    ("--phantom-reads", "readout", "phantom_reads", count(2**12, minimum=0)),
    ("--row-overhead", "readout", "row_overhead", count(2**20, minimum=0)),
    ("--frame-overhead", "readout", "frame_overhead", count(2**30, minimum=0)),
    ("--nframes", "readout", "nframes", count(2**20)),
    ("--frame-time", "readout", "frame_time", positive_float),
]


#: What a default of None means, for the help.
_NONE_DEFAULT = {
    "frame_overhead": f"{DEFAULT_FRAME_OVERHEAD}, the paper's 1.51 s frame; unless "
                      "--frame-time is given",
    "frame_time": "from --frame-overhead",
}


def _option_help(key):
    """Help of one option from its YAML parameter declaration: meaning, choices, default."""
    param = {p.name: p for p in (*GEOMETRY_PARAMETERS, *READOUT_PARAMETERS)}[key]
    text = param.doc
    if param.choices:
        text += f": {', '.join(param.choices)}"
    default = _NONE_DEFAULT.get(key) if param.default is None else f"{param.default:g}" \
        if isinstance(param.default, float) else param.default
    return f"{text} (default: {default})".replace("%", "%%")


def add_parser(sub):
    p = sub.add_parser("readout", help="build a readout schedule; print, save or draw it",
                       description="Build a readout schedule (defaults: the SPHEREx array "
                       "and the paper's Table 3) from options or a scene/pipeline YAML file; "
                       "options override the file. Print its summary, save it as a table or "
                       "draw its read order.")
    p.add_argument("--config", metavar="YAML",
                   help="scene or pipeline YAML file whose geometry: and readout: sections "
                   "give the starting values")
    for flag, _, key, typ in OPTIONS:
        p.add_argument(flag, dest=key, type=typ, default=None, help=_option_help(key))
    p.add_argument("-o", "--output", metavar="SCHEDULE.ecsv",
                   help="write the schedule table (ECSV: read row kind start time)")
    p.add_argument("--plot", metavar="PNG", help="draw the read order to this PNG")
    p.add_argument("--overwrite", action="store_true", help="replace existing outputs")
    p.set_defaults(func=run)


def schedule_from_args(args):
    """The schedule from ``--config`` overridden by explicit options."""
    config = load_yaml(args.config, "config")[0] if args.config else {}
    sections = {"geometry": dict(config.get("geometry") or {}),
                "readout": dict(config.get("readout") or {})}
    for _, section, key, _ in OPTIONS:
        value = getattr(args, key)
        if value is not None:
            sections[section][key] = value
    return schedule_from_config(sections["geometry"], sections["readout"])


def run(args):
    check_paths([args.config], [args.output, args.plot])
    schedule = schedule_from_args(args)
    for path in (args.output, args.plot):  # refuse early, before any work
        if path:
            atomic_output(path, args.overwrite)
    print(schedule.summary())
    with all_or_nothing([args.output, args.plot], args.overwrite) as (tmp, tmp_plot):
        if args.output:
            schedule.to_table().write(tmp, format="ascii.ecsv")
        if args.plot:
            from ..plotting import plot_read_order, save_figure

            save_figure(plot_read_order(schedule), tmp_plot)
    for path in (args.output, args.plot):
        if path:
            print(f"wrote {path}")
