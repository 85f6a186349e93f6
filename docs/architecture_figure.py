"""The architecture picture of docs/architecture.rst, drawn when the docs are built.

Left: the layers of the package (``[tool.importlinter]`` in pyproject.toml),
imports pointing down, and the rooms (subpackages) of each layer with their
public entry.  Right: the data flow of a reduction, one executor pass
and the steps run whole after it.  To look at it without building the docs::

    MPLBACKEND=Agg python -c "exec(open('docs/architecture_figure.py').read());
    plt.savefig('architecture.png', bbox_inches='tight')"
"""

import matplotlib.pyplot as plt
from matplotlib.patches import FancyArrowPatch, FancyBboxPatch

LAYERS = [  # (folder, what it holds), top to bottom: each imports only from those below
    ("cli/", "spherex-reduce subcommands"),
    ("analysis/", "run_case, P(k), temporal PSDs,\nsweeps, compare-strategies"),
    ("simulation/", "noise engine, scenes, slope\nroutes, the simulator's plugin"),
    ("reduce/", "pipeline, passes, executor,\nStep, plugins, provenance,\n"
                "batch; steps/: unchop, phantom,\nclipping, dark, pairs, pixel_maps"),
    ("io/", "open_input and the sources,\nwriter, config, plotting"),
    ("noise/", "components, PSDs, slope\nstatistics, read covariances"),
    ("core/", "exposure, block, geometry,\nfields, dq, errors, parameters"),
]
LAYER_COLOURS = ["#d9d9d9", "#fde0c5", "#fde0c5", "#d9ead3", "#fff2cc", "#cfe2f3", "#ead1dc"]
ROOMS = {  # layer: its rooms (subpackages), each (folder, its public entry)
    "analysis/": [("forecast/", "forecast()"), ("design/", "design_readout()"),
                  ("figures/", "make_figures(), demo")],
    "reduce/": [("steps/reference/", "correct_reference()"),
                ("steps/fit_ramp/", "fit_ramp()"), ("steps/jumps/", "detect_jumps()")],
    "io/": [("readers/", "read(), every layout")],
    "core/": [("readout/", "ReadoutSchedule")],
}


def box(ax, x, y, w, h, text, colour, size=9, weight="normal"):
    ax.add_patch(FancyBboxPatch((x, y), w, h, boxstyle="round,pad=0.02,rounding_size=0.08",
                                facecolor=colour, edgecolor="0.25", linewidth=1))
    ax.text(x + w / 2, y + h / 2, text, ha="center", va="center", fontsize=size,
            weight=weight, linespacing=1.25)


def arrow(ax, start, end, text=None, offset=(0.08, 0), style="-|>", colour="0.2", size=8):
    ax.add_patch(FancyArrowPatch(start, end, arrowstyle=style, mutation_scale=14,
                                 color=colour, linewidth=1.3, shrinkA=0, shrinkB=0))
    if text:
        ax.text((start[0] + end[0]) / 2 + offset[0], (start[1] + end[1]) / 2 + offset[1],
                text, fontsize=size, ha="left", va="center", color=colour)


def layers_panel(ax):
    ax.set_title("Layers (folders of spherex_reduce/): imports only go down;\n"
                 "rooms (subpackages) and their public entry on the right",
                 fontsize=10.5, loc="left")
    room_h, gap, w, room_x = 0.36, 0.3, 7.4, 4.25
    heights = [max(0.78, len(ROOMS.get(name, [])) * (room_h + 0.06) + 0.08,
                   0.2 * (what.count("\n") + 1) + 0.16) for name, what in LAYERS]
    top = sum(heights) + gap * len(LAYERS)
    y = top
    for i, ((name, what), colour, h) in enumerate(zip(LAYERS, LAYER_COLOURS, heights,
                                                      strict=True)):
        y -= h + gap
        box(ax, 0, y, 1.4, h, name, colour, size=10, weight="bold")
        box(ax, 1.5, y, room_x - 1.6, h, what, colour, size=8)
        rooms = ROOMS.get(name, [])
        for r, (room, entry) in enumerate(rooms):
            ry = y + h - 0.06 - (r + 1) * (room_h + 0.06) + 0.02
            box(ax, room_x, ry, w - room_x, room_h, "", colour, size=8)
            ax.text(room_x + 0.08, ry + room_h / 2, room, fontsize=8, weight="bold",
                    ha="left", va="center")
            ax.text(w - 0.08, ry + room_h / 2, entry, fontsize=8, ha="right",
                    va="center", family="monospace")
        if i:
            arrow(ax, (0.6, y + h + gap - 0.02), (0.6, y + h + 0.02))
    ax.text(0.7, top - heights[0] - 1.5 * gap, "imports", fontsize=8, va="center",
            color="0.2")
    ax.set_xlim(-0.1, w + 0.1)
    ax.set_ylim(-0.1, top + 0.1)


