"""``spherex-reduce design-readout``: the readout of least forecast band power."""

from pathlib import Path

from ..io import atomic_output
from ..io.config import load_yaml
from ._common import all_or_nothing, check_paths, named_files, plot_path


def add_parser(sub):
    p = sub.add_parser(
        "design-readout", help="search the readout (row order, c, r) of least forecast "
        "5-20' noise within a frame time",
        description="Search skip, nested-skip, bit-reversal and golden-ratio row orders, the "
        "phantom reads c, the reference reads r and their placement, then permutations of the "
        "rows (local search), for the least forecast band power of the image the pipeline "
        "makes, at a fixed frame time (DESIGN.yaml: scene:, noise:, band:, pipeline:, "
        "budget:, baseline:, search:, realizations:, seed:). Writes the best schedule as a "
        "scene that simulate, forecast and reduce accept; the report compares it with the "
        "paper's S = 24, r = 32 distributed, c = 4 per k and per noise component and "
        "confirms the gain with a paired Monte Carlo.")
    p.add_argument("input", metavar="DESIGN.yaml")
    p.add_argument("-o", "--output", required=True, metavar="BEST.yaml")
    p.add_argument("--report", metavar="REPORT.ecsv",
                   help="P(k) of best and baseline per k and component, the gain, the Monte "
                   "Carlo and every candidate (meta)")
    p.add_argument("--plot", nargs="?", const=True, metavar="PNG",
                   help="band power of every candidate and P(k) of best and baseline "
                   "(default name: the output with .png)")
    p.add_argument("--overwrite", action="store_true", help="replace existing outputs")
    p.set_defaults(func=run)


def run(args):
    import yaml

    from ..analysis.design.file import load_design
    from ..analysis.design.search import design_readout, plot_design

    plot = plot_path(args)
    outputs = [args.output, args.report, plot]
    named = load_yaml(Path(args.input), "design")[0]  # the scene, noise, pipeline files too
    check_paths([args.input, *named_files(named, Path(args.input).parent)], outputs)
    for path in outputs:
        if path:
            atomic_output(path, args.overwrite)
    design = load_design(Path(args.input))
    for note in design.notes:
        print(f"note: {note}")
    res = design_readout(design, progress=not args.quiet)
    meta = res.report.meta
    with all_or_nothing(outputs, args.overwrite) as (best, report, png):
        best.write_text(f"# spherex-reduce design-readout {args.input}: {meta['best']['summary']}"
                        f"\n# forecast band power {meta['band_power_best']:.6g} "
                        f"{meta['band_unit']}, {100 * meta['gain']:.1f} % below "
                        f"{meta['baseline']['summary']}\n"
                        + yaml.safe_dump(res.best_scene, sort_keys=False,
                                         default_flow_style=None, width=100))
        if report:
            res.report.write(report, format="ascii.ecsv")
        if png:
            from ..io.plotting import save_figure

            save_figure(plot_design(res.report), png, overwrite=True)
    b, a = meta["best"], meta["baseline"]
    print(f"{meta['evaluations']} schedules forecast in "
          f"{sum(meta['seconds'].values()):.1f} s")
    print(f"baseline {a['summary']}: band power {meta['band_power_baseline']:.4g} "
          f"{meta['band_unit']}")
    print(f"best     {b['summary']} ({b['family']} {b['label']}): band power "
          f"{meta['band_power_best']:.4g}, gain {100 * meta['gain']:.1f} % (forecast)")
    mc = meta.get("monte_carlo")
    if mc:
        ran = f"{mc['realizations']} paired realisations"
        if mc["realizations"] < mc["most_realizations"]:
            ran += f" of {mc['most_realizations']}: the gain's error reached gain_error"
        print(f"Monte Carlo ({ran}): gain {100 * mc['gain']:.1f} ± "
              f"{100 * mc['gain_err']:.1f} %")
    for path in outputs:
        if path:
            print(f"wrote {path}")
    return 0
