"""``spherex-reduce forecast``: numbers against independent expectations (the analytic
variance of a white-noise slope, a simulated image measured by ``spectrum``), the table's
columns and meta against ``spectrum``'s, and one-line errors."""

import numpy as np
import pytest
from astropy.table import Table

from spherex_reduce.cli import main
from spherex_reduce.simulation import load_scene

WHITE = """\
geometry: {nrows: 96, ncols: 96, nchannels: 4, ref_border: 4}
readout: {skip: 4, ref_reads: 4, phantom_reads: 2, nframes: 6}
noise: {components: [{name: white, alpha: 2.0e-3}]}
"""

# the package's default noise (Table 2) on a small array, slopes, a fixed seed
SMALL = """\
geometry: {nrows: 128, ncols: 128, nchannels: 4, ref_border: 4}
readout: {skip: 8, ref_reads: 8, phantom_reads: 2, nframes: 10}
output: {mode: slopes}
seed: 7
"""


@pytest.fixture
def white(tmp_path):
    f = tmp_path / "white.yaml"
    f.write_text(WHITE)
    return f


def _run(*argv):
    return main(["-q", "forecast", *map(str, argv)])


def test_white_noise_forecast_is_the_analytic_slope_variance(white, tmp_path, capsys):
    out = tmp_path / "f.ecsv"
    assert _run(white, "-c", "unchop", "-o", out, "--bins", 6) == 0
    t = Table.read(out)
    s = load_scene(str(white)).schedule
    # white noise of PSD alpha: per-sample variance alpha fs / 2; a uniform least-squares
    # slope over N frames spaced T apart has variance sigma^2 / sum (t_k - mean t)^2
    fs = s.geometry.pixel_rate
    sigma2 = 2.0e-3 * fs / 2
    t_k = np.arange(s.nframes) * s.frame_samples / fs
    expect = sigma2 / np.sum((t_k - t_k.mean()) ** 2)
    np.testing.assert_allclose(t["power"].value, expect, rtol=1e-9)  # flat, every bin
    np.testing.assert_allclose(t["power_white"].value, expect, rtol=1e-9)
    assert t.meta["variance"] == pytest.approx(expect, rel=1e-9)
    assert t.meta["band_power"] == pytest.approx(expect, rel=1e-9)
    # one realisation's standard error: each mode's |FFT|^2 is exponential (its sd = its
    # mean), so the band power of n independent cells scatters by P / sqrt(n)
    assert 0 < t.meta["band_power_err"] < expect
    text = capsys.readouterr().out
    assert f"= {expect:.4g} electron2 pix2 / s2 (one realisation: ± " in text
    assert f"wrote {out}" in text


def test_lines_up_with_spectrum_of_a_simulated_image(tmp_path, capsys):
    scene = tmp_path / "small.yaml"
    scene.write_text(SMALL)
    raw, measured, fc = tmp_path / "s.fits", tmp_path / "m.ecsv", tmp_path / "f.ecsv"
    assert main(["-q", "simulate", str(scene), "-o", str(raw)]) == 0
    assert main(["-q", "spectrum", str(raw), "-o", str(measured), "--bins", "12"]) == 0
    assert _run(scene, "-c", "unchop", "-o", fc, "--bins", 12, "--compare", measured,
                "--plot") == 0
    text = capsys.readouterr().out
    m, f = Table.read(measured), Table.read(fc)
    # the same bins, columns and band: the two tables plot together
    assert f.colnames[:7] == m.colnames[:7]
    for c in ("k", "k_lo", "k_hi", "nmodes", "theta"):
        np.testing.assert_allclose(f[c], m[c], rtol=1e-12)
    spectrum_keys = set(m.meta) - {"photon_noise_power", "photocurrent_e_per_s"}
    assert spectrum_keys <= set(f.meta)
    for key in ("band", "band_kmin", "band_kmax", "band_theta_exact", "band_power_unit",
                "shape", "pixel_scale", "exclude_horizontal"):
        assert f.meta[key] == m.meta[key]
    assert f.meta["config"] == "unchop (shipped)" and f.meta["source"] == str(scene)
    # one realisation against its expectation: per bin, z = (measured - forecast) / the
    # forecast's one-realisation error; a forecast off by 30 % would give chi^2 ~ 4x
    z = (m["power"] - f["power"]) / f["power_err"]
    assert np.all(np.abs(z) < 4), z
    assert 0.2 < np.mean(z**2) < 2.5
    zb = (m.meta["band_power"] - f.meta["band_power"]) / f.meta["band_power_err"]
    assert abs(zb) < 3
    assert f"{raw.parent / 'm.ecsv'}: measured band power" in text
    assert (tmp_path / "f.png").stat().st_size > 10_000


