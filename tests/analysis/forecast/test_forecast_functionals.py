"""The forecast's functionals (`spherex_reduce.analysis.forecast.functionals`) against
explicit loops: the light columns' phases as sums of exp(-i k x), their per-channel sums
column by column, and the correlations X(k_x, d) = sum_s f_a(s + d) conj f_b(s) of dense
and separable parts summed offset by offset, for channel and common scope, ACN and
visibility."""

import cmath
import math

import numpy as np
import pytest

from spherex_reduce.analysis.forecast.functionals import (
    Correlations,
    Part,
    channel_sums,
    column_phases,
)
from spherex_reduce.core.geometry import DetectorGeometry
from spherex_reduce.noise import NoiseComponent

NCH, NKX, N = 3, 4, 5  # channels, column wave numbers, offsets of a functional


@pytest.fixture
def geometry():
    return DetectorGeometry(nrows=12, ncols=24, nchannels=NCH, ref_border=2)


def test_column_phases_are_exp_minus_i_k_x_of_each_light_column(geometry):
    cols = slice(2, 22)
    kx = [0, 1, 3, 10]
    j, phase = column_phases(geometry, cols, kx)
    assert list(j) == list(range(2, 22))
    assert phase.shape == (20, 4)
    for x in range(20):
        for q, k in enumerate(kx):
            expected = cmath.exp(-1j * 2 * math.pi * k / 20 * x)
            assert phase[x, q] == pytest.approx(expected, abs=1e-12)


def test_channel_sums_add_the_phases_of_each_channels_used_columns(geometry):
    cols = slice(2, 22)
    j, phase = column_phases(geometry, cols, [0, 1, 2, 5])
    rng = np.random.default_rng(3)
    used = rng.random(j.size) < 0.6
    got = channel_sums(geometry, j, phase, used)
    width = 24 // NCH
    expected = np.zeros((NCH, 4), dtype=complex)
    for x, column in enumerate(j):
        if used[x]:
            expected[column // width] += phase[x]
    np.testing.assert_allclose(got, expected, atol=1e-12)
    # kx = 0: each channel counts its used columns
    for ch in range(NCH):
        count = sum(1 for x, col in enumerate(j) if used[x] and col // width == ch)
        assert got[ch, 0] == pytest.approx(count)


def _random_parts(rng, phantom_flags):
    """A functional of one dense part and separable ones (amp times profile)."""
    parts = []
    for i, phantom in enumerate(phantom_flags):
        if i == 0:
            dense = rng.normal(size=(NCH, NKX, N)) + 1j * rng.normal(size=(NCH, NKX, N))
            parts.append(Part(phantom, dense=dense))
        else:
            amp = rng.normal(size=(NCH, NKX)) + 1j * rng.normal(size=(NCH, NKX))
            parts.append(Part(phantom, amp=amp, profile=rng.normal(size=N)))
    return parts


def _values(parts, comp):
    """f[ch, k, s]: the sum of the parts ``comp`` sees, written out."""
    f = np.zeros((NCH, NKX, N), dtype=complex)
    for part in parts:
        seen = comp.seen_by_phantom if part.phantom else comp.seen_by_pixels
        if not seen:
            continue
        for ch in range(NCH):
            for k in range(NKX):
                for s in range(N):
                    f[ch, k, s] += (part.dense[ch, k, s] if part.dense is not None
                                    else part.amp[ch, k] * part.profile[s])
    return f


def _brute_correlation(fa, fb, comp):
    """X[k, d + n - 1] = sum_ch sum_s fa(s + d) conj fb(s) (of the channel sums for common
    scope); with ACN, odd d are zero."""
    if comp.scope == "common":
        fa, fb = fa.sum(axis=0, keepdims=True), fb.sum(axis=0, keepdims=True)
    x = np.zeros((NKX, 2 * N - 1), dtype=complex)
    for k in range(NKX):
        for d in range(-(N - 1), N):
            if comp.acn and d % 2:
                continue
            total = 0j
            for ch in range(fa.shape[0]):
                for s in range(N):
                    if 0 <= s + d < N:
                        total += fa[ch, k, s + d] * np.conj(fb[ch, k, s])
            x[k, d + N - 1] = total
    return x


COMPONENTS = [
    NoiseComponent("pixels", alpha=1.0),
    NoiseComponent("acn", beta=1.0, acn=True),
    NoiseComponent("phantom", beta=1.0, visibility="phantom"),
    NoiseComponent("both", alpha=1.0, visibility="both", acn=True),
    NoiseComponent("common", beta=1.0, scope="common", visibility="both"),
    NoiseComponent("common_pixels", beta=1.0, scope="common"),
]


@pytest.mark.parametrize("comp", COMPONENTS, ids=lambda c: c.name)
def test_correlations_of_two_functionals_are_the_sums_over_offsets(comp):
    rng = np.random.default_rng(7)
    a = ("a", _random_parts(rng, [False, True, False]))
    b = ("b", _random_parts(rng, [False, False, True]))
    corr = Correlations()
    for first, second in ((a, b), (b, a), (a, a)):
        got = corr.correlate(first, second, comp)
        expected = _brute_correlation(_values(first[1], comp), _values(second[1], comp),
                                      comp)
        np.testing.assert_allclose(got, expected, atol=1e-9)


def test_correlations_are_kept_per_component_kind_and_zero_when_nothing_is_seen():
    rng = np.random.default_rng(11)
    a = ("a", _random_parts(rng, [False, False]))
    b = ("b", _random_parts(rng, [False]))
    corr = Correlations()
    pixels, acn, phantom = COMPONENTS[0], COMPONENTS[1], COMPONENTS[2]
    # the same cached correlation, ACN applied to it afterwards
    full = corr.correlate(a, b, pixels)
    halved = corr.correlate(a, b, acn)
    d = np.arange(-(N - 1), N)
    np.testing.assert_allclose(halved[:, d % 2 == 0], full[:, d % 2 == 0])
    assert np.all(halved[:, d % 2 == 1] == 0)
    # no part of these pixel-only functionals is seen by a phantom-only component
    assert np.all(corr.correlate(a, b, phantom) == 0)
    assert corr.correlate(a, b, phantom).shape == (NKX, 2 * N - 1)


def test_part_seen_follows_the_components_visibility():
    pix, ph = Part(False, dense=np.zeros((1, 1, 1))), Part(True, dense=np.zeros((1, 1, 1)))
    for comp in COMPONENTS:
        assert pix.seen(comp) == (comp.visibility in ("pixels", "both"))
        assert ph.seen(comp) == (comp.visibility in ("phantom", "both"))
