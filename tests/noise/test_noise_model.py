"""Noise table, components and the analytic slope variance.

The analytic slope variance (closed-form structure functions) is checked
against an independent numerical quadrature of ``integral p(f) |H(f)|^2 df``
that resolves the comb of ``|H|^2``; the simulator's own exact expectation is
checked against it in ``tests/simulation/test_engine_expectation.py``.
"""

import itertools

import numpy as np
import pytest
from _paper import TABLE2
from _paths import ROOT
from astropy import units as u
from scipy import integrate

from spherex_reduce import expected_slope_variance
from spherex_reduce.io.config import schedule_from_config
from spherex_reduce.simulation import (
    NoiseComponent,
    load_noise_table,
    ls_weights,
    noise_components,
)

SINGLE = [NoiseComponent("alpha_only", alpha=2e-3), NoiseComponent("beta_only", beta=8.4e-3),
          NoiseComponent("gamma_only", gamma=0.1)]
SMALL = ({"nrows": 16, "ncols": 64, "nchannels": 32, "ref_border": 0},
         {"skip": 1, "ref_reads": 0, "phantom_reads": 0, "row_overhead": 0,
          "frame_overhead": 200})


def test_table2_values_and_provenance():
    t = load_noise_table("spherex-table2")
    assert "Heaton" in t.meta["reference"] and "one-sided" in t.meta["psd"]
    assert "100000 Hz" in t.meta["pixel_rate"]
    comps = noise_components()
    assert list(comps) == list(TABLE2)
    for name, (a, b, g) in TABLE2.items():
        c = comps[name]
        assert (c.alpha, c.beta, c.gamma, c.exponent) == (a, b, g, 1.3)
    assert comps["video8"].scope == comps["roic"].scope == "channel"
    assert all(comps[n].scope == "common" for n in ("bias_correlated", "bias_phantom_only",
                                                    "bias_pixels_only"))
    assert comps["roic"].visibility == "pixels"  # ROIC not seen by phantom reads
    assert comps["bias_phantom_only"].visibility == "phantom"
    assert comps["bias_correlated"].visibility == "both"
    assert t["alpha"].unit == u.electron**2 / u.Hz


def test_repository_copy_matches_package_table():
    repo = ROOT / "data" / "spherex-table2.ecsv"
    pkg = ROOT / "spherex_reduce" / "data" / "spherex-table2.ecsv"
    assert repo.read_text() == pkg.read_text()


@pytest.mark.parametrize("comp", [NoiseComponent("x", alpha=1e-3, beta=2e-3, gamma=0.05),
                                  NoiseComponent("y", gamma=0.1, exponent=2.0),
                                  NoiseComponent("z", gamma=0.1, exponent=0.5)])
def test_structure_function_against_quadrature(comp):
    """D(lag) = 2 int_0^{fs/2} p(f) (1 - cos(2 pi f lag / fs)) df, by QUADPACK (QAWO)."""
    fs = 1e5
    for lag in (1, 7, 12.5, 1000, 151000):
        om = 2 * np.pi * lag / fs
        eps = 1e-3 / om
        near = integrate.quad(lambda f, om=om: comp.psd(f) * 2 * np.sin(om * f / 2) ** 2, 0, eps,
                              epsabs=0, epsrel=1e-9, limit=200)[0]
        e, top = comp.exponent, fs / 2  # elementary integral of p over [eps, fs/2]
        plain = (comp.alpha * (top - eps) + comp.beta * np.log(top / eps)
                 + comp.gamma * (top ** (1 - e) - eps ** (1 - e)) / (1 - e))
        osc = integrate.quad(comp.psd, eps, fs / 2, weight="cos", wvar=om, epsabs=0,
                             epsrel=1e-8, limit=5000)[0]
        assert comp.structure_function(lag, fs) == pytest.approx(2 * (near + plain - osc),
                                                                 rel=1e-6)


