"""``spherex-reduce readout``: build, print, save and draw a readout schedule."""

import argparse

from ..core.fields import FIELDS, SIDES
from ..core.presets import PRESETS
from ..io import atomic_output
from ..io.config import load_yaml, schedule_from_config
from ._common import all_or_nothing, check_paths, count, finite_float, positive_float


def _flag(field):
    return "--" + field.name.replace("_", "-")


def per_side(number):
    """An argparse type: one ``number`` (every side) or ``side=number,...`` (others 0).

    Examples
    --------
    >>> from spherex_reduce.cli._common import count
    >>> from spherex_reduce.cli.readout import per_side
    >>> per_side(count(1024, minimum=0))("top=4,left=4")
    {'top': 4, 'left': 4}
    >>> per_side(count(1024, minimum=0))("4")
    4
    """
    def parse(text):
        if "=" not in text:
            return number(text)
        sides = {}
        for item in text.split(","):
            side, _, value = (part.strip() for part in item.partition("="))
            if side not in SIDES or side in sides:
                raise argparse.ArgumentTypeError(
                    f"expected a number or side=number,... with sides {', '.join(SIDES)}; "
                    f"got {text!r}")
            try:
                sides[side] = number(value)
            except argparse.ArgumentTypeError as exc:
                raise argparse.ArgumentTypeError(f"{side}: {exc}") from None
        return sides

    parse.__name__ = "per_side"
    return parse


def _option_type(field):
    """The argparse type of a field: its bounds (counts up to ``cli_max``)."""
    if field.side_keywords:
        return per_side(count(field.cli_max, minimum=field.minimum))
    if field.kind is int:
        return count(field.cli_max, minimum=field.minimum)
    if field.kind is float:  # the YAML check that follows applies any other bound
        return positive_float if field.exclusive_minimum and field.minimum == 0 else finite_float
    if field.from_text is not None and str not in field.types:  # a structure as its FITS
        # text (``--groups``); a field that may be a string (``--order``) takes a path
        return _from_text(field.from_text)
    return str


def _from_text(parse):
    def from_text(text):
        try:
            return parse(text)
        except ValueError as exc:
            raise argparse.ArgumentTypeError(str(exc)) from None

    from_text.__name__ = parse.__name__
    return from_text


#: One option per field of the table: (flag, YAML section, key, type).
OPTIONS = [(_flag(f), f.section, f.name, _option_type(f)) for f in FIELDS]


#: How a structure field is written on the command line (its FITS text).
TEXT_FORMS = {"groups": "0;1-2;3-6 (';' between groups, a-b a run of reads)",
              "read_times": "0,2.93,12.93 (s, ',' between reads)",
              "order": "the path of an ECSV file of one integer column, in read order"}

#: The names a field without fixed choices takes (``--preset``).
NAMED = {"preset": tuple(PRESETS)}


def _option_help(field):
    """Help of one option from its field: meaning, choices, default."""
    text = field.doc
    if field.side_keywords:
        text += f", e.g. top=4,left=4 (sides {', '.join(SIDES)}; others 0)"
    if field.choices and not all(choice in field.doc for choice in field.choices):
        text += f": {', '.join(field.choices)}"  # unless the line names them already
    if field.name in NAMED:
        text += f": {', '.join(NAMED[field.name])}"
    if field.from_text:
        text += f", as text: {TEXT_FORMS[field.name]}"
    if field.default is None:
        default = field.none_means.format(**{f.name: _flag(f) for f in FIELDS})
    else:
        default = f"{field.default:g}" if isinstance(field.default, float) else field.default
    return f"{text} (default: {default})".replace("%", "%%")


def add_parser(sub):
    p = sub.add_parser("readout", help="build a readout schedule; print, save or draw it",
                       description="Build a readout schedule (defaults: the SPHEREx array "
                       "and the paper's Table 3) from options or a scene/pipeline YAML file; "
                       "options override the file. Print its summary, save it as a table or "
                       "draw its read order.")
    p.add_argument("--config", metavar="YAML",
                   help="scene or pipeline YAML file whose geometry:, readout: and window: "
                   "sections give the starting values")
    for field, (flag, _, key, typ) in zip(FIELDS, OPTIONS, strict=True):
        p.add_argument(flag, dest=key, type=typ, default=None, help=_option_help(field))
    p.add_argument("-o", "--output", metavar="SCHEDULE.ecsv",
                   help="write the schedule table (ECSV: read row kind start time)")
    p.add_argument("--plot", metavar="PNG", help="draw the read order and the channels on "
                   "the stored image to this PNG")
    p.add_argument("--overwrite", action="store_true", help="replace existing outputs")
    p.set_defaults(func=run)


def schedule_from_args(args):
    """The schedule from ``--config`` overridden by explicit options."""
    config = load_yaml(args.config, "config")[0] if args.config else {}
    sections = {name: dict(config.get(name) or {}) for name in ("geometry", "readout", "window")}
    for _, section, key, _ in OPTIONS:
        value = getattr(args, key)
        if value is not None:
            sections[section][key] = value
    return schedule_from_config(sections["geometry"], sections["readout"], sections["window"])


def run(args):
    check_paths([args.config], [args.output, args.plot])
    schedule = schedule_from_args(args)
    for path in (args.output, args.plot):  # refuse early, before any work
        if path:
            atomic_output(path, args.overwrite)
    print(schedule.summary())
    g = schedule.geometry
    if g.window is not None:
        print(g.window.summary(g.nrows, g.ncols))
    if not g.layout.identity:  # the summary is of the readout frame
        print(g.layout.summary())
    with all_or_nothing([args.output, args.plot], args.overwrite) as (tmp, tmp_plot):
        if args.output:
            schedule.to_table().write(tmp, format="ascii.ecsv")
        if args.plot:
            from ..io.plotting import plot_read_order, save_figure

            save_figure(plot_read_order(schedule), tmp_plot)
    for path in (args.output, args.plot):
        if path:
            print(f"wrote {path}")
