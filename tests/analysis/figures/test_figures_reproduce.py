"""``spherex-reduce figures --quick`` (and ``--forecast``): every figure, the numbers and a
verdict per claim."""

import re

import numpy as np
import pytest
from _figure_checks import drawn, errorbar_ends, overlaps, saved_figures, tick_labels
from _paths import ROOT
from astropy.table import Table

from spherex_reduce.analysis import forecast
from spherex_reduce.cli import main

PNGS = ["fig4_components.png", "fig5_phantom.png", "fig6_skip.png", "fig7_fft2d.png",
        "fig8_reference_reads.png", "fig9_image.png", "fig9_spectrum.png",
        "fig10_corrected.png", "fig12a_sigma_vs_n.png"]


def _check_citations(report):
    """Every document the report cites is in the repository (it cited a design.md that is
    not), and the wrap-around bias it quotes is docs/simulation.rst's table's."""
    cited = set(re.findall(r"[\w/.-]+\.(?:md|rst)\b", report)) - {"report.md"}
    assert cited, "the report cites no document"
    assert all((ROOT / name).is_file() for name in cited), cited
    row = next(line for line in (ROOT / "docs" / "simulation.rst").read_text().splitlines()
               if line.startswith("period = exposure"))
    gamma_10, _, gamma_74, _ = (float(v.replace("\u2212", "-")) for v in
                                re.findall(r"\u2212?[\d.]+(?= %)", row))
    assert f"{-gamma_10:g} % low at N = 10 and {-gamma_74:g} % low at N = 74" in report


def test_figures_quick_with_forecast(tmp_path, capsys):
    """``figures --quick --forecast``: every figure, the numbers, a verdict per claim; Figs.
    6-8 judged on the forecast, which equals the forecast of each point computed here."""
    out = tmp_path / "figs"
    assert main(["-q", "figures", "-o", str(out), "--quick", "--forecast"]) == 0
    assert "report.md" in capsys.readouterr().out
    for name in [*PNGS, "fig7_profile.png"]:
        assert (out / name).stat().st_size > 1000, name
    report = (out / "report.md").read_text()
    for name in PNGS:
        assert f"]({name})" in report
    verdicts = re.findall(r"\*\*(holds|does not hold|within the noise)\*\* in (our simulation|"
                          r"the forecast)", report)
    assert len(verdicts) == 7  # one per claim, each with its numbers
    # the claims of Figs. 6, 7 and 8 on the forecast, exactly, the Monte Carlo beside
    judged = [line for line in report.splitlines() if "in the forecast" in line]
    assert [re.search(r"\(Fig\. (\d+)", line)[1] for line in judged] == ["6", "7", "8"]
    for line in judged:
        assert "decided exactly" in line and "The Monte Carlo beside it:" in line, line
        assert re.search(r"\*\*(holds|does not hold)\*\*", line), line  # never "noise"
    assert "Wrap-around bias" in report
    _check_citations(report)
    t = Table.read(out / "figures.ecsv")
    assert set(t["figure"]) == {"4", "5", "6", "7", "8", "9", "10", "12a"}
    assert np.all(np.isfinite(t["y"]))
    # the figures of the paper's scans have one point per grid value, and one forecast each
    six = t[t["figure"] == "6"]
    assert sorted(six["x"][~np.char.endswith(six["series"].astype(str), "forecast")]) == \
        [1, 4, 16, 64]
    fc = six[np.char.endswith(six["series"].astype(str), ", forecast")]
    scene = {"geometry": {"nrows": 512, "ncols": 512, "nchannels": 8, "ref_border": 4},
             "readout": {"skip": 16, "ref_reads": 32, "ref_mode": "distributed",
                         "phantom_reads": 4, "nframes": 20}}
    expect = forecast(scene, "spherex-default", {"exclude_horizontal": True, "bins": 20})
    assert fc["y"][fc["x"] == 16][0] == pytest.approx(expect.meta["band_power"], rel=1e-9)
    nine = t[(t["figure"] == "9") & (t["y_name"] == "band_power")]
    phantom = forecast(dict(scene, readout={**scene["readout"], "skip": 24}),
                       {"steps": [{"unchop": {}}, {"subtract_phantom": {}}]})
    assert nine["y"][nine["series"] == "before reference correction, forecast"][0] == \
        pytest.approx(phantom.meta["band_power"], rel=1e-9)
    # an existing report is kept
    assert main(["-q", "figures", "-o", str(out), "--quick"]) == 2


