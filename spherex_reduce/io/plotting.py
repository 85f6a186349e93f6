"""Figures people would rather look at than read.

Figures are built with `matplotlib.figure.Figure` (no pyplot state, no display
needed) and saved atomically with :func:`save_figure`.
"""

import numpy as np
from matplotlib.figure import Figure

from ..core._text import plural
from . import atomic_output

__all__ = ["bin_image", "plot_channel_layout", "plot_image", "plot_images", "plot_read_order",
           "save_figure", "show_image", "unit_label"]


def save_figure(fig, path, overwrite=False, dpi=120):
    """Save ``fig`` as PNG atomically; keep an existing file unless ``overwrite``."""
    with atomic_output(path, overwrite) as tmp:
        fig.savefig(tmp, format="png", dpi=dpi, bbox_inches="tight")
    return path


#: Font size (pt) of the read numbers of the read-order panel.
READ_NUMBER_SIZE = 7
#: Passes drawn at most in the read-order panel (fewer rows are shown to keep to it).
MAX_PASSES_SHOWN = 32
_ROW_PITCH = 10.0  # points between rows of the read-order panel: a read number's height and more
_LABEL_OFFSET = 4.0  # points from a read's dot to its number
_HEAD_CLEARANCE = 8.0  # points from a number's end to the next pass: an arrowhead and a gap
_REFERENCE_OFFSET = 12.0  # points from a reference row's dot to its numbers: clear of arrowheads


def plot_read_order(schedule, max_rows=48):
    """Draw the order in which rows are read, as in the paper's Fig. 3.

    Left: each physical row (down the page) with its read number and arrows
    from read to read, for the first ``max_rows`` rows (all of a small array;
    fewer when more than `MAX_PASSES_SHOWN` passes would be in them).  The
    passes are spaced and the figure sized so that every read number fits
    between its dot and the next pass's arrows (with many passes this panel
    takes a row of its own, above the other two).  Middle: physical row against
    read number for the whole frame, reference reads in red.  Right: the
    stored image's channels (`plot_channel_layout`).  Rows are those of the
    readout frame (the stored image's own when the channels are columns).

    Parameters
    ----------
    schedule : `~spherex_reduce.ReadoutSchedule`
    max_rows : int
        Rows shown in the left panel at most.

    Returns
    -------
    `matplotlib.figure.Figure`
        Its axes: the read order, the whole frame, the channels.

    Examples
    --------
    >>> from spherex_reduce import DetectorGeometry, ReadoutSchedule
    >>> from spherex_reduce.io.plotting import plot_read_order
    >>> fig = plot_read_order(ReadoutSchedule(DetectorGeometry(24, 8, 1, ref_border=2),
    ...                                       skip=4, ref_reads=4))
    >>> len(fig.axes)
    3
    """
    from matplotlib.textpath import TextPath

    rows, is_ref = schedule.rows, schedule.is_reference
    g = schedule.geometry
    passes = _passes(schedule)
    shown = min(g.nrows, max_rows)
    late = rows[(passes >= MAX_PASSES_SHOWN) & (rows < shown)]
    shown = int(late.min()) if late.size else shown
    sel = np.flatnonzero(rows < shown)
    columns = 2 + int(passes[sel][~is_ref[sel]].max(initial=-1))  # ref and the passes in view
    numbered = len(sel) <= 200
    refs = _reference_lines(sel, is_ref, rows) if numbered else {}
    widest = TextPath((0, 0), str(sel.max(initial=0)), size=READ_NUMBER_SIZE).get_extents().x1
    pitch = _LABEL_OFFSET + widest + _HEAD_CLEARANCE  # points from one pass to the next
    # the reference rows' lines to the left of their dots, where no arrow goes
    widest_ref = max((TextPath((0, 0), t, size=READ_NUMBER_SIZE - 0.5).get_extents().x1
                      for t in refs.values()), default=0.0)
    room = ((widest_ref + _REFERENCE_OFFSET + 4) if refs else 0.6 * pitch,  # points
            _LABEL_OFFSET + widest + 4)  # left of the first column, right of the last
    left = max(4.3, ((columns - 1) * pitch + sum(room)) / 72)  # inches
    height = max(6.4, shown * _ROW_PITCH / 72 + 1.9)
    if left <= 7.5:  # one row of three panels
        fig = Figure(figsize=(left + 11.7, height), layout="constrained")
        ax, ax2, ax3 = fig.subplots(1, 3, gridspec_kw={"width_ratios": [left, 6.2, 5.6]})
    else:  # many passes: the read order alone on the first row, to stay readable
        fig = Figure(figsize=(max(left + 1.2, 13.0), height + 6.4), layout="constrained")
        panels = fig.subplot_mosaic([["reads", "reads"], ["frame", "channels"]],
                                    height_ratios=[height, 6.4], width_ratios=[6.2, 5.6])
        ax, ax2, ax3 = panels["reads"], panels["frame"], panels["channels"]
    _draw_reads(ax, schedule, passes, sel, (shown, columns), refs, numbered)
    # right: the whole frame
    idx = np.arange(rows.size)
    ax2.plot(idx[~is_ref], rows[~is_ref], ".", ms=2, color="black", label="active read")
    ax2.plot(idx[is_ref], rows[is_ref], "o", ms=4, color="tab:red", label="reference read")
    ax2.set_xlabel(f"read index (each {schedule.row_samples} samples = "
                   f"{schedule.row_samples / schedule.geometry.pixel_rate * 1e6:.0f} µs)")
    ax2.set_ylabel("physical row")
    ax2.invert_yaxis()
    # outside the axes: inside it would cover reads, which fill the whole frame
    ax2.legend(loc="lower center", bbox_to_anchor=(0.5, 1.08), ncol=2, fontsize=8,
               frameon=False)
    ax2.set_title(f"{schedule.describe_order()}, "
                  f"c={schedule.phantom_reads}: {schedule.n_reads} reads, frame "
                  f"{schedule.frame_time.value:.4g} s", fontsize=9)
    if not g.layout.identity:
        for a in (ax, ax2):
            a.set_ylabel("row of the readout frame")
    if g.window is not None:
        _draw_window(ax2, g)
    _draw_channels(ax3, g.stored_geometry)
    _space_passes(ax, columns, pitch, room)
    return fig