def _quadrature_slope_variance(comp, schedule):
    """Independent: integrate p(f)|H(f)|^2 over [0, fs/2], period by period of |H|^2."""
    fs = schedule.geometry.pixel_rate
    n = schedule.nframes
    tf = schedule.frame_samples / fs
    t = np.arange(n) * tf
    w = ls_weights(t)
    nper = round(fs / 2 * tf)
    x, wq = np.polynomial.legendre.leggauss(2 * n + 16)
    x, wq = (x + 1) / 2, wq / 2

    def h2(f):
        return np.abs(np.exp(2j * np.pi * f[:, None] * t[None, :]) @ w) ** 2

    # first period: geometric pieces towards f = 0 (integrand ~ f^(2 - exponent))
    edges = np.concatenate([[0.0], np.geomspace(1e-10, 1.0, 200)]) / tf
    total = 0.0
    for a, b in itertools.pairwise(edges):
        f = a + (b - a) * x
        total += np.sum(wq * comp.psd(f) * h2(f)) * (b - a)
    f = (np.arange(1, nper)[:, None] + x[None, :]).ravel() / tf
    total += np.sum(np.tile(wq, nper - 1) * comp.psd(f) * h2(f)) / tf
    return total


@pytest.mark.parametrize("n", [2, 10, 74])
@pytest.mark.parametrize("comp", [*SINGLE, noise_components()["video8"]])
def test_analytic_variance_against_quadrature(comp, n):
    s = schedule_from_config({"nrows": 16, "ncols": 64, "nchannels": 32, "ref_border": 0},
                             {"skip": 1, "ref_reads": 0, "phantom_reads": 0,
                              "row_overhead": 0, "frame_overhead": 1000, "nframes": n})
    ana = expected_slope_variance(comp, s)
    assert ana.unit == u.electron**2 / u.s**2
    assert ana.value == pytest.approx(_quadrature_slope_variance(comp, s), rel=1e-4)


def test_white_closed_form_and_table_sum():
    s = schedule_from_config({}, {"nframes": 10})
    white = NoiseComponent("w", alpha=2e-3)
    w = ls_weights(np.arange(10) * s.frame_time.value)
    assert expected_slope_variance(white, s).value == pytest.approx(100.0 * np.sum(w * w))
    total = expected_slope_variance("spherex-table2", s)
    parts = [expected_slope_variance(c, s) for c in noise_components().values()]
    assert total.value == pytest.approx(sum(p.value for p in parts))
    # bias_phantom_only is not seen by the pixels
    assert expected_slope_variance(noise_components()["bias_phantom_only"], s).value == 0
    ph = expected_slope_variance(noise_components()["bias_phantom_only"], s, kind="phantom")
    assert ph.value > 0


def test_g_power_at_multiples_of_pi_is_the_series_without_its_sine_terms():
    """Given ``cos z`` (``z`` a multiple of pi, ``sin z = 0``), the tail series of
    ``G_e`` drops its sine terms: the same numbers, to the last digit, as the full series
    written out here with ``sin z = 0``, and within 1e-12 of it with ``sin`` and ``cos``
    of ``z`` computed; a non-finite ``cos z`` falls back to the trigonometric functions."""
    from scipy import special

    from spherex_reduce.noise.structure_functions import g_power

    rng = np.random.default_rng(7)
    n = rng.integers(13, 10**6, 500).astype(float)
    z = np.pi * n
    for e in (0.7, 1.3, 2.2):
        cos_z = 1.0 - 2.0 * (n % 2)
        k_e = np.pi / (2 * special.gamma(e) * np.sin(np.pi * (e - 1) / 2))
        s, c, inv, zme = np.zeros_like(z), cos_z, 1 / z, z ** (-e)
        tail = zme * (-s + inv * (e * c + inv * (e * (e + 1) * s - inv * (
            e * (e + 1) * (e + 2) * c + inv * e * (e + 1) * (e + 2) * (e + 3) * s))))
        expect = k_e - z * zme / (e - 1) + tail
        assert np.array_equal(g_power(z, e, cos_z), expect)
        np.testing.assert_allclose(g_power(z, e), expect, rtol=1e-12)
        some = np.where(np.arange(z.size) % 3 == 0, np.nan, cos_z)
        np.testing.assert_allclose(g_power(z, e, some), expect, rtol=1e-12)


def test_a_builtin_table_s_components_are_parsed_once_and_handed_out_as_new_dicts():
    """A search loads the paper's table for every schedule: its components are parsed once,
    each call gets its own dict (changing one changes no other), the same components as the
    table's rows read here."""
    from spherex_reduce.noise.components import load_noise_table, noise_components

    first = noise_components("spherex-table2")
    first.pop("roic")
    again = noise_components("spherex-table2")
    table = load_noise_table("spherex-table2")
    assert list(again) == [str(n) for n in table["name"]]
    for row in table:
        comp = again[str(row["name"])]
        assert comp.alpha == float(row["alpha"]) and comp.beta == float(row["beta"])
        assert comp.gamma == float(row["gamma"]) and comp.scope == str(row["scope"])
