"""Checks of drawn figures that need no eyes: texts that overlap, error bars drawn."""

import numpy as np


def drawn(fig):
    """Draw ``fig`` (running its layout) and return the renderer."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    FigureCanvasAgg(fig).draw()
    return fig.canvas.get_renderer()


def overlaps(a, b, slack=0.5):
    """Whether two window extents overlap by more than ``slack`` pixels."""
    return (min(a.x1, b.x1) - max(a.x0, b.x0) > slack
            and min(a.y1, b.y1) - max(a.y0, b.y0) > slack)


def tick_labels(ax, renderer):
    """``(text, window extent)`` of the tick labels ``ax`` draws (major and minor)."""
    labels = []
    for axis in (ax.xaxis, ax.yaxis):
        lo, hi = sorted(axis.get_view_interval())
        for minor in (False, True):
            ticks = axis.get_minor_ticks() if minor else axis.get_major_ticks()
            locs = axis.get_minorticklocs() if minor else axis.get_majorticklocs()
            for tick, loc in zip(ticks, locs, strict=False):
                label = tick.label1
                if lo <= loc <= hi and label.get_visible() and label.get_text():
                    labels.append(label)
    return [(t.get_text(), t.get_window_extent(renderer)) for t in labels]


def errorbar_ends(ax):
    """Lower and upper ends of every drawn error bar."""
    ends = []
    for c in ax.containers:
        for col in c.lines[2]:
            for seg in col.get_segments():
                seg = np.asarray(seg, float).reshape(-1, 2)
                if len(seg):  # points left out have no bar
                    ends.append((seg[:, 1].min(), seg[:, 1].max()))
    return np.array(ends).reshape(-1, 2)


def saved_figures(module, argv):
    """Run ``spherex-reduce ARGV`` and return the figures ``module.save_figure`` saved, by
    file name (each also written as usual)."""
    import pytest

    from spherex_reduce.cli import main

    figs = {}
    real_save = module.save_figure
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(module, "save_figure", lambda fig, path, *a, **k: (
            figs.setdefault(path.name, fig), real_save(fig, path, *a, **k))[1])
        assert main(argv) == 0
    return figs