def _space_passes(ax, columns, pitch, room):
    """Set the x range of the read-order panel ``ax`` once the layout has sized it: ``room``
    points left of the first column and right of the last, at least ``pitch`` points between
    columns (the figure widened if the panel is too narrow for that)."""
    fig = ax.figure
    need = (columns - 1) * pitch + sum(room)
    for _ in range(3):  # the layout gives the panel a share of the added width
        fig.get_layout_engine().execute(fig)
        width = ax.get_position().width * fig.get_figwidth() * 72  # points
        if width >= need - 0.5:
            break
        fig.set_figwidth(fig.get_figwidth() + 1.1 * (need - width) / 72)
    per_column = width / (columns - 1 + sum(room) / pitch)  # points per column, >= pitch
    ax.set_xlim(-room[0] / per_column, (width - room[0]) / per_column)


def _passes(schedule):
    """The pass of every read (0 for reference reads): pass k of a chopped order reads the
    active rows k, k + S, ...; of an explicit order, a run of active reads down the array."""
    rows, is_ref = schedule.rows, schedule.is_reference
    g = schedule.geometry
    if schedule.order is None:
        return np.where(is_ref, 0, (rows - g.border.top) % min(schedule.skip,
                                                               max(g.n_active_rows, 1)))
    active = rows[~is_ref]
    passes = np.zeros(rows.size, dtype=int)
    passes[~is_ref] = np.concatenate([[0], np.cumsum(np.diff(active) < 0)])
    return passes


def _reference_lines(sel, is_ref, rows):
    """``{row: "reads i, j, … (n×)"}`` of the reference rows among the reads ``sel``."""
    lines = {}
    for r in np.unique(rows[sel][is_ref[sel]]):
        reads = sel[is_ref[sel] & (rows[sel] == r)]
        listed = ", ".join(map(str, reads[:4])) + (", …" if reads.size > 4 else "")
        lines[int(r)] = f"reads {listed} ({reads.size}×)"
    return lines


