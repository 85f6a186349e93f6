"""The demonstration run behind ``spherex-reduce demo``."""

from pathlib import Path

import numpy as np

from .examples import example_raw_exposure, tiny_schedule
from .fits_format import atomic_output, write
from .pipeline import Pipeline
from .plotting import plot_image, plot_read_order, save_figure

__all__ = ["run_demo"]


def run_demo(outdir, overwrite=False, progress=True):
    """Write the demo products to ``outdir``; yields lines of a summary.

    Products: the raw exposure (``raw.fits``), the reduced one
    (``reduced.fits``), the schedule table (``schedule.ecsv``), the read
    order (``read_order.png``) and the reduced image (``reduced.png``).
    """
    outdir = Path(outdir)
    outdir.mkdir(parents=True, exist_ok=True)
    names = ["raw.fits", "reduced.fits", "schedule.ecsv", "read_order.png", "reduced.png"]
    for name in names:  # refuse before doing any work
        atomic_output(outdir / name, overwrite)
    schedule = tiny_schedule()
    yield schedule.summary()
    raw = example_raw_exposure(schedule, seed=1)
    write(raw, outdir / "raw.fits", overwrite)
    pipeline = Pipeline.from_yaml("unchop")
    reduced = pipeline.run(outdir / "raw.fits", progress=progress)
    write(reduced, outdir / "reduced.fits", overwrite)
    with atomic_output(outdir / "schedule.ecsv", overwrite) as tmp:
        schedule.to_table().write(tmp, format="ascii.ecsv")
    save_figure(plot_read_order(schedule), outdir / "read_order.png", overwrite)
    cds = reduced.data.data[-1] - reduced.data.data[0]
    save_figure(plot_image(cds, "last minus first frame, physical order", "electron"),
                outdir / "reduced.png", overwrite)
    yield f"reduced with {pipeline.source}: " + ", ".join(n for n, _ in pipeline.steps)
    yield f"last-minus-first frame: mean {np.nanmean(cds):.1f} e, std {np.nanstd(cds):.1f} e"
    for name in names:
        yield f"wrote {outdir / name}"
