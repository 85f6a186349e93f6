"""What a user sees: command output, help texts and the plots (issue 11, section 3).

Plots are checked for what can be checked without looking: texts that must not
overlap (their window extents after a draw), labels that carry the real unit,
error bars drawn where the legend shows them, no bar end at or below zero on a
log axis, one colour stretch for panels meant to be compared, binned (not
decimated) large images.
"""

import numpy as np
import pytest
from astropy import units as u
from astropy.table import Table

from spherex_reduce.cli import main

SWEEP = {
    "scene": {"geometry": {"nrows": 64, "ncols": 64, "nchannels": 4, "ref_border": 4},
              "readout": {"nframes": 4, "phantom_reads": 2, "ref_reads": 8}},
    "grid": {"skip": [1, 4], "ref_mode": ["repeated", "distributed"]},
    "realizations": 1,
    "seed": 3,
    "measure": {"kmin": 0.1, "kmax": 1.0, "bins": 6},
}


def _lines(fig):
    """``(label, x, y)`` of every error-bar series of the first axes."""
    ax = fig.axes[0]
    return sorted((c.get_label(), tuple(c.lines[0].get_xdata()), tuple(c.lines[0].get_ydata()))
                  for c in ax.containers)


# -- sweep --plot -------------------------------------------------------------------------
def test_sweep_plot_in_memory_equals_plot_of_the_file(tmp_path, monkeypatch):
    """The in-memory results carry the grid, so ``--plot`` draws against the first key."""
    import yaml

    import spherex_reduce.plotting as plotting
    from spherex_reduce.analysis.sweep import plot_sweep

    drawn = []
    real_save = plotting.save_figure
    monkeypatch.setattr(plotting, "save_figure",
                        lambda fig, *a, **k: (drawn.append(fig), real_save(fig, *a, **k))[1])
    path = tmp_path / "sweep.yaml"
    path.write_text(yaml.safe_dump(SWEEP, sort_keys=False))
    out = tmp_path / "res.ecsv"
    assert main(["-q", "sweep", str(path), "-o", str(out), "--scheduler", "serial",
                 "--plot"]) == 0
    (fig,) = drawn
    assert fig.axes[0].get_xlabel() == "skip"
    from_file = plot_sweep(Table.read(out))
    assert _lines(fig) == _lines(from_file)
    # one line per ref_mode, two points (skip 1, 4) each
    assert [(lab, x) for lab, x, _ in _lines(fig)] == [
        ("ref_mode=distributed", (1, 4)), ("ref_mode=repeated", (1, 4))]
