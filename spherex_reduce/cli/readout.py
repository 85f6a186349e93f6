"""``spherex-reduce readout``: build, print, save and draw a readout schedule."""

from ..config import load_yaml, schedule_from_config
from ..fits_format import atomic_output

OPTIONS = [  # (flag, YAML section, key, type)
    ("--nrows", "geometry", "nrows", int), ("--ncols", "geometry", "ncols", int),
    ("--nchannels", "geometry", "nchannels", int), ("--ref-border", "geometry", "ref_border", int),
    ("--scan", "geometry", "scan", str), ("--pixel-rate", "geometry", "pixel_rate", float),
    ("--skip", "readout", "skip", int), ("--ref-reads", "readout", "ref_reads", int),
    ("--ref-mode", "readout", "ref_mode", str),
    ("--phantom-reads", "readout", "phantom_reads", int),
    ("--row-overhead", "readout", "row_overhead", int),
    ("--frame-overhead", "readout", "frame_overhead", int),
    ("--nframes", "readout", "nframes", int), ("--frame-time", "readout", "frame_time", float),
]


def add_parser(sub):
    p = sub.add_parser("readout", help="build a readout schedule; print, save or draw it",
                       description="Build a readout schedule (defaults: the paper's Table 3) "
                       "from options or a scene/pipeline YAML file.")
    p.add_argument("--config", help="YAML file with geometry: and readout: sections")
    for flag, _, key, typ in OPTIONS:
        p.add_argument(flag, dest=key, type=typ, default=None)
    p.add_argument("-o", "--output", help="write the schedule table (ECSV: read row kind start "
                   "time)")
    p.add_argument("--plot", help="draw the read order to this PNG")
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
    schedule = schedule_from_args(args)
    for path in (args.output, args.plot):  # refuse early, before any work
        if path:
            atomic_output(path, args.overwrite)
    print(schedule.summary())
    if args.output:
        with atomic_output(args.output, args.overwrite) as tmp:
            schedule.to_table().write(tmp, format="ascii.ecsv")
        print(f"wrote {args.output}")
    if args.plot:
        from ..plotting import plot_read_order, save_figure

        save_figure(plot_read_order(schedule), args.plot, args.overwrite)
        print(f"wrote {args.plot}")
