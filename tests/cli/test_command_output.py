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

    import spherex_reduce.io.plotting as plotting
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
    unit = Table.read(out)["band_power"].unit
    assert fig.axes[0].get_ylabel() == f"band power ({unit.to_string('latex_inline')})"
    # one line per ref_mode, two points (skip 1, 4) each
    assert [(lab, x) for lab, x, _ in _lines(fig)] == [
        ("ref_mode=distributed", (1, 4)), ("ref_mode=repeated", (1, 4))]


# -- one band power -----------------------------------------------------------------------
@pytest.fixture(scope="module")
def demo_dir(tmp_path_factory):
    """A small demo run: its directory and its figures by file name."""
    import spherex_reduce.analysis.demo as demo

    out = tmp_path_factory.mktemp("demo")
    figs = {}
    real_save = demo.save_figure
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(demo, "save_figure",
                   lambda fig, path, *a: (figs.setdefault(path.name, fig),
                                          real_save(fig, path, *a))[1])
        assert main(["-q", "demo", "--size", "256", "--nframes", "3", "-o", str(out)]) == 0
    return out, figs


def test_demo_and_spectrum_give_one_band_power(demo_dir, tmp_path):
    """The same file, the same band: the same number from ``demo`` and ``spectrum``.

    256² is the smallest size at which the binned P(k) that demo used straddles the band.
    """
    demo_dir, _ = demo_dir
    demo_meta = Table.read(demo_dir / "spectra.ecsv").meta
    for label in ("chopped", "unchopped"):
        out = tmp_path / f"{label}.ecsv"
        assert main(["spectrum", str(demo_dir / f"reduced_{label}.fits"), "-o", str(out)]) == 0
        spec = Table.read(out).meta
        demo = u.Quantity(demo_meta[f"band_power_{label}"])
        assert demo.unit == u.Unit(spec["band_power_unit"])
        assert demo.value == pytest.approx(spec["band_power"], rel=1e-12)


def test_band_power_of_a_table_is_the_band_power_of_the_image():
    """A table only gives the band power if its bins tile the band (else it is refused)."""
    from spherex_reduce.analysis import band_power, power_spectrum
    from spherex_reduce.core.errors import SpherexReduceError

    img = np.random.default_rng(5).normal(0, 1, (128, 128)) * np.linspace(1, 3, 128)
    exact = band_power(img)
    tiled = power_spectrum(img, bins=[0.01, 0.03, 0.07, 0.13, 1.0])
    assert band_power(tiled).value == pytest.approx(exact.value, rel=1e-9)
    with pytest.raises(SpherexReduceError, match="tile"):
        band_power(power_spectrum(img, bins=30))  # bins straddle the band edges


# -- help texts and listings -------------------------------------------------------------
def test_readout_help_describes_every_option_with_its_default(capsys):
    from spherex_reduce.cli.readout import OPTIONS
    from spherex_reduce.io.config import GEOMETRY_PARAMETERS, READOUT_PARAMETERS

    with pytest.raises(SystemExit):
        main(["readout", "--help"])
    text = " ".join(capsys.readouterr().out.split())  # unwrap argparse's lines
    declared = {p.name: p for p in (*GEOMETRY_PARAMETERS, *READOUT_PARAMETERS)}
    assert len(OPTIONS) == 14
    for flag, _, key, _ in OPTIONS:
        p = declared[key]
        after = text.split(f"{flag} {key.upper()} ", 1)[1]
        assert after.startswith(p.doc), flag
        if p.default is not None:
            default = f"{p.default:g}" if isinstance(p.default, float) else str(p.default)
            assert after.split("(default: ", 1)[1].startswith(default + ")"), flag
        else:
            assert "(default: " in after.split(" --", 1)[0], flag
    assert "(default: 1816, the paper's 1.51 s frame" in text


def test_show_config_list_gives_each_shipped_config_its_description(capsys):
    import importlib.resources

    import yaml

    assert main(["show-config", "--list"]) == 0
    lines = capsys.readouterr().out.splitlines()
    configs = importlib.resources.files("spherex_reduce") / "data" / "configs"
    shipped = sorted(p.name[:-5] for p in configs.iterdir() if p.name.endswith(".yaml"))
    assert [line.split()[0] for line in lines] == shipped
    for name, line in zip(shipped, lines, strict=True):
        description = yaml.safe_load((configs / f"{name}.yaml").read_text())["description"]
        assert 10 < len(description) < 62 and "\n" not in description
        assert line.split(None, 1)[1] == description
        assert line.index(description) == lines[0].index(lines[0].split(None, 1)[1])


