"""``spherex-reduce spectrum``, ``fit-noise`` and ``sweep --forecast``."""

import numpy as np
import pytest
from astropy import units as u
from astropy.io import fits
from astropy.table import Table

from spherex_reduce import DetectorGeometry, Exposure, ReadoutSchedule, write
from spherex_reduce.cli import main


@pytest.fixture
def image_file(tmp_path):
    img = np.random.default_rng(0).normal(0, 0.5, (256, 256)).astype(np.float32)
    hdu = fits.PrimaryHDU(img)
    hdu.header["BUNIT"] = "electron / s"
    path = tmp_path / "image.fits"
    hdu.writeto(path)
    return path


def test_spectrum_writes_table_with_band_power_and_plot(image_file, tmp_path, capsys):
    out = tmp_path / "spec.ecsv"
    assert main(["spectrum", str(image_file), "-o", str(out), "--plot"]) == 0
    t = Table.read(out)
    assert t.colnames[:5] == ["k", "theta", "power", "power_err", "nmodes"]
    assert t["k"].unit == u.rad / u.pix
    assert abs(t.meta["band_power"] - 0.25) < 4 * t.meta["band_power_err"]
    assert t.meta["photon_noise_power"] == pytest.approx(1 / 111.74)  # 1 e/s, no NFRAMES
    assert (tmp_path / "spec.png").stat().st_size > 1000
    # the band by its nominal name; the θ its k limits give on 6.2″ pixels in the meta
    assert "band power 5–20′ (0.03 ≤ k ≤ 0.13 rad/pixel) = " in capsys.readouterr().out
    assert t.meta["band"] == "5–20′ (0.03 ≤ k ≤ 0.13 rad/pixel)"
    assert t.meta["band_theta_exact"] == "θ = 4.99–21.6′ for 6.2″ pixels"
    # an existing output is kept
    assert main(["spectrum", str(image_file), "-o", str(out)]) == 2
    assert "exists" in capsys.readouterr().err


def test_spectrum_compare_and_readout_order_image(image_file, tmp_path):
    g = DetectorGeometry(64, 64, 4, ref_border=4)
    s = ReadoutSchedule(g, skip=8, ref_reads=8, phantom_reads=0, nframes=10)
    rng = np.random.default_rng(1)
    slopes = Exposure.from_arrays(rng.normal(0, 2.0, (s.n_reads, 64)), s,
                                  unit=u.electron / u.s)
    raw = write(slopes, tmp_path / "slopes.fits")
    out = tmp_path / "cmp.ecsv"
    assert main(["spectrum", str(raw), "-o", str(out), "--compare", str(image_file),
                 "--bins", "8", "--plot", str(tmp_path / "cmp.png")]) == 0
    t = Table.read(out)
    assert "power_compare" in t.colnames
    assert abs(t.meta["band_power_compare"] - 0.25) < 4 * t.meta["band_power_compare_err"]
    assert abs(t.meta["band_power"] - 4.0) < 4 * t.meta["band_power_err"]
    # the photon line uses the file's schedule: N = 10 frames
    from spherex_reduce.analysis import photon_noise_power

    assert t.meta["photon_noise_power"] == pytest.approx(
        photon_noise_power(1.0, schedule=s).value)


def test_spectrum_of_ramps_is_a_clear_error(tmp_path, capsys):
    g = DetectorGeometry(16, 16, 2, ref_border=2)
    s = ReadoutSchedule(g, skip=4, ref_reads=4, phantom_reads=0, nframes=3)
    path = write(Exposure.from_arrays(np.zeros((3, s.n_reads, 16)), s), tmp_path / "r.fits")
    assert main(["spectrum", str(path), "-o", str(tmp_path / "x.ecsv")]) == 2
    assert "fit them first" in capsys.readouterr().err


def test_fit_noise_cli(tmp_path, capsys):
    from _noise_streams import raw_exposure

    raw = write(raw_exposure(5, nframes=6), tmp_path / "raw.fits")
    out = tmp_path / "fit.ecsv"
    assert main(["fit-noise", str(raw), "-o", str(out), "--plot"]) == 0
    t = Table.read(out)
    assert list(t["stream"]) == ["reference", "phantom"]
    assert {"alpha", "alpha_err", "beta_err", "gamma_err", "chi2", "dof"} <= set(t.colnames)
    assert (tmp_path / "fit.png").exists()
    assert "alpha" in capsys.readouterr().out


# -- -c PIPELINE.yaml and small images (issue 13) -----------------------------------------------

def _strip_schedule(src, dst):
    """Copy FITS ``src`` to ``dst`` without its schedule: no geometry or readout keyword, no
    ``READOUT`` table (as a file from other electronics comes)."""
    from spherex_reduce.core.fields import FIELDS

    with fits.open(src) as hdul:
        hdus = fits.HDUList([h.copy() for h in hdul if h.name != "READOUT"])
    for hdu in hdus:
        for key in [f.keyword for f in FIELDS] + ["CHECKSUM", "DATASUM", "NEXTEND"]:
            hdu.header.remove(key, ignore_missing=True)
    hdus.writeto(dst)
    return dst