def flow_panel(ax):
    ax.set_title("Data flow of a reduction", fontsize=11, loc="left")
    file_c, exe_c, step_c, out_c = "#fff2cc", "#f3f3f3", "#d9ead3", "#ead1dc"
    # sources
    box(ax, 0.0, 7.75, 2.35, 0.85, "raw FITS file, read files,\n4-D file, reader", file_c,
        size=8)
    box(ax, 2.65, 7.75, 2.35, 0.85, "Exposure in memory\n(readout order)", file_c, size=8)
    box(ax, 0.0, 6.35, 5.0, 0.85,
        "open_input → a source: FileSource (pread of rows of every frame)\n"
        "or MemorySource (views of the Exposure)", exe_c, size=8)
    arrow(ax, (1.17, 7.75), (1.17, 7.2))
    arrow(ax, (3.82, 7.75), (3.82, 7.2))
    # side block and bands
    box(ax, 0.0, 4.55, 1.9, 1.15, "side block\n(reference reads\nof every frame)",
        exe_c, size=8)
    box(ax, 2.35, 4.55, 2.65, 1.15, "bands of rows\nof every frame\n(on several threads)",
        exe_c, size=8)
    arrow(ax, (0.95, 6.35), (0.95, 5.7))
    arrow(ax, (3.67, 6.35), (3.67, 5.7))
    # kernels
    box(ax, 0.0, 2.85, 1.9, 1.05, "Kernel.prepare\n→ coefficients\n(apply_side)",
        step_c, size=8)
    box(ax, 2.35, 2.85, 2.65, 1.05,
        "Kernel.apply, in YAML order:\nunchop → subtract_phantom\n→ correct_reference",
        step_c, size=8)
    arrow(ax, (0.95, 4.55), (0.95, 3.9))
    arrow(ax, (3.67, 4.55), (3.67, 3.9))
    arrow(ax, (1.9, 3.37), (2.35, 3.37))
    # consumer and the rest
    box(ax, 2.35, 1.45, 2.65, 0.85, "Consumer.band → finish\n(fit_ramp: slopes)",
        step_c, size=8)
    arrow(ax, (3.67, 2.85), (3.67, 2.3))
    box(ax, 0.0, 1.45, 1.9, 0.85, "Kernel.record\ntables, cards", step_c, size=8)
    arrow(ax, (0.95, 2.85), (0.95, 2.3))
    box(ax, 0.0, 0.0, 5.0, 0.85,
        "Exposure → steps run whole (sigma_clip, subtract_dark, pair_difference)\n"
        "→ FITS file with S_* keywords and the PROVENANCE table", out_c, size=8)
    arrow(ax, (3.67, 1.45), (3.67, 0.85))
    arrow(ax, (0.95, 1.45), (0.95, 0.85))
    ax.text(5.12, 4.3, "one pass of\nthe executor\n(grey: io/sources.py\nand executor.py,\n"
            "green: the steps'\nkernels and\nconsumer, in\nreduce/steps/)",
            fontsize=8, va="center", color="0.2")
    ax.plot([5.06, 5.06], [1.45, 7.2], color="0.4", linewidth=1)
    ax.set_xlim(-0.1, 6.6)
    ax.set_ylim(-0.1, 8.7)


def architecture_figure():
    """The figure (a pyplot figure, for the plot directive)."""
    fig, (left, right) = plt.subplots(1, 2, figsize=(14.5, 7.4),
                                      gridspec_kw={"width_ratios": [1.45, 1.0]})
    for ax in (left, right):
        ax.set_axis_off()
    layers_panel(left)
    flow_panel(right)
    fig.subplots_adjust(left=0.01, right=0.99, top=0.93, bottom=0.02, wspace=0.08)
    return fig


architecture_figure()  # the plot directive runs this file and saves the pyplot figure