def test_components_add_up_to_the_total(tmp_path):
    scene = tmp_path / "small.yaml"
    scene.write_text(SMALL)
    out = tmp_path / "f.ecsv"
    assert _run(scene, "-c", "unchop", "-o", out, "--bins", 8, "--exclude-horizontal",
                "--kmin", 0.05, "--kmax", 0.5) == 0
    t = Table.read(out)
    parts = [c for c in t.colnames if c.startswith("power_") and c != "power_err"]
    assert len(parts) >= 4  # Table 2's components, and the Poisson noise if any
    np.testing.assert_allclose(sum(t[c].value for c in parts), t["power"].value, rtol=1e-9)
    assert t.meta["exclude_horizontal"] is True
    assert (t.meta["band_kmin"], t.meta["band_kmax"]) == (0.05, 0.5)


@pytest.mark.parametrize("argv, words", [
    (["-c", "MEDIAN"], "correct_reference"),  # not linear: refused, named
    (["-c", "unchop", "--kmin", "0.2", "--kmax", "0.1"], "--kmin (0.2) must be below"),
    (["-c", "unchop", "--bins", "0"], "--bins"),
    (["-c", "unchop", "--kmax", "inf"], "--kmax"),
    (["-c", "no-such-config"], "no shipped config"),
])
def test_bad_options_one_line_exit_2(white, tmp_path, capsys, argv, words):
    median = tmp_path / "median.yaml"
    median.write_text("steps: [{unchop: {}}, {fit_ramp: {}}, "
                      "{correct_reference: {strategy: median}}]\n")
    argv = [str(median) if a == "MEDIAN" else a for a in argv]
    out = tmp_path / "f.ecsv"
    assert _run(white, *argv, "-o", out) == 2
    err = capsys.readouterr().err
    assert words in err and err.count("\n") == 1 and "Traceback" not in err
    assert not out.exists()


def test_spectrum_and_forecast_refuse_an_inverted_band_alike(white, tmp_path, capsys):
    errors = []
    for argv in (["spectrum", tmp_path / "no-such.fits"], ["forecast", white, "-c", "unchop"]):
        assert main(["-q", *map(str, argv), "-o", str(tmp_path / "o.ecsv"), "--kmin", "0.2",
                     "--kmax", "0.1"]) == 2
        errors.append(capsys.readouterr().err.split(": error: ", 1)[1])
    assert errors == ["--kmin (0.2) must be below --kmax (0.1)\n"] * 2
    assert list(tmp_path.iterdir()) == [white]


@pytest.mark.parametrize("scene, words", [
    ("geometry: [\n", "not valid YAML"),
    ("readout: {nframes: 1}\n", "frame"),
    ("geometry: {nrows: 100000, ncols: 100000}\n", "memory"),
    ("noise: {components: [{name: a, alpha: .nan}]}\n", "alpha"),
])
def test_bad_scene_one_line_exit_2(tmp_path, capsys, scene, words):
    f = tmp_path / "bad.yaml"
    f.write_text(scene)
    assert _run(f, "-c", "unchop", "-o", tmp_path / "f.ecsv") == 2
    err = capsys.readouterr().err
    assert words in err and err.count("\n") == 1 and "Traceback" not in err