def _bytes(*paths):
    return [p.read_bytes() for p in paths]


def _assert_same_table(a, b):
    """Every column of ECSV table ``a`` is in ``b`` with the same values (``b`` may have more)."""
    ta, tb = Table.read(a), Table.read(b)
    assert tb.colnames[:len(ta.colnames)] == ta.colnames and len(ta) == len(tb) > 0
    for name in ta.colnames:
        if ta[name].dtype.kind in "fi":
            np.testing.assert_array_equal(np.asarray(ta[name]), np.asarray(tb[name]), name)
    return ta, tb


def test_fit_noise_config_supplies_what_the_file_lacks(tmp_path, capsys):
    from _noise_streams import raw_exposure

    full = write(raw_exposure(5, nframes=6), tmp_path / "raw.fits")  # 512 x 64, 4 channels
    bare = _strip_schedule(full, tmp_path / "bare.fits")
    config = tmp_path / "lab.yaml"
    config.write_text("geometry: {nrows: 512, ncols: 64, nchannels: 4, ref_border: 4, "
                      "pixel_rate: 100000.0}\n"
                      "readout: {skip: 24, ref_reads: 32, ref_mode: distributed, phantom_reads: 4, "
                      "nframes: 6, frame_overhead: 40}\nsteps:\n  - unchop: {}\n")
    before = _bytes(bare, config)
    # without -c the file does not say how it was read
    assert main(["fit-noise", str(bare), "-o", str(tmp_path / "no.ecsv")]) == 2
    assert "missing readout keyword" in capsys.readouterr().err
    assert main(["fit-noise", str(full), "-o", str(tmp_path / "ref.ecsv")]) == 0
    assert main(["fit-noise", str(bare), "-c", str(config), "-o", str(tmp_path / "c.ecsv")]) == 0
    _, got = _assert_same_table(tmp_path / "ref.ecsv", tmp_path / "c.ecsv")
    assert list(got["stream"]) == ["reference", "phantom"]
    assert got.meta["config"] == str(config)
    assert _bytes(bare, config) == before
    assert not (tmp_path / "no.ecsv").exists()


def test_spectrum_config_supplies_what_the_file_lacks(tmp_path):
    from spherex_reduce import Pipeline
    from spherex_reduce.analysis.io import read_image

    g = DetectorGeometry(64, 64, 4, ref_border=4)
    s = ReadoutSchedule(g, skip=8, ref_reads=8, phantom_reads=0, nframes=10, frame_overhead=40)
    rng = np.random.default_rng(3)
    slopes = Exposure.from_arrays(rng.normal(0, 2.0, (s.n_reads, 64)), s, unit=u.electron / u.s)
    full = write(slopes, tmp_path / "slopes.fits")  # readout order: un-chopped when read
    bare = _strip_schedule(full, tmp_path / "bare.fits")
    config = tmp_path / "lab.yaml"
    config.write_text("geometry: {nrows: 64, ncols: 64, nchannels: 4, ref_border: 4, "
                      "pixel_rate: 100000.0}\n"
                      "readout: {skip: 8, ref_reads: 8, ref_mode: distributed, phantom_reads: 0, "
                      "nframes: 10, frame_overhead: 40}\nsteps:\n  - unchop: {}\n")
    before = _bytes(bare, config)
    assert main(["spectrum", str(full), "-o", str(tmp_path / "ref.ecsv"), "--bins", "8"]) == 0
    assert main(["spectrum", str(bare), "-c", str(config), "-o", str(tmp_path / "c.ecsv"),
                 "--bins", "8", "--compare", str(bare)]) == 0
    ref, got = _assert_same_table(tmp_path / "ref.ecsv", tmp_path / "c.ecsv")
    for key in ("band_power", "band_power_err", "photon_noise_power"):
        assert got.meta[key] == ref.meta[key], key
    assert got.meta["band_power_compare"] == ref.meta["band_power"]  # --compare: read with -c
    np.testing.assert_array_equal(got["power_compare"], ref["power"])
    assert abs(ref.meta["band_power"] - 4.0) < 4 * ref.meta["band_power_err"]
    assert got.meta["config"] == str(config)
    assert _bytes(bare, config) == before
    # the Python API reads it the same way: the pixels of the complete file, un-chopped
    image = read_image(bare, pipeline=Pipeline.from_yaml(config))
    np.testing.assert_array_equal(image.data, read_image(full).data)
    assert image.meta["NFRAMES"] == 10