def test_plugins_names_distribution_and_version_in_aligned_columns(capsys):
    import importlib.metadata

    import spherex_reduce

    assert main(["plugins"]) == 0
    lines = capsys.readouterr().out.splitlines()
    header = lines[0]
    assert header.split() == ["kind", "name", "keyword", "strategies", "plugin", "distribution"]
    starts = [header.index(w) for w in header.split()]
    rows = [line for line in lines[1:] if not line.startswith("blocked")]
    for line in rows:
        for s in starts[1:]:  # every column starts where its heading does
            assert line[s - 2:s] == "  " or len(line) <= s, line
        assert line[starts[4]] != " " and line[starts[5]] != " ", line
    by_name = {line.split()[1]: line for line in rows}
    own = f"spherex-reduce {spherex_reduce.__version__}"
    assert by_name["correct_reference"].endswith(own)
    assert "S_REFCOR" in by_name["correct_reference"]
    assert by_name["unchop"][starts[4]:].split()[0] == "builtin.unchop"
    for ep in importlib.metadata.entry_points(group="spherex_reduce"):
        installed = f"{ep.dist.name} {ep.dist.version}"  # e.g. spherex-reduce-destripe 0.1.0
        assert any(line.endswith(installed) and f" {ep.name} " in line for line in rows)


def test_counts_of_one_are_singular(capsys):
    from spherex_reduce import DetectorGeometry, ReadoutSchedule

    summary = ReadoutSchedule(DetectorGeometry(64, 64, 1, ref_border=4)).summary()
    assert "1 channel of 64 columns" in summary
    assert "2 channels of 32 columns" in ReadoutSchedule(DetectorGeometry(64, 64, 2,
                                                                          ref_border=4)).summary()
    assert main(["readout", "--nrows", "64", "--ncols", "64", "--nchannels", "1"]) == 0
    out = capsys.readouterr().out
    assert "1 channel of" in out and "channels" not in out


# -- plots ------------------------------------------------------------------------------
def _drawn(fig):
    """Draw ``fig`` (running its layout) and return the renderer."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    FigureCanvasAgg(fig).draw()
    return fig.canvas.get_renderer()


def _overlaps(a, b, slack=0.5):
    """Whether two window extents overlap by more than ``slack`` pixels."""
    return (min(a.x1, b.x1) - max(a.x0, b.x0) > slack
            and min(a.y1, b.y1) - max(a.y0, b.y0) > slack)


def _tick_labels(ax, renderer):
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


class _Reduced:
    """What demo's image panel needs of a reduced exposure."""

    def __init__(self, data):
        from astropy.nddata import CCDData

        self.data = np.ma.MaskedArray(data, mask=np.zeros(data.shape, bool))
        self.unit = u.electron / u.s
        self._ccd = CCDData(data, unit=self.unit, mask=self.data.mask)

    def to_ccddata(self):
        return self._ccd


@pytest.fixture(scope="module")
def images_2048():
    """demo's images.png for two 2048² images, one with 10 times the noise of the other.

    Small values: colour-bar labels like "−0.008" are as wide as those of real slopes.
    """
    from spherex_reduce.analysis.demo import _images

    rng = np.random.default_rng(7)
    data = [rng.normal(0, s, (2048, 2048)).astype(np.float32) for s in (0.003, 0.03)]
    fig = _images({"a": _Reduced(data[0]), "b": _Reduced(data[1])}, {"a": "A", "b": "B"})
    return fig, data


def test_images_panels_share_one_stretch(images_2048):
    fig, _ = images_2048
    shown = [ax.images[0] for ax in fig.axes if ax.images]
    assert len(shown) == 2
    assert shown[0].norm is shown[1].norm or (
        (shown[0].norm.vmin, shown[0].norm.vmax) == (shown[1].norm.vmin, shown[1].norm.vmax))