@pytest.mark.parametrize("content, words", [
    ("k power\n1 2\n", "not an ECSV table"),
    ("# %ECSV 1.0\n# ---\n# datatype:\n# - {name: k, datatype: float64}\n"
     "# schema: astropy-2.0\nk\n0.1\n", "no column power, power_err"),
])
def test_bad_compare_table_and_existing_output_kept(white, tmp_path, capsys, content, words):
    bad = tmp_path / "m.ecsv"
    bad.write_text(content)
    out = tmp_path / "f.ecsv"
    out.write_text("keep me")
    assert _run(white, "-c", "unchop", "-o", out, "--compare", bad, "--overwrite") == 2
    err = capsys.readouterr().err
    assert words in err and err.count("\n") == 1
    assert out.read_text() == "keep me" and bad.read_text() == content
    assert _run(white, "-c", "unchop", "-o", out) == 2  # no --overwrite: kept
    assert "exists" in capsys.readouterr().err and out.read_text() == "keep me"


def _compare_refused(white, tmp_path, capsys, meta, words):
    """``forecast --compare`` of a measured table with ``meta`` exits 2 in one line with
    ``words`` and writes nothing."""
    from astropy import units as u

    unit = u.electron**2 / u.s**2 * u.pix**2
    measured = Table({"k": [0.05, 0.1] * u.rad / u.pix, "power": [1.0, 2.0] * unit,
                      "power_err": [0.1, 0.2] * unit},
                     meta={"band_power": 1.5, "band_power_err": 0.1, **meta})
    path = tmp_path / "m.ecsv"
    measured.write(path)
    out = tmp_path / "f.ecsv"
    assert _run(white, "-c", "unchop", "-o", out, "--compare", path) == 2
    err = capsys.readouterr().err
    assert err.startswith("spherex-reduce forecast: error: --compare: ") and words in err
    assert err.count("\n") == 1 and not out.exists()


@pytest.mark.parametrize("meta, words", [
    ({"band_power_unit": "furlong"}, "m.ecsv: band_power_unit: 'furlong' is not a unit"),
    ({"band_power_unit": "m"}, "m.ecsv: band_power_unit: m, expected electron2 pix2 / s2"),
    ({"band_power": "abc"}, "m.ecsv: band_power: expected a number >= 0 or null, got 'abc'"),
    ({"band_power_err": [1, 2]}, "m.ecsv: band_power_err: expected a number"),
    ({"band_power": float("nan")}, "m.ecsv: band_power: expected a number"),
])
def test_bad_compare_band_power_meta_one_line_exit_2(white, tmp_path, capsys, meta, words):
    from astropy import units as u

    unit = u.electron**2 / u.s**2 * u.pix**2
    _compare_refused(white, tmp_path, capsys,
                     {"band_power_unit": unit.to_string(), **meta}, words)


def test_progress_shows_the_time_on_a_terminal_only(monkeypatch):
    import io
    import sys
    import time

    from spherex_reduce.cli.forecast import _ticking

    class Terminal(io.StringIO):
        def isatty(self):
            return True

    for stream, enabled, expect in ((Terminal(), True, True), (Terminal(), False, False),
                                    (io.StringIO(), True, False)):
        monkeypatch.setattr(sys, "stderr", stream)
        with _ticking(enabled):
            time.sleep(1.7 if isinstance(stream, Terminal) else 0.1)
        text = stream.getvalue()
        assert ("forecast: 00:01" in text) is expect
        if expect:  # erased when done: the command's lines start on a clean line
            assert text.endswith("\r") and text.rstrip("\r ").count("forecast") >= 1


@pytest.fixture
def measured_white(white, tmp_path):
    """A white slope image of the WHITE scene, simulated, for spectrum to measure."""
    raw = tmp_path / "w.fits"
    assert main(["-q", "simulate", str(white), "-o", str(raw), "--mode", "slopes"]) == 0
    return raw


