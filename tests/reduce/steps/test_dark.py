"""Master darks: subtract_dark and combine_darks against ccdproc, and the combine command."""

import numpy as np
import pytest
from astropy import units as u
from astropy.nddata import CCDData
from astropy.stats import mad_std

from spherex_reduce import (
    DetectorGeometry,
    Exposure,
    ReadoutSchedule,
    combine_darks,
    read,
    subtract_dark,
    write,
)
from spherex_reduce.cli import main
from spherex_reduce.core.errors import SpherexReduceError


def sched(nframes=4, skip=3):
    return ReadoutSchedule(DetectorGeometry(32, 32, 2, ref_border=2), skip=skip, ref_reads=4,
                           phantom_reads=0, nframes=nframes)


def image(s, values, **kw):
    return Exposure.from_arrays(values, s, order="physical", unit=u.electron / u.s, **kw)


def test_subtract_dark_and_combine_with_ccdproc(tmp_path):
    s = sched()
    rng = np.random.default_rng(4)
    dark_level = rng.normal(5, 1, (32, 32))
    darks = [image(s, dark_level + rng.normal(0, 0.1, (32, 32))) for _ in range(5)]
    darks[0].data.data[0, 0] = 1e4  # an outlier the clipped combine rejects
    master = combine_darks(darks)
    import ccdproc

    ref = ccdproc.combine([CCDData(d.data.data, unit="electron/s") for d in darks],
                          method="average", sigma_clip=True, sigma_clip_low_thresh=3.0,
                          sigma_clip_high_thresh=3.0, sigma_clip_func=np.ma.median,
                          sigma_clip_dev_func=mad_std)
    np.testing.assert_allclose(master.data.data, ref.data)
    assert master.data.data[0, 0] == pytest.approx(dark_level[0, 0], abs=0.5)
    assert master.data.uncertainty is not None and master.header["NCOMBINE"] == 5
    sci = image(s, dark_level + 2.0)
    out = subtract_dark(sci, master)
    np.testing.assert_allclose(out.data.data, 2.0, atol=0.3)
    path = write(master, tmp_path / "master.fits")
    out2 = subtract_dark(sci, path)
    np.testing.assert_allclose(out2.data.data, out.data.data)
    assert out2.header["DARKFILE"] == "master.fits"
    ccd = CCDData(np.ones((32, 32)) * 1000, unit="electron / ks")  # unit conversion
    np.testing.assert_allclose(subtract_dark(sci, ccd).data.data, dark_level + 1.0)
    with pytest.raises(SpherexReduceError, match="at least two"):
        combine_darks(darks[:1])
    with pytest.raises(SpherexReduceError, match="does not match"):
        subtract_dark(sci, CCDData(np.ones((4, 4)), unit="electron/s"))


def test_combine_cli(tmp_path, capsys):
    s = sched()
    paths = []
    for i in range(3):
        paths.append(write(image(s, np.full((32, 32), float(i))), tmp_path / f"d{i}.fits"))
    out = tmp_path / "master.fits"
    assert main(["combine", *map(str, paths), "-o", str(out), "--sigma", "0"]) == 0
    master = read(out)
    np.testing.assert_allclose(master.data.data, 1.0)
    assert master.header["NCOMBINE"] == 3
    assert main(["combine", *map(str, paths), "-o", str(out)]) == 2  # exists
    assert "exists" in capsys.readouterr().err
    assert main(["combine", str(paths[0]), "-o", str(tmp_path / "m2.fits")]) == 2
    assert main(["combine", *map(str, paths), "-o", str(out), "--overwrite"]) == 0
    raw = sched()
    ramp = write(Exposure.from_arrays(np.zeros((4, raw.n_reads, 32)), raw), tmp_path / "r.fits")
    assert main(["combine", str(ramp), str(ramp), "-o", str(tmp_path / "m3.fits")]) == 2
    assert "fit the ramps first" in capsys.readouterr().err