def test_spectrum_of_an_image_too_small_for_the_band(tmp_path, caplog):
    img = np.random.default_rng(4).normal(0, 0.5, (32, 32))
    path = tmp_path / "small.fits"
    hdu = fits.PrimaryHDU(img)
    hdu.header["BUNIT"] = "electron / s"
    hdu.writeto(path)
    before = path.read_bytes()
    out = tmp_path / "small.ecsv"
    with caplog.at_level("WARNING"):
        assert main(["spectrum", str(path), "-o", str(out), "--plot"]) == 0
    warnings = [r.getMessage() for r in caplog.records if r.levelname == "WARNING"]
    assert len(warnings) == 1, warnings
    assert "0.03 <= k <= 0.13" in warnings[0] and "32 x 32" in warnings[0]
    assert "2 pi/32 = 0.196" in warnings[0]  # why: the fundamental is above the band
    t = Table.read(out)
    assert t.meta["band_power"] is None and t.meta["band_power_err"] is None
    assert "no Fourier mode" in t.meta["band_power_missing"]
    # P(k) is written all the same: modes from the fundamental 2π/32 up, white at σ² = 0.25
    assert t["k"][0] == pytest.approx(2 * np.pi / 32)
    assert int(np.sum(t["nmodes"])) > 300
    mean = np.sum(t["power"] * t["nmodes"]) / np.sum(t["nmodes"])
    assert abs(mean - 0.25) < 0.05
    assert (tmp_path / "small.png").stat().st_size > 1000
    assert path.read_bytes() == before


def _numpy_spectrum(light, k_lo, k_hi):
    """P(k) of an image with no masked pixel, by brute force on the full Fourier plane:
    mean-subtracted, |FFT|^2 / (ny nx) averaged over the cells with k_lo <= |k| < k_hi
    (the last bin's upper edge included, k = 0 left out)."""
    ny, nx = light.shape
    p = np.abs(np.fft.fft2(light - light.mean())) ** 2 / (ny * nx)
    k = np.hypot(2 * np.pi * np.fft.fftfreq(ny)[:, None], 2 * np.pi * np.fft.fftfreq(nx)[None])
    out = []
    for i, (lo, hi) in enumerate(zip(k_lo, k_hi, strict=True)):
        cells = (k >= lo) & ((k <= hi) if i == len(k_lo) - 1 else (k < hi)) & (k > 0)
        out.append(p[cells].mean())
    return np.array(out)


@pytest.mark.parametrize("widths", [{"top": 4, "bottom": 4, "left": 4, "right": 4},
                                    {"top": 4, "left": 4}])
def test_spectrum_leaves_the_reference_pixels_out(tmp_path, widths):
    """A 24 x 24 image whose reference pixels hold 1e6: its P(k) is numpy's of the
    light-sensitive pixels alone (with the border in, P(k) was ~3e12 times larger)."""
    s = ReadoutSchedule(DetectorGeometry(24, 24, 2, ref_border=widths), skip=4, ref_reads=4,
                        phantom_reads=0, nframes=4)
    rows = slice(4, 20 if "bottom" in widths else 24)
    cols = slice(4, 20 if "right" in widths else 24)
    img = np.full((24, 24), 1e6)
    img[rows, cols] = np.random.default_rng(6).normal(0, 2.0, img[rows, cols].shape)
    path = write(Exposure.from_arrays(img, s, order="physical", unit=u.electron / u.s),
                 tmp_path / "image.fits")
    before = path.read_bytes()
    out = tmp_path / "spec.ecsv"
    assert main(["spectrum", str(path), "-o", str(out), "--bins", "5"]) == 0
    t = Table.read(out)
    stored = img[rows, cols].astype(np.float32).astype(float)  # write stores float32
    expected = _numpy_spectrum(stored, np.asarray(t["k_lo"]), np.asarray(t["k_hi"]))
    np.testing.assert_allclose(t["power"], expected, rtol=1e-10)
    assert t.meta["shape"] == list(img[rows, cols].shape) and t.meta["masked_fraction"] == 0
    assert path.read_bytes() == before


def test_sweep_forecast_only(tmp_path, capsys):
    """``sweep --forecast`` with ``realizations: 0``: the forecast table and its plot; the
    same file without ``--forecast`` is one error line, exit 2."""
    import yaml

    path = tmp_path / "sweep.yaml"
    path.write_text(yaml.safe_dump({
        "scene": {"geometry": {"nrows": 64, "ncols": 64, "nchannels": 4},
                  "readout": {"nframes": 6}},
        "pipeline": "unchop", "grid": {"skip": [1, 4, 16]}, "realizations": 0}))
    out = tmp_path / "f.ecsv"
    assert main(["-q", "sweep", str(path), "-o", str(out), "--forecast", "--plot"]) == 0
    assert "3 points forecast" in capsys.readouterr().out
    t = Table.read(out)
    assert list(t["skip"]) == [1, 4, 16] and np.all(t["band_power_forecast"] > 0)
    assert (tmp_path / "f.png").stat().st_size > 1000
    assert main(["-q", "sweep", str(path), "-o", str(tmp_path / "g.ecsv")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "realizations: 0 runs no Monte Carlo" in err[0]
    assert not (tmp_path / "g.ecsv").exists()
