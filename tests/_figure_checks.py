"""Checks of drawn figures that need no eyes: texts that overlap, arrowheads under texts,
error bars drawn, images as ds9 shows them, colour bars as tall as their panels, axes
limits that hold every line."""

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


def arrowheads(ax):
    """Window extents of the heads of the arrows of ``ax``'s annotations (after `drawn`):
    the last piece of an arrow's path (an arrow without a separate head has none)."""
    from matplotlib.path import Path
    from matplotlib.transforms import Bbox

    heads = []
    for text in ax.texts:
        patch = getattr(text, "arrow_patch", None)
        if patch is None:
            continue
        path = patch.get_transform().transform_path(patch.get_path())
        starts = np.flatnonzero(np.asarray(path.codes) == Path.MOVETO) if path.codes is not \
            None else []
        if len(starts) > 1:
            xy = path.vertices[starts[-1]:]
            heads.append(Bbox.from_extents(*xy.min(axis=0), *xy.max(axis=0)))
    return heads


def text_boxes(ax, renderer):
    """``(text, window extent)`` of the texts drawn in ``ax`` (not its arrows' own extents)."""
    from matplotlib.text import Text

    return [(t.get_text(), Text.get_window_extent(t, renderer)) for t in ax.texts
            if t.get_text()]


def inside(inner, outer, slack=0.5):
    """Whether window extent ``inner`` lies within ``outer`` (``slack`` pixels allowed)."""
    return (inner.x0 >= outer.x0 - slack and inner.x1 <= outer.x1 + slack
            and inner.y0 >= outer.y0 - slack and inner.y1 <= outer.y1 + slack)


def images_and_colorbars(fig):
    """``(panel axes, its image, its colour bar's axes)`` for every image drawn in ``fig``."""
    out = []
    for ax in fig.axes:
        for image in ax.images:
            cbar = image.colorbar
            out.append((ax, image, None if cbar is None else cbar.ax))
    return out


def line_data_within_limits(ax):
    """Labels of the lines of ``ax`` with finite data outside its limits (log axes: positive
    data only, as drawn)."""
    lo_x, hi_x = sorted(ax.get_xlim())
    lo_y, hi_y = sorted(ax.get_ylim())
    outside = []
    for line in ax.get_lines():
        x = np.asarray(line.get_xdata(), float)
        y = np.asarray(line.get_ydata(), float)
        if line.get_transform().contains_branch_seperately(ax.transData) != (True, True):
            x = np.full_like(y, (lo_x + hi_x) / 2)  # a horizontal line: y in data, x in axes
        good = np.isfinite(x) & np.isfinite(y)
        if ax.get_yscale() == "log":
            good &= y > 0
        if ax.get_xscale() == "log":
            good &= x > 0
        if np.any((y[good] < lo_y) | (y[good] > hi_y)):
            outside.append(line.get_label())
    return outside


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
