"""The forecast of a readout in an explicit read order (``readout.order``) against a brute-force
covariance of every pixel pair, and against the skip order it spells out."""

import numpy as np
import pytest
from astropy import units as u

from spherex_reduce.analysis import forecast, power_spectrum
from spherex_reduce.noise.variance import slope_covariance
from spherex_reduce.simulation import load_scene

BINS = 5
PINK_ACN = {"name": "pink_acn", "beta": 8e-3, "acn": True}
COMMON = {"name": "common", "alpha": 3e-6, "beta": 9e-5, "scope": "common"}
#: 20 rows: reference rows 0, 1 (top) and 18, 19 (bottom); light rows 2-17 read in a shuffled
#: order, with reference reads between them (one reference row read three times).
ORDER = [0, 9, 3, 14, 17, 18, 6, 2, 11, 5, 16, 1, 8, 13, 4, 10, 0, 15, 7, 12, 19, 0]


def scene(order=None, skip=None):
    readout = {"phantom_reads": 2, "nframes": 4, "frame_overhead": 20000}
    readout.update({"order": order} if order is not None else {"skip": skip, "ref_reads": 4})
    return load_scene({
        "geometry": {"nrows": 20, "ncols": 20, "nchannels": 2,
                     "ref_border": {"top": 2, "bottom": 2, "left": 2, "right": 2}},
        "readout": readout,
        "noise": {"components": [PINK_ACN, COMMON]},
    })


def brute_force(sc):
    """E[power_spectrum] from every light pixel pair's slope covariance at its sampling lag,
    with the read of each physical row looked up in the order written above."""
    s, g = sc.schedule, sc.schedule.geometry
    rows = cols = np.arange(2, 18)
    read = np.array([ORDER.index(p) for p in rows])
    t = (s.starts[read][:, None] + g.column_offsets()[cols][None, :]).ravel()
    chan = np.broadcast_to(g.channel_of_column()[cols], (16, 16)).ravel()
    parity = np.broadcast_to(g.column_offsets()[cols] % 2, (16, 16)).ravel()
    cov = np.zeros((t.size, t.size))
    for comp in sc.components:
        c = slope_covariance(comp, s, t[:, None] - t[None, :])[0]
        if comp.scope == "channel":
            c = c * (chan[:, None] == chan[None, :])
        if comp.acn:
            c = c * (parity[:, None] == parity[None, :])
        cov += c
    lam, vec = np.linalg.eigh(cov)
    keep = lam > 1e-12 * lam.max()
    return sum(lv * power_spectrum(v.reshape(16, 16), bins=BINS)["power"].value
               for lv, v in zip(lam[keep], vec[:, keep].T, strict=True))


def test_an_explicit_order_equals_brute_force():
    sc = scene(ORDER)
    assert sc.schedule.rows.tolist() == ORDER
    got = u.Quantity(forecast(sc, measure={"bins": BINS})["power"]).value
    np.testing.assert_allclose(got, brute_force(sc), rtol=1e-3)


@pytest.mark.parametrize("skip", [1, 3])
def test_an_explicit_order_spelling_out_a_skip_order_forecasts_the_same(skip):
    a = scene(skip=skip)
    b = scene(order=a.schedule.rows.tolist())
    fa, fb = (u.Quantity(forecast(x, measure={"bins": BINS})["power"]).value for x in (a, b))
    np.testing.assert_allclose(fb, fa, rtol=1e-12)
    shuffled = u.Quantity(forecast(scene(ORDER), measure={"bins": BINS})["power"]).value
    assert np.max(np.abs(shuffled / fa - 1)) > 0.01  # the order matters: not a tautology
