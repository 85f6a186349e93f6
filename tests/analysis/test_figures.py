"""``spherex-reduce figures --quick``: every figure, the numbers and a verdict per claim."""

import re

import numpy as np
from astropy.table import Table

from spherex_reduce.cli import main

PNGS = ["fig4_components.png", "fig5_phantom.png", "fig6_skip.png", "fig7_fft2d.png",
        "fig8_reference_reads.png", "fig9_image.png", "fig9_spectrum.png",
        "fig10_corrected.png", "fig12a_sigma_vs_n.png"]


def test_figures_quick(tmp_path, capsys):
    out = tmp_path / "figs"
    assert main(["-q", "figures", "-o", str(out), "--quick"]) == 0
    assert "report.md" in capsys.readouterr().out
    for name in PNGS:
        assert (out / name).stat().st_size > 1000, name
    report = (out / "report.md").read_text()
    for name in PNGS:
        assert f"]({name})" in report
    verdicts = re.findall(r"\*\*(holds|does not hold|within the noise)\*\* in our", report)
    assert len(verdicts) == 7  # one per claim, each with its numbers
    assert "Wrap-around bias" in report
    t = Table.read(out / "figures.ecsv")
    assert set(t["figure"]) == {"4", "5", "6", "7", "8", "9", "10", "12a"}
    assert np.all(np.isfinite(t["y"]))
    # the figures of the paper's scans have one point per grid value
    assert sorted(t["x"][t["figure"] == "6"]) == [1, 4, 16, 64]
    # an existing report is kept
    assert main(["-q", "figures", "-o", str(out), "--quick"]) == 2
