"""Figures people would rather look at than read.

Figures are built with `matplotlib.figure.Figure` (no pyplot state, no display
needed) and saved atomically with :func:`save_figure`.
"""

import numpy as np
from matplotlib.figure import Figure

from .fits_format import atomic_output

__all__ = ["plot_image", "plot_read_order", "save_figure"]


def save_figure(fig, path, overwrite=False, dpi=120):
    """Save ``fig`` as PNG atomically; keep an existing file unless ``overwrite``."""
    with atomic_output(path, overwrite) as tmp:
        fig.savefig(tmp, format="png", dpi=dpi, bbox_inches="tight")
    return path


def plot_read_order(schedule, max_rows=48):
    """Draw the order in which rows are read, as in the paper's Fig. 3.

    Left: each physical row (down the page) with its read number and arrows
    from read to read, for the first ``max_rows`` rows (all of a small array).
    Right: physical row against read number for the whole frame, reference
    reads in red.

    Parameters
    ----------
    schedule : `~spherex_reduce.ReadoutSchedule`
    max_rows : int
        Rows shown in the left panel.

    Returns
    -------
    `matplotlib.figure.Figure`

    Examples
    --------
    >>> from spherex_reduce import DetectorGeometry, ReadoutSchedule
    >>> from spherex_reduce.plotting import plot_read_order
    >>> fig = plot_read_order(ReadoutSchedule(DetectorGeometry(24, 8, 1, ref_border=2),
    ...                                       skip=4, ref_reads=4))
    >>> len(fig.axes)
    2
    """
    rows, is_ref = schedule.rows, schedule.is_reference
    nrows = schedule.geometry.nrows
    shown = min(nrows, max_rows)
    fig = Figure(figsize=(11, 6))
    ax, ax2 = fig.subplots(1, 2, gridspec_kw={"width_ratios": [1, 1.4]})
    # left: Fig. 3 style. One column per chopping pass (pass k reads active rows
    # k, k+S, ...), reference reads in the first column; arrows join consecutive reads.
    g = schedule.geometry
    sel = np.flatnonzero(rows < shown)
    npass = min(schedule.skip, max(g.n_active_rows, 1))
    x = np.where(is_ref[sel], 0, 1 + (rows[sel] - g.ref_border) % npass)
    y = rows[sel]
    for r in range(shown):
        ref = r < g.ref_border or r >= nrows - g.ref_border
        if ref:
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
    if len(sel) <= 200:
        for xi, yi, i in zip(x, y, sel, strict=True):
            ax.text(xi + 0.12, yi, str(i), va="center", fontsize=6,
                    color="tab:red" if is_ref[i] else "0.3")
    ax.set_xlim(-0.6, npass + 0.8)
    ax.set_ylim(shown - 0.5, -0.5)
    ax.set_xticks(range(npass + 1), ["ref"] + [str(k) for k in range(npass)],
                  fontsize=7 if npass < 16 else 5)
    ax.set_xlabel("pass (dashed red: return to the first unread row)")
    ax.set_ylabel("physical row")
    ax.set_title(f"read order, first {shown} rows (grey: reference rows)\n"
                 "numbers: read index within the frame", fontsize=9)
    # right: the whole frame
    idx = np.arange(rows.size)
    ax2.plot(idx[~is_ref], rows[~is_ref], ".", ms=2, color="black", label="active read")
    ax2.plot(idx[is_ref], rows[is_ref], "o", ms=4, color="tab:red", label="reference read")
    ax2.set_xlabel(f"read index (each {schedule.row_samples} samples = "
                   f"{schedule.row_samples / schedule.geometry.pixel_rate * 1e6:.0f} µs)")
    ax2.set_ylabel("physical row")
    ax2.invert_yaxis()
    ax2.legend(loc="upper right", fontsize=8)
    ax2.set_title(f"S={schedule.skip}, r={schedule.ref_reads} ({schedule.ref_mode}), "
                  f"c={schedule.phantom_reads}: {schedule.n_reads} reads, frame "
                  f"{schedule.frame_time.value:.4g} s", fontsize=9)
    return fig


def plot_image(image, title="", unit="", percentile=(1, 99)):
    """Show a 2-D image with a colour bar, stretched between two percentiles.

    Parameters
    ----------
    image : array-like or `~astropy.nddata.CCDData`
        Masked pixels (``mask`` True) are shown blank.

    Returns
    -------
    `matplotlib.figure.Figure`
    """
    data = np.asarray(getattr(image, "data", image), dtype=float)
    mask = getattr(image, "mask", None)
    if mask is not None:
        data = np.where(np.asarray(mask) != 0, np.nan, data)
    finite = data[np.isfinite(data)]
    lo, hi = np.percentile(finite, percentile) if finite.size else (0, 1)
    fig = Figure(figsize=(6, 5))
    ax = fig.subplots()
    im = ax.imshow(data, origin="upper", vmin=lo, vmax=hi, cmap="gray", interpolation="nearest")
    fig.colorbar(im, ax=ax, label=unit)
    ax.set_xlabel("column")
    ax.set_ylabel("row")
    ax.set_title(title, fontsize=10)
    return fig