def _draw_reads(ax, schedule, passes, sel, extent, refs, numbered):
    """The left panel of `plot_read_order` (Fig. 3 style): one column per pass, reference
    reads in the first column with their lines ``refs`` to its left, arrows joining
    consecutive reads, each read's number beside its dot (if ``numbered``); ``extent`` is
    the rows and columns shown (`_space_passes` sets the x range)."""
    shown, columns = extent
    rows, is_ref = schedule.rows, schedule.is_reference
    g = schedule.geometry
    nrows = g.nrows
    x = np.where(is_ref[sel], 0, 1 + passes[sel])
    y = rows[sel]
    for r in range(shown):
        if r < g.border.top or r >= nrows - g.border.bottom:
            ax.axhspan(r - 0.5, r + 0.5, color="0.88", lw=0)
    for k in range(len(sel) - 1):
        if sel[k + 1] != sel[k] + 1:  # a jump over rows outside the panel
            continue
        same = x[k + 1] == x[k]
        ax.annotate("", xy=(x[k + 1], y[k + 1]), xytext=(x[k], y[k]),
                    arrowprops={"arrowstyle": "->", "lw": 0.9 if same else 0.6,
                                "color": "black" if same else "tab:red",
                                "linestyle": "-" if same else "--", "shrinkA": 4, "shrinkB": 4})
    ax.scatter(x, y, s=12, c=np.where(is_ref[sel], "tab:red", "black"), zorder=3)
    if numbered:
        # active rows are read once: the number beside the dot, in the room the passes'
        # spacing leaves before the next pass's arrows; a reference row is read many times
        # at the same place, so its numbers go on one line left of its dot
        for xi, yi, i in zip(x[~is_ref[sel]], y[~is_ref[sel]], sel[~is_ref[sel]], strict=True):
            ax.annotate(str(i), (xi, yi), xytext=(_LABEL_OFFSET, 0),
                        textcoords="offset points", va="center",
                        fontsize=READ_NUMBER_SIZE, color="0.25", zorder=4,
                        bbox={"boxstyle": "square,pad=0.05", "fc": "white", "ec": "none",
                              "alpha": 0.8})
        for r, text in refs.items():
            ax.annotate(text, (0, r), xytext=(-_REFERENCE_OFFSET, 0),
                        textcoords="offset points", va="center", ha="right",
                        fontsize=READ_NUMBER_SIZE - 0.5, color="tab:red", zorder=4)
    ax.set_ylim(shown - 0.5, -0.5)
    ax.set_xticks(range(columns), ["ref"] + [str(k) for k in range(columns - 1)], fontsize=9)
    ax.set_xlabel("pass (dashed red: return to the first unread row)" if schedule.order is None
                  else "pass: a run of reads down the array (dashed red: a jump back up)")
    ax.set_ylabel("physical row")
    ax.set_title(f"read order, first {shown} rows (grey: reference rows)\n"
                 "numbers: read index within the frame", fontsize=9)


def plot_channel_layout(geometry):
    """Draw where each output channel lies on the stored image.

    Each channel's rectangle (numbered), its fast-scan direction (an arrow
    along the first row it reads) and its first-read pixel (a dot); the
    reference border shaded.  Row 0 is at the bottom, as ds9 and
    `plot_image` show the stored image; axes in pixels of the stored image.

    Parameters
    ----------
    geometry : `~spherex_reduce.DetectorGeometry`
        The stored image's geometry (a readout frame draws its `stored`).

    Returns
    -------
    `matplotlib.figure.Figure`

    Examples
    --------
    >>> from spherex_reduce import DetectorGeometry
    >>> from spherex_reduce.io.plotting import plot_channel_layout
    >>> fig = plot_channel_layout(DetectorGeometry.from_preset("WFC3-IR"))
    >>> len(fig.axes[0].patches)  # 4 reference strips, 4 channels
    8
    """
    fig = Figure(figsize=(6, 6.6), layout="constrained")
    _draw_channels(fig.subplots(), geometry.stored_geometry)
    return fig


