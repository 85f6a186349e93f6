"""pair_difference: scaling, uncertainty, refusals, and a foreign second file."""

import numpy as np
import pytest
from astropy import units as u

from spherex_reduce import (
    DetectorGeometry,
    Exposure,
    Pipeline,
    ReadoutSchedule,
    pair_difference,
    unchop,
)
from spherex_reduce.core.errors import SpherexReduceError
from spherex_reduce.io.examples import example_raw_exposure


def sched(nframes=4, skip=3):
    return ReadoutSchedule(DetectorGeometry(32, 32, 2, ref_border=2), skip=skip, ref_reads=4,
                           phantom_reads=0, nframes=nframes)


def image(s, values, **kw):
    return Exposure.from_arrays(values, s, order="physical", unit=u.electron / u.s, **kw)


def test_pair_difference_scaling_uncertainty_and_refusal():
    s = sched()
    rng = np.random.default_rng(2)
    a_val, b_val = rng.normal(0, 1, (2, 32, 32))
    a = image(s, a_val, uncertainty=np.full((32, 32), 3.0))
    b = image(s, b_val, uncertainty=np.full((32, 32), 4.0),
              mask=np.eye(32, dtype=bool))
    d = pair_difference(a, b)
    np.testing.assert_allclose(d.data.data, (a_val - b_val) / np.sqrt(2))
    np.testing.assert_allclose(d.data.uncertainty.array, 5.0 / np.sqrt(2))
    assert np.array_equal(d.data.mask, np.eye(32, dtype=bool))
    assert d.header["PAIRDIFF"]
    other = image(sched(skip=4), b_val)
    with pytest.raises(SpherexReduceError, match=r"readout parameters differ \(skip: 3 vs 4"):
        pair_difference(a, other)
    with pytest.raises(SpherexReduceError, match="shapes differ"):
        pair_difference(a, Exposure.from_arrays(np.zeros((4, 32, 32)), s, order="physical"))


def test_pair_difference_doubles_nothing_for_identical_noise_statistics():
    # the 1/sqrt(2) keeps the per-exposure noise: std of the difference of two N(0, 1)
    s = sched()
    rng = np.random.default_rng(3)
    a, b = (image(s, rng.normal(0, 1, (32, 32))) for _ in range(2))
    assert np.std(pair_difference(a, b).data.data) == pytest.approx(1.0, rel=0.1)


def test_pair_difference_reads_a_foreign_second_file_with_the_config_sections(tmp_path):
    # both files of the pair lack the read-order keywords; the config's geometry:/readout:
    # sections must serve the second one too (it failed with "supply them in the config")
    from astropy.io import fits

    from spherex_reduce import (
        DetectorGeometry,
        ReadoutSchedule,
        fit_ramp,
        pair_difference,
        subtract_phantom,
    )

    s = ReadoutSchedule(DetectorGeometry(32, 16, 2, ref_border=2), skip=5, ref_reads=6,
                        ref_mode="distributed", phantom_reads=3, row_overhead=2,
                        frame_overhead=50, nframes=4)
    raws = [example_raw_exposure(s, seed=seed) for seed in (1, 2)]
    paths = []
    for k, raw in enumerate(raws):
        paths.append(tmp_path / f"foreign{k}.fits")
        fits.HDUList([fits.PrimaryHDU(), fits.ImageHDU(np.asarray(raw.data.data), name="SCI"),
                      fits.ImageHDU(raw.phantom, name="PHANTOM")]).writeto(paths[-1])
    config = {
        "geometry": {"nrows": 32, "ncols": 16, "nchannels": 2, "ref_border": 2,
                     "pixel_rate": 100000},
        "readout": {"skip": 5, "ref_reads": 6, "ref_mode": "distributed", "phantom_reads": 3,
                    "row_overhead": 2, "frame_overhead": 50, "nframes": 4},
        "steps": [{"unchop": {}}, {"subtract_phantom": {}}, {"fit_ramp": {}},
                  {"pair_difference": {"other": str(paths[1])}}],
    }
    out = Pipeline(config).run(paths[0])
    expected = pair_difference(*[fit_ramp(subtract_phantom(unchop(r))) for r in raws])
    np.testing.assert_allclose(out.data.data, expected.data.data, rtol=1e-5, atol=1e-3)
    # and when the second file is already at the same stage (read, not reduced)
    config["steps"][-1]["pair_difference"]["reduce_other"] = False
    config["steps"] = config["steps"][-1:]
    out = Pipeline(config).run(paths[0])
    assert out.header["S_PAIRDF"] == "COMPLETE"
