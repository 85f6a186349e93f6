"""demo's image panels and the power-spectrum plot, checked without looking.

Texts must not overlap (their window extents after a draw), error bars are
drawn where the legend shows them, no bar end sits at or below zero on a log
axis, panels meant to be compared share one colour stretch, and large images
are binned (block means), not decimated.
"""

import numpy as np
import pytest
from _figure_checks import (
    drawn,
    errorbar_ends,
    images_and_colorbars,
    line_data_within_limits,
    overlaps,
)
from astropy import units as u
from astropy.table import Table


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
    from spherex_reduce.analysis.figures.demo import _images

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
    renderer = drawn(fig)
    panels = images_and_colorbars(fig)
    assert len(panels) == 2 and all(cbar is not None for _, _, cbar in panels)
    right_label = panels[1][0].yaxis.label.get_window_extent(renderer)
    for _, _, cbar in panels:
        assert not overlaps(right_label, cbar.get_tightbbox(renderer))


def _check_ds9_panels(fig, n):
    """Each of the ``n`` images of ``fig``: row 0 drawn at the bottom (its first row's
    centre below its last on the screen), origin 'lower', and a colour bar as tall as the
    panel and beside it (window extents after a draw)."""
    renderer = drawn(fig)
    panels = images_and_colorbars(fig)
    assert len(panels) == n
    for ax, image, cbar in panels:
        assert image.origin == "lower"
        left, right, bottom, top = image.get_extent()
        x = (left + right) / 2
        ny = np.asarray(image.get_array()).shape[0]
        first, last = (bottom + (top - bottom) * (i + 0.5) / ny for i in (0, ny - 1))
        assert ax.transData.transform((x, first))[1] < ax.transData.transform((x, last))[1]
        panel = ax.get_window_extent(renderer)
        bar = cbar.get_window_extent(renderer)
        assert bar.height == pytest.approx(panel.height, abs=1.0)
        assert bar.y0 == pytest.approx(panel.y0, abs=1.0)
        assert panel.x1 <= bar.x0 < panel.x1 + 0.1 * panel.width


def test_images_row_0_at_the_bottom_colour_bars_as_tall_as_the_panels(images_2048):
    _check_ds9_panels(images_2048[0], 2)


def test_fft_panels_row_0_at_the_bottom_colour_bars_as_tall_as_the_panels():
    from spherex_reduce.analysis import fft_magnitude
    from spherex_reduce.analysis.figures.plots import plot_fft_magnitude

    rng = np.random.default_rng(3)
    ffts = {name: fft_magnitude(rng.normal(size=(32, 32)), size=9) for name in "abc"}
    _check_ds9_panels(plot_fft_magnitude(ffts), 3)


def _spectrum(power, err):
    k = np.geomspace(0.01, 1.0, len(power))
    punit = u.electron**2 * u.pix**2 / u.s**2
    return Table({"k": k * u.rad / u.pix, "power": np.asarray(power, float) * punit,
                  "power_err": np.asarray(err, float) * punit})


def test_spectra_log_axis_has_no_points_or_bars_at_or_below_zero():
    from spherex_reduce.analysis.figures.plots import plot_spectra

    fig = plot_spectra({"a": _spectrum([4.0, 0.0, 2.0, 1.0, 0.0, 3.0],
                                       [5.0, 0.0, 0.5, 2.0, 0.0, 0.1])})
    ax = fig.axes[0]
    for line in ax.get_lines():
        y = np.asarray(line.get_ydata(), float)
        if line.get_label() == "a" or line in ax.containers[0].lines[:1]:
            assert np.all(y[np.isfinite(y)] > 0)
    ends = errorbar_ends(ax)
    assert len(ends) and np.all(ends[:, 0] > 0)


def test_spectra_legend_shows_error_bars_only_where_drawn():
    from matplotlib.container import ErrorbarContainer

    from spherex_reduce.analysis.figures.plots import plot_spectra

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
def test_spectra_band_labelled_nominally_and_the_theta_it_gives_in_the_caption(scale):
    from spherex_reduce.analysis.figures.plots import plot_spectra

    fig = plot_spectra({"a": _spectrum([1.0, 2.0], [0.1, 0.1])}, band=(0.03, 0.13),
                       pixel_scale=scale * u.arcsec)
    (band,) = [t.get_text() for t in fig.axes[0].get_legend().get_texts()
               if t.get_text().startswith("band")]
    # the paper's name of the band on SPHEREx pixels only; its k range always
    assert band == ("band 5–20′ (0.03 ≤ k ≤ 0.13 rad/pixel)" if scale == 6.2
                    else "band 0.03 ≤ k ≤ 0.13 rad/pixel")
    # θ = 2π · pixel scale / k, independently of the package, in the caption
    short, long_ = (2 * np.pi * scale / k for k in (0.13, 0.03))  # arcsec
    unit, mark = (60.0, "′") if long_ >= 60 else (1.0, "″")
    caption = fig.get_supxlabel()
    assert caption == (f"shaded band: θ = {short / unit:.3g}–{long_ / unit:.3g}{mark} "
                       f"for {scale:g}″ pixels")
    assert "0–0" not in caption
    assert not any("θ =" in t.get_text() for t in fig.axes[0].get_legend().get_texts())