def _draw_channels(ax, g):
    """The channel-layout panel of `plot_read_order` and `plot_channel_layout` on ``ax``."""
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch, Rectangle

    frame, lay = g.frame, g.layout
    size = max(g.nrows, g.ncols)
    seen = 0.012 * size  # narrower strips are drawn this wide, to be seen
    top, bottom, left, right = (0 if w == 0 else max(w, seen) for w in g.border.sides().values())
    for x, y, w, h in ((0, 0, g.ncols, top), (0, g.nrows - bottom, g.ncols, bottom),
                       (0, 0, left, g.nrows), (g.ncols - right, 0, right, g.nrows)):
        if w and h:
            ax.add_patch(Rectangle((x - 0.5, y - 0.5), w, h, color="0.8", lw=0, zorder=1))
    exaggerated = any(0 < w < seen for w in g.border.sides().values())
    width, last = frame.channel_width, frame.nrows - 1
    numbered = g.nchannels <= 8  # more would crowd: the channels count from the left
    head = 0.35 * min(g.nrows, g.ncols) / max(np.sqrt(g.nchannels), 1) / 4
    for ch, direction in enumerate(frame.scan_directions):
        lo, hi = ch * width, (ch + 1) * width - 1
        rows, cols = lay.stored_coordinates(np.array([0, 0, last, last]),
                                            np.array([lo, hi, lo, hi]))
        ax.add_patch(Rectangle((cols.min() - 0.5, rows.min() - 0.5), np.ptp(cols) + 1,
                               np.ptp(rows) + 1, fill=False, ec="tab:blue", lw=1.2,
                               zorder=2))
        start, end = (lo, hi) if direction > 0 else (hi, lo)
        (r0, r1), (c0, c1) = lay.stored_coordinates(np.array([0, 0]), np.array([start, end]))
        ax.annotate("", xy=(c1, r1), xytext=(c0, r0), zorder=4,
                    arrowprops={"arrowstyle": f"-|>,head_length={min(head, 0.6):.2f},"
                                              f"head_width={min(head, 0.6) / 2:.2f}",
                                "color": "tab:orange", "lw": 1.4})
        ax.plot([c0], [r0], "o", color="tab:red", ms=5 if numbered else 3, zorder=5,
                clip_on=False)
        if numbered:
            ax.text(cols.mean(), rows.mean(), str(ch), ha="center", va="center",
                    fontsize=11, color="tab:blue", zorder=3)
    pad = 0.04 * size
    ax.set_xlim(-0.5 - pad, g.ncols - 0.5 + pad)
    ax.set_ylim(-0.5 - pad, g.nrows - 0.5 + pad)  # row 0 at the bottom, as ds9 shows it
    ax.set_aspect("equal")
    ax.set_xlabel("column (pixel)")
    ax.set_ylabel("row (pixel)")
    named = f"{g.preset}: " if g.preset else ""
    how = {"columns": "stripes of columns", "rows": "bands of rows, read along the columns",
           "quadrants": f"quadrants from the {g.first_corner} corner, along {g.fast_axis}"}
    ax.set_title(f"{named}stored image {g.nrows} x {g.ncols}, {plural(g.nchannels, 'channel')}\n"
                 f"{how[g.channels]}", fontsize=9)
    handles = [Patch(fc="none", ec="tab:blue", label="channel (number)" if numbered
                     else "channel"),
               Line2D([], [], color="tab:orange", marker=">", label="fast-scan direction"),
               Line2D([], [], color="tab:red", marker="o", ls="none",
                      label="first pixel read"),
               Patch(color="0.8", label="reference border" + (" (drawn wider)"
                                                               if exaggerated else ""))]
    ax.legend(handles=handles, loc="upper center", bbox_to_anchor=(0.5, -0.1), ncol=2,
              fontsize=8, frameon=False)


def _draw_window(ax, geometry):
    """An inset in the empty lower left of ``ax``: the full array with its channel
    boundaries, and the window (``geometry``) as a filled rectangle in it; row 0 at the
    bottom, as ds9 shows the array."""
    from matplotlib.patches import Rectangle

    w = geometry.window
    f = w.full
    inset = ax.inset_axes([0.03, 0.03, 0.3, 0.3])
    inset.add_patch(Rectangle((0, 0), f.ncols, f.nrows, fill=False, lw=0.8))
    for col in range(f.channel_width, f.ncols, f.channel_width):
        inset.axvline(col, lw=0.3, color="0.7")
    inset.add_patch(Rectangle((w.first_column, w.first_row), geometry.ncols, geometry.nrows,
                              color="tab:blue", alpha=0.7, label="window"))
    # a marker too: a corner cutout is a few pixels of a 4096-pixel-wide inset
    inset.plot(w.first_column + geometry.ncols / 2, w.first_row + geometry.nrows / 2, "o",
               color="tab:blue", ms=4, clip_on=False)
    inset.set_xlim(0, f.ncols)
    inset.set_ylim(0, f.nrows)
    inset.set_xticks([])
    inset.set_yticks([0, f.nrows], ["row 0", str(f.nrows)], fontsize=6)
    inset.set_title(f"window in the {f.nrows}x{f.ncols} array", fontsize=7)