@pytest.mark.parametrize("spectrum_argv, forecast_argv, words", [
    (["--kmin", "0.05", "--kmax", "0.5"], [],
     "was measured in the band 0.05 to 0.5 rad/pixel, the forecast's is 0.03 to 0.13: give "
     "the forecast --kmin 0.05 --kmax 0.5"),
    (["--exclude-horizontal"], [],
     "was measured with --exclude-horizontal, the forecast without: give it to both or "
     "neither"),
    ([], ["--exclude-horizontal"],
     "was measured without --exclude-horizontal, the forecast with: give it to both or "
     "neither"),
])
def test_compare_refuses_a_measurement_in_another_band_or_options(
        white, measured_white, tmp_path, capsys, spectrum_argv, forecast_argv, words):
    """Its band power is not what the forecast forecasts: it was compared all the same
    ("0.2214x the forecast, -58.2 standard errors")."""
    m = tmp_path / "m.ecsv"
    assert main(["-q", "spectrum", str(measured_white), "-o", str(m), *spectrum_argv]) == 0
    capsys.readouterr()
    out = tmp_path / "f.ecsv"
    assert _run(white, "-c", "unchop", "-o", out, "--compare", m, *forecast_argv) == 2
    err = capsys.readouterr().err
    assert err == f"spherex-reduce forecast: error: --compare: {m} {words}\n"
    assert not out.exists()
    # the forecast with the measurement's options: compared
    assert _run(white, "-c", "unchop", "-o", out, "--compare", m, *spectrum_argv) == 0
    assert f"{m}: measured band power" in capsys.readouterr().out


@pytest.mark.parametrize("meta, words", [
    ({}, "no band_kmin, band_kmax, exclude_horizontal, shape in its meta"),
    ({"band_kmin": 0.03, "band_kmax": 0.13, "exclude_horizontal": False, "shape": [40, 88]},
     "was measured on a 40 x 88 image, the forecast is of the scene's 88 x 88 "
     "light-sensitive pixels"),
    ({"band_kmin": "0.03", "band_kmax": 0.13, "exclude_horizontal": False, "shape": [88, 88]},
     "band_kmin: expected a number, got '0.03'"),
    ({"band_kmin": 0.03, "band_kmax": 0.13, "exclude_horizontal": "no", "shape": [88, 88]},
     "exclude_horizontal: expected true or false, got 'no'"),
])
def test_compare_refuses_a_table_that_does_not_say_what_it_measured(white, tmp_path, capsys,
                                                                    meta, words):
    _compare_refused(white, tmp_path, capsys, meta, words)


def test_plot_draws_the_photon_line_and_holds_every_line(white, tmp_path):
    """``--plot``: the photon noise of 1 e/s over the scene's reads (the closed form of a
    least-squares slope, 6 (N² + 1) / (5 N (N² − 1)) · i / t_frame) drawn and named, and the
    P axis holding every line drawn."""
    from _figure_checks import line_data_within_limits, saved_figures

    import spherex_reduce.io.plotting as plotting

    out = tmp_path / "f.ecsv"
    figs = saved_figures(plotting, ["-q", "forecast", str(white), "-c", "unchop", "-o", str(out),
                                    "--bins", "8", "--plot"])
    (fig,) = figs.values()  # saved under the output's temporary name
    ax = fig.axes[0]
    s = load_scene(str(white)).schedule
    n, t = s.nframes, s.integration_time.to_value("s")
    expected = 6 * (n**2 + 1) / (5 * n * (n**2 - 1)) * 1.0 / (t / n)
    (line,) = [ln for ln in ax.get_lines() if ln.get_label().startswith("photon noise of 1 e/s")]
    assert np.allclose(line.get_ydata(), expected, rtol=1e-12)
    assert line.get_label() in [t.get_text() for t in ax.get_legend().get_texts()]
    assert line_data_within_limits(ax) == []