def test_plot_forecast_curves_measured_points_and_axis():
    from spherex_reduce.analysis.figures.plots import plot_forecast

    unit = u.electron**2 / u.s**2 * u.pix**2
    k = np.geomspace(0.01, 3, 8)
    big, tiny = np.full(8, 2e-3), np.full(8, 1e-36)  # a component cancelled to rounding
    fc = Table({"k": k * u.rad / u.pix, "power": (big + tiny) * unit,
                "power_err": big * 0.1 * unit, "power_roic": big * unit,
                "power_phantom": tiny * unit, "power_none": np.zeros(8) * unit},
               meta={"band_kmin": 0.03, "band_kmax": 0.13, "band_power": 2e-3,
                     "config": "spherex-default (shipped)"})
    measured = Table({"k": k * u.rad / u.pix, "power": big * 1.1 * unit,
                      "power_err": big * 0.05 * unit})
    fig = plot_forecast(fc, measured, measured_label="m.ecsv")
    ax = fig.axes[0]
    labels = [t.get_text() for t in ax.get_legend().get_texts()]
    # every component with power is drawn; one with none, or only its rounding, is not
    assert labels[:2] == ["forecast: total", "forecast: roic"]
    assert "forecast: none" not in labels and "forecast: phantom" not in labels
    assert "measured: m.ecsv" in labels
    low, high = ax.get_ylim()
    # the lines span 2e-3 (the total; the lowest error bar end 1.1 * 2e-3 - 1e-4) to 2.31e-3
    assert 1e-3 < low < 2e-3 and 2.31e-3 < high < 1e-2
    assert "spherex-default" in ax.get_title() and ax.get_yscale() == "log"


def _faint_forecast():
    unit = u.electron**2 / u.s**2 * u.pix**2
    k = np.geomspace(0.003, 3, 10)
    parts = {"roic": np.geomspace(5e-2, 1e-3, 10), "faint": np.geomspace(4e-6, 5e-11, 10),
             "dips": np.array([2e-6, 0, 3e-7, 1e-9, 0, 4e-8, 2e-10, 1e-8, 0, 3e-9])}
    total = sum(parts.values())
    return Table({"k": k * u.rad / u.pix, "power": total * unit,
                  "power_err": total * 0.1 * unit,
                  **{f"power_{n}": v * unit for n, v in parts.items()}},
                 meta={"band_kmin": 0.03, "band_kmax": 0.13, "band_power": 2e-3})


def test_plot_forecast_range_holds_every_component():
    """The forecast plot's P range contains every drawn line's finite data: components eight
    decades under the total (the paper's bias_correlated is 1e-8 of it) too."""
    from spherex_reduce.analysis.figures.plots import plot_forecast

    ax = plot_forecast(_faint_forecast()).axes[0]
    low, high = ax.get_ylim()
    assert low <= 5e-11 and high >= 5e-2  # the faintest and the brightest value, by hand
    for line in ax.get_lines():
        y = np.asarray(line.get_ydata(), float)
        y = y[np.isfinite(y) & (y > 0)]
        assert np.all((y >= low) & (y <= high)), line.get_label()
    assert line_data_within_limits(ax) == []
    labels = [t.get_text() for t in ax.get_legend().get_texts()]
    assert {"forecast: roic", "forecast: faint", "forecast: dips"} <= set(labels)


def test_plot_forecast_draws_the_photon_line_as_the_spectrum_plot_does():
    """The photon-noise line, named in the legend, at its value, in the style plot_spectra
    gives it (one code path), inside the P range."""
    from spherex_reduce.analysis.figures.plots import plot_forecast, plot_spectra

    photon = 1e-12 * u.electron**2 / u.s**2 * u.pix**2  # below every component
    ax = plot_forecast(_faint_forecast(), photon=photon,
                       photon_label="photon noise of 1 e/s over 112 s").axes[0]
    (line,) = [ln for ln in ax.get_lines() if ln.get_label() == "photon noise of 1 e/s over 112 s"]
    assert "photon noise of 1 e/s over 112 s" in [t.get_text()
                                                   for t in ax.get_legend().get_texts()]
    assert np.allclose(line.get_ydata(), 1e-12)
    assert ax.get_ylim()[0] <= 1e-12 and line_data_within_limits(ax) == []
    ref = plot_spectra({"a": _spectrum([1.0, 2.0], [0.1, 0.1])}, photon=photon,
                       photon_label="p").axes[0]
    (same,) = [ln for ln in ref.get_lines() if ln.get_label() == "p"]
    assert (line.get_linestyle(), line.get_color()) == (same.get_linestyle(), same.get_color())


def test_plot_forecast_draws_the_masked_power_as_its_magnitude():
    """``power_masked`` is signed (a clip's mask moves power from the strong scales to the
    weak ones): drawn as its magnitude, dotted and named so, its negative bins not lost."""

    from spherex_reduce.analysis.figures.plots import plot_forecast

    k = np.array([0.05, 0.1, 0.5, 1.0]) * u.rad / u.pix
    unit = u.electron ** 2 * u.pix ** 2 / u.s ** 2
    masked = np.array([-30.0, -5.0, 2.0, 3.0]) * unit
    t = Table({"k": k, "power": [300.0, 100.0, 60.0, 60.0] * unit,
               "power_white": [330.0, 105.0, 58.0, 57.0] * unit, "power_masked": masked})
    ax = plot_forecast(t).axes[0]
    line = next(x for x in ax.get_lines() if "masked" in x.get_label())
    assert line.get_label() == "forecast: |masked| (moved by the clip's mask)"
    assert line.get_linestyle() == ":"
    np.testing.assert_allclose(line.get_ydata(), [30.0, 5.0, 2.0, 3.0])