def test_images_are_block_means_not_decimated(images_2048):
    fig, data = images_2048
    rng = np.random.default_rng(0)
    for ax, d in zip([ax for ax in fig.axes if ax.images], data, strict=True):
        shown = np.asarray(ax.images[0].get_array())
        assert 256 <= max(shown.shape) <= 512
        f = -(-2048 // shown.shape[0])  # pixels per block; the last block may hold fewer
        assert shown.shape == (-(-2048 // f),) * 2
        picks = [(0, 0), (shown.shape[0] - 1, shown.shape[1] - 1),
                 *rng.integers(0, shown.shape[0], (50, 2))]
        for i, j in picks:
            block = d[i * f:(i + 1) * f, j * f:(j + 1) * f].astype(float)
            assert shown[i, j] == pytest.approx(block.mean(), rel=1e-5, abs=1e-6), (i, j)
        # the axes still count pixels of the full image
        assert ax.get_xlim() == (-0.5, 2047.5)


def test_images_labels_clear_of_the_other_panel(images_2048):
    fig, _ = images_2048
    renderer = _drawn(fig)
    image_axes = [ax for ax in fig.axes if ax.images]
    colorbars = [ax for ax in fig.axes if not ax.images]
    right_label = image_axes[1].yaxis.label.get_window_extent(renderer)
    for cb in colorbars:
        assert not _overlaps(right_label, cb.get_tightbbox(renderer))


def test_large_image_binned_in_plot_image():
    from spherex_reduce.io.plotting import plot_image

    img = np.arange(1200 * 30, dtype=float).reshape(1200, 30)
    shown = np.asarray(plot_image(img).axes[0].images[0].get_array())
    assert shown.shape == (400, 10)  # 3 x 3 blocks
    assert shown[0, 0] == pytest.approx(img[:3, :3].mean())
    assert shown[-1, -1] == pytest.approx(img[-3:, -3:].mean())


def test_read_order_labels_readable_and_legend_off_the_points():
    from spherex_reduce import ReadoutSchedule
    from spherex_reduce.io.plotting import plot_read_order

    fig = plot_read_order(ReadoutSchedule())  # the paper's case: 4 reference rows read 4 times
    renderer = _drawn(fig)
    left, right = fig.axes[:2]
    boxes = [(t.get_text(), t.get_window_extent(renderer)) for t in left.texts
             if t.get_text()]  # (arrows are annotations without text)
    assert len(boxes) > 40
    for i, (ta, a) in enumerate(boxes):
        for tb, b in boxes[i + 1:]:
            assert not _overlaps(a, b), (ta, tb)
    legend = right.get_legend().get_window_extent(renderer)
    for line in right.get_lines():
        xy = right.transData.transform(np.c_[line.get_xdata(), line.get_ydata()])
        inside = ((xy[:, 0] > legend.x0) & (xy[:, 0] < legend.x1)
                  & (xy[:, 1] > legend.y0) & (xy[:, 1] < legend.y1))
        assert not inside.any(), line.get_label()


def _spectrum(power, err):
    k = np.geomspace(0.01, 1.0, len(power))
    punit = u.electron**2 * u.pix**2 / u.s**2
    return Table({"k": k * u.rad / u.pix, "power": np.asarray(power, float) * punit,
                  "power_err": np.asarray(err, float) * punit})


def _errorbar_ends(ax):
    """Lower and upper ends of every drawn error bar."""
    ends = []
    for c in ax.containers:
        for col in c.lines[2]:
            for seg in col.get_segments():
                seg = np.asarray(seg, float).reshape(-1, 2)
                if len(seg):  # points left out have no bar
                    ends.append((seg[:, 1].min(), seg[:, 1].max()))
    return np.array(ends).reshape(-1, 2)


def test_spectra_log_axis_has_no_points_or_bars_at_or_below_zero():
    from spherex_reduce.analysis.plots import plot_spectra

    fig = plot_spectra({"a": _spectrum([4.0, 0.0, 2.0, 1.0, 0.0, 3.0],
                                       [5.0, 0.0, 0.5, 2.0, 0.0, 0.1])})
    ax = fig.axes[0]
    for line in ax.get_lines():
        y = np.asarray(line.get_ydata(), float)
        if line.get_label() == "a" or line in ax.containers[0].lines[:1]:
            assert np.all(y[np.isfinite(y)] > 0)
    ends = _errorbar_ends(ax)
    assert len(ends) and np.all(ends[:, 0] > 0)


def test_spectra_legend_shows_error_bars_only_where_drawn():
    from matplotlib.container import ErrorbarContainer

    from spherex_reduce.analysis.plots import plot_spectra

    fig = plot_spectra({"one realisation": _spectrum([3.0, 2.0, 1.0], [0.0, 0.0, 0.0]),
                        "with errors": _spectrum([3.0, 2.0, 1.0], [0.3, 0.2, 0.1])})
    ax = fig.axes[0]
    handles, labels = ax.get_legend_handles_labels()
    kinds = dict(zip(labels, handles, strict=True))
    assert isinstance(kinds["with errors"], ErrorbarContainer)
    assert not isinstance(kinds["one realisation"], ErrorbarContainer)
    for h in handles:  # every error-bar symbol in the legend has bars of some length
        if isinstance(h, ErrorbarContainer):
            lengths = [np.ptp(np.asarray(seg, float).reshape(-1, 2)[:, 1])
                       for col in h.lines[2] for seg in col.get_segments() if len(seg)]
            assert max(lengths) > 0


@pytest.mark.parametrize("scale", [6.2, 0.5, 60.0])
def test_spectra_band_labelled_by_k_and_the_theta_it_gives(scale):
    from spherex_reduce.analysis.plots import plot_spectra

    fig = plot_spectra({"a": _spectrum([1.0, 2.0], [0.1, 0.1])}, band=(0.03, 0.13),
                       pixel_scale=scale * u.arcsec)
    (band,) = [t.get_text() for t in fig.axes[0].get_legend().get_texts()
               if t.get_text().startswith("band")]
    # θ = 2π · pixel scale / k, independently of the package
    short, long_ = (2 * np.pi * scale / k for k in (0.13, 0.03))  # arcsec
    unit, mark = (60.0, "′") if long_ >= 60 else (1.0, "″")
    assert band == (f"band 0.03 ≤ k ≤ 0.13 rad/pixel "
                    f"(θ = {short / unit:.3g}–{long_ / unit:.3g}{mark})")
    assert "0–0" not in band


def test_demo_spectra_legend_and_unit(demo_dir):
    """The photon line says its flux and time; the P(k) unit is LaTeX, not 'electron2'."""
    from spherex_reduce.io import read

    out, figs = demo_dir
    ax = figs["spectra.png"].axes[0]
    assert ax.get_ylabel() == "P(k) ($\\mathrm{electron^{2}\\,pix^{2}\\,s^{-2}}$)"
    schedule = read(out / "raw_chopped.fits").schedule
    legend = [t.get_text() for t in ax.get_legend().get_texts()]
    (photon,) = [t for t in legend if t.startswith("photon noise")]
    assert "1 e/s" in photon
    assert f"{schedule.integration_time.to_value(u.s):.3g} s" in photon
    assert f"N = {schedule.nframes}" in photon


def test_fit_noise_plot_names_streams_and_unit(demo_dir, tmp_path, monkeypatch):
    import spherex_reduce.io.plotting as plotting
    from spherex_reduce.io import read

    out, _ = demo_dir
    figs = []
    real_save = plotting.save_figure  # still written: the outputs are renamed together
    monkeypatch.setattr(plotting, "save_figure",
                        lambda fig, *a, **k: (figs.append(fig), real_save(fig, *a, **k))[1])
    raw = out / "raw_chopped.fits"
    assert main(["-q", "fit-noise", str(raw), "-o", str(tmp_path / "fit.ecsv"), "--plot",
                 str(tmp_path / "fit.png")]) == 0
    (ax,) = figs[0].axes
    unit = read(raw).unit**2 / u.Hz
    assert ax.get_ylabel() == f"one-sided PSD ({unit.to_string('latex_inline')})"
    legend = [t.get_text() for t in ax.get_legend().get_texts()]
    assert not any("spectrum" in t for t in legend)
    assert {"reference: border columns", "reference: re-read rows", "phantom"} <= set(legend)


# -- figures --quick ------------------------------------------------------------------------
@pytest.fixture(scope="module")
def quick_figures(tmp_path_factory):
    """One ``figures --quick`` run: its directory and its figures by file name."""
    import spherex_reduce.io.plotting as plotting

    out = tmp_path_factory.mktemp("figures")
    figs = {}
    real_save = plotting.save_figure
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(plotting, "save_figure", lambda fig, path, *a, **k: (
            figs.setdefault(path.name, fig), real_save(fig, path, *a, **k))[1])
        assert main(["-q", "figures", "--quick", "-o", str(out)]) == 0
    return out, figs


def test_fig4_no_spikes_to_zero_on_the_log_axis(quick_figures):
    _, figs = quick_figures
    ax = figs["fig4_components.png"].axes[0]
    assert ax.get_yscale() == "log"
    for c in ax.containers:
        y = np.asarray(c.lines[0].get_ydata(), float)
        assert np.all(y[np.isfinite(y)] > 0), c.get_label()
    ends = _errorbar_ends(ax)
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
    renderer = _drawn(fig)
    titles = [t for t in [fig._suptitle, *(a.title for a in fig.axes)] if t and t.get_text()]
    assert titles
    ticks = [box for ax in fig.axes for _, box in _tick_labels(ax, renderer)]
    for title in titles:
        box = title.get_window_extent(renderer)  # touching counts: keep 2 pixels clear
        assert not any(_overlaps(box, t, slack=-2) for t in ticks), title.get_text()


def test_fig12a_tick_labels_do_not_overlap(quick_figures):
    _, figs = quick_figures
    fig = figs["fig12a_sigma_vs_n.png"]
    renderer = _drawn(fig)
    labels = _tick_labels(fig.axes[0], renderer)
    for i, (ta, a) in enumerate(labels):
        for tb, b in labels[i + 1:]:
            assert not _overlaps(a, b), (ta, tb)
    assert [t for t, _ in labels if t.isdigit()] == ["4", "16", "74"]


def test_figures_report_states_its_verdict_rules(quick_figures):
    import re

    from spherex_reduce.analysis.figures import _margin, _verdict

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
    assert float(_margin(1.0, 0.1, 1.5, 0.2)) == pytest.approx(0.5 / np.sqrt(0.05))
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
