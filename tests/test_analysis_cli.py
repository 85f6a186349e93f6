"""``spherex-reduce spectrum`` and ``spherex-reduce fit-noise``."""

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
    assert "band power" in capsys.readouterr().out
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
    from test_analysis_temporal import raw_exposure

    raw = write(raw_exposure(5, nframes=6), tmp_path / "raw.fits")
    out = tmp_path / "fit.ecsv"
    assert main(["fit-noise", str(raw), "-o", str(out), "--plot"]) == 0
    t = Table.read(out)
    assert list(t["stream"]) == ["reference", "phantom"]
    assert {"alpha", "alpha_err", "beta_err", "gamma_err", "chi2", "dof"} <= set(t.colnames)
    assert (tmp_path / "fit.png").exists()
    assert "alpha" in capsys.readouterr().out