def unit_label(unit):
    """A unit as LaTeX for an axis label (``""`` for none or dimensionless).

    Examples
    --------
    >>> from astropy import units as u
    >>> from spherex_reduce.io.plotting import unit_label
    >>> print(unit_label(u.electron**2 * u.pix**2 / u.s**2))
    $\\mathrm{electron^{2}\\,pix^{2}\\,s^{-2}}$
    """
    from astropy import units as u

    if unit is None or unit == "":
        return ""
    unit = u.Unit(unit)
    return "" if unit == u.one else unit.to_string("latex_inline")


def bin_image(data, max_pixels=400):
    """Block means of ``data`` so that neither side exceeds ``max_pixels``.

    Drawing a large image on a few hundred screen pixels picks every n-th
    pixel, which turns noise into moiré; block means show what is there.
    NaN pixels are left out of their block's mean (a block of NaN only is NaN).

    Parameters
    ----------
    data : 2-D array
    max_pixels : int
        Largest number of blocks along a side.

    Returns
    -------
    binned : `numpy.ndarray`
        The block means (``data`` itself, as float, when it is small enough).
    factor : int
        Pixels per block along each side; the last block of a side may hold fewer.

    Examples
    --------
    >>> import numpy as np
    >>> from spherex_reduce.io.plotting import bin_image
    >>> b, f = bin_image(np.arange(16.0).reshape(4, 4), max_pixels=2)
    >>> f, b.tolist()
    (2, [[2.5, 4.5], [10.5, 12.5]])
    """
    data = np.asarray(data, dtype=float)
    factor = max(1, -(-max(data.shape) // int(max_pixels)))
    if factor == 1:
        return data, 1
    ny, nx = (-(-n // factor) for n in data.shape)
    padded = np.full((ny * factor, nx * factor), np.nan)
    padded[: data.shape[0], : data.shape[1]] = data
    blocks = padded.reshape(ny, factor, nx, factor)
    good = np.isfinite(blocks)
    count = good.sum(axis=(1, 3))
    total = np.where(good, blocks, 0.0).sum(axis=(1, 3))
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(count > 0, total / np.maximum(count, 1), np.nan), factor


def _masked(image):
    data = np.asarray(getattr(image, "data", image), dtype=float)
    mask = getattr(image, "mask", None)
    if mask is not None:
        data = np.where(np.asarray(mask) != 0, np.nan, data)
    return data


def show_image(ax, data, colorbar_label="", **imshow):
    """Draw an image on ``ax`` as ds9 shows it, with a colour bar as tall as the panel.

    Row 0 at the bottom (``origin="lower"``); the colour bar in an inset
    axes just right of the panel, so it has the panel's height whatever its
    aspect (a colour bar taking its height from the panel's grid cell is
    taller than a square image in a wide cell).

    Parameters
    ----------
    ax : `matplotlib.axes.Axes`
    data : 2-D array
    colorbar_label : str
        Label of the colour bar (say its unit).
    **imshow
        Keywords of `matplotlib.axes.Axes.imshow` (``extent`` as
        ``(left, right, bottom, top)``); ``origin`` is not one of them.

    Returns
    -------
    `matplotlib.image.AxesImage`
        Its ``colorbar`` is the colour bar.

    Examples
    --------
    >>> import numpy as np
    >>> from matplotlib.figure import Figure
    >>> from spherex_reduce.io.plotting import show_image
    >>> ax = Figure(layout="constrained").subplots()
    >>> im = show_image(ax, np.arange(6.0).reshape(2, 3), "e/s")
    >>> im.origin, im.colorbar.ax.get_ylabel()
    ('lower', 'e/s')
    """
    im = ax.imshow(data, origin="lower", **imshow)
    cax = ax.inset_axes([1.03, 0.0, 0.05, 1.0])
    ax.figure.colorbar(im, cax=cax, label=colorbar_label)
    return im


def plot_images(images, title="", unit="", percentile=(1, 99), max_pixels=400):
    """Images side by side, on one grey scale, each with a colour bar.

    Row 0 at the bottom, as ds9 shows an image (`show_image`).

    One stretch (the ``percentile`` range of all the panels' pixels together)
    so that the panels can be compared by eye.  Images larger than
    ``max_pixels`` are shown as block means (`bin_image`), never decimated.

    Parameters
    ----------
    images : dict of label -> array-like or `~astropy.nddata.CCDData`
        Masked pixels (``mask`` True) and NaN are shown blank.
    title : str
        Title of the figure.
    unit : str or `~astropy.units.Unit`
        Unit of the colour bars (taken from the first image that has one if
        not given).
    percentile : (float, float)
        Percentiles of the shown pixels at the ends of the grey scale.
    max_pixels : int
        Largest number of shown pixels along a side.

    Returns
    -------
    `matplotlib.figure.Figure`
        One axes and one colour bar per image, all with the same ``norm``.

    Examples
    --------
    >>> import numpy as np
    >>> from spherex_reduce.io.plotting import plot_images
    >>> rng = np.random.default_rng(0)
    >>> fig = plot_images({"a": rng.normal(size=(64, 64)), "b": rng.normal(size=(64, 64))})
    >>> a, b = fig.axes[0].images[0], fig.axes[1].images[0]
    >>> a.norm is b.norm
    True
    """
    from matplotlib.colors import Normalize

    if not unit:
        unit = next((getattr(im, "unit", None) for im in images.values()
                     if getattr(im, "unit", None) is not None), "")
    shown = {}
    for label, image in images.items():
        data = _masked(image)
        binned, factor = bin_image(data, max_pixels)
        shown[label] = (binned, factor, data.shape)
    finite = np.concatenate([b[np.isfinite(b)] for b, _, _ in shown.values()])
    lo, hi = np.percentile(finite, percentile) if finite.size else (0.0, 1.0)
    norm = Normalize(vmin=lo, vmax=hi if hi > lo else lo + 1)
    n = len(shown)
    fig = Figure(figsize=(5.6 * n + 0.4, 5.2), layout="constrained")
    axes = np.atleast_1d(fig.subplots(1, n))
    label = unit_label(unit)
    for ax, (name, (binned, factor, (ny, nx))) in zip(axes, shown.items(), strict=True):
        extent = (-0.5, binned.shape[1] * factor - 0.5, -0.5, binned.shape[0] * factor - 0.5)
        show_image(ax, binned, label, norm=norm, cmap="gray", interpolation="nearest",
                   extent=extent)
        ax.set_xlim(-0.5, nx - 0.5)
        ax.set_ylim(-0.5, ny - 0.5)
        ax.set_xlabel("column")
        ax.set_ylabel("row")
        note = f"({factor}×{factor}-pixel means)" if factor > 1 else ""
        ax.set_title("\n".join(t for t in (name, note) if t), fontsize=9)
    if title:
        fig.suptitle(title, fontsize=10)
    return fig


def plot_image(image, title="", unit="", percentile=(1, 99), max_pixels=400):
    """Show a 2-D image with a colour bar, stretched between two percentiles.

    Parameters
    ----------
    image : array-like or `~astropy.nddata.CCDData`
        Masked pixels (``mask`` True) are shown blank.
    title : str
    unit : str or `~astropy.units.Unit`
    percentile : (float, float)
    max_pixels : int
        Larger images are shown as block means (`bin_image`).

    Returns
    -------
    `matplotlib.figure.Figure`

    Examples
    --------
    >>> import numpy as np
    >>> from spherex_reduce.io.plotting import plot_image
    >>> fig = plot_image(np.ones((1000, 10)), "flat")
    >>> fig.axes[0].images[0].get_array().shape   # 3 x 3 means: 334 x 4 shown
    (334, 4)
    """
    return plot_images({"": image}, title=title, unit=unit, percentile=percentile,
                       max_pixels=max_pixels)