# -- figures --quick ------------------------------------------------------------------------
@pytest.fixture(scope="module")
def quick_figures(tmp_path_factory):
    """One ``figures --quick`` run: its directory and its figures by file name."""
    import spherex_reduce.io.plotting as plotting

    out = tmp_path_factory.mktemp("figures")
    figs = saved_figures(plotting, ["-q", "figures", "--quick", "-o", str(out)])
    return out, figs


def test_fig4_no_spikes_to_zero_on_the_log_axis(quick_figures):
    _, figs = quick_figures
    ax = figs["fig4_components.png"].axes[0]
    assert ax.get_yscale() == "log"
    for c in ax.containers:
        y = np.asarray(c.lines[0].get_ydata(), float)
        assert np.all(y[np.isfinite(y)] > 0), c.get_label()
    ends = errorbar_ends(ax)
    assert len(ends) and np.all(ends[:, 0] > 0)


@pytest.mark.parametrize("name", ["fig5_phantom.png", "fig10_corrected.png",
                                  "fig9_spectrum.png", "fig4_components.png"])
def test_figure_legends_show_error_bars_only_if_drawn(quick_figures, name):
    from matplotlib.container import ErrorbarContainer

    _, figs = quick_figures
    handles, labels = figs[name].axes[0].get_legend_handles_labels()
    for h, label in zip(handles, labels, strict=True):
        if isinstance(h, ErrorbarContainer):
            lengths = [np.ptp(np.asarray(seg, float).reshape(-1, 2)[:, 1])
                       for col in h.lines[2] for seg in col.get_segments() if len(seg)]
            assert lengths and max(lengths) > 0, label


def test_fig9a_title_clear_of_the_tick_labels(quick_figures):
    _, figs = quick_figures
    fig = figs["fig9_image.png"]
    renderer = drawn(fig)
    titles = [t for t in [fig._suptitle, *(a.title for a in fig.axes)] if t and t.get_text()]
    assert titles
    ticks = [box for ax in fig.axes for _, box in tick_labels(ax, renderer)]
    for title in titles:
        box = title.get_window_extent(renderer)  # touching counts: keep 2 pixels clear
        assert not any(overlaps(box, t, slack=-2) for t in ticks), title.get_text()


def test_fig12a_tick_labels_do_not_overlap(quick_figures):
    _, figs = quick_figures
    fig = figs["fig12a_sigma_vs_n.png"]
    renderer = drawn(fig)
    labels = tick_labels(fig.axes[0], renderer)
    for i, (ta, a) in enumerate(labels):
        for tb, b in labels[i + 1:]:
            assert not overlaps(a, b), (ta, tb)
    assert [t for t, _ in labels if t.isdigit()] == ["4", "16", "74"]


def test_figures_report_states_its_verdict_rules(quick_figures):
    import re

    from spherex_reduce.analysis.figures.report import _verdict, sigma_margin

    out, _ = quick_figures
    report = (out / "report.md").read_text()
    claims = [line for line in report.splitlines() if line.startswith("- ") and "(Fig." in line]
    assert len(claims) == 7
    for line in claims:
        verdict = re.search(r"\*\*(holds|does not hold|within the noise)\*\*", line)
        assert verdict, line
        assert "*Rule:*" in line and "smallest margin" in line, line
        margin = float(re.search(r"smallest margin ([-+]?[\d.]+|[-+]?inf) standard", line)[1])
        expected = ("holds" if margin > 2 else "does not hold" if margin < -2
                    else "within the noise")
        assert verdict[1] == expected, line
        assert re.search(r"realisation|one image", line), line
    assert "more than 2 standard errors" in report and "1 realisation per point" in report
    # independent numbers: 1.5 ± 0.2 against 1.0 ± 0.1 is 2.24 standard errors apart
    assert float(sigma_margin(1.0, 0.1, 1.5, 0.2)) == pytest.approx(0.5 / np.sqrt(0.05))
    assert _verdict([3.0, 2.24]) == "holds" and _verdict([3.0, 1.9]) == "within the noise"
    assert _verdict([3.0, -2.1]) == "does not hold"


def test_figure_units_are_latex(quick_figures):
    _, figs = quick_figures
    for name, fig in figs.items():
        for ax in fig.axes:
            label = ax.get_ylabel()
            assert "electron2" not in label and " / s" not in label, (name, label)
    for name in ("fig4_components.png", "fig6_skip.png", "fig8_reference_reads.png",
                 "fig10_corrected.png", "fig12a_sigma_vs_n.png"):
        assert "$\\mathrm{" in figs[name].axes[0].get_ylabel(), name
