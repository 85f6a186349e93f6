"""``scene.active_read_noise``: white read noise of the light-sensitive pixels alone (the
reference pixels read quieter, as NGHXRG's and JWST's do), in ramps and in slopes, against
its variance computed here with numpy."""

import numpy as np
import pytest

from spherex_reduce import simulate
from spherex_reduce.simulation import load_scene

SIGMA, WHITE = 6.0, 2e-4  # e per read; the channel's white level (e^2/Hz): 10 e^2 per read


def _scene(mode, terms=None, **top):
    return {"geometry": {"nrows": 48, "ncols": 48, "nchannels": 2, "ref_border": 4},
            "readout": {"skip": 4, "ref_reads": 8, "phantom_reads": 0, "nframes": 8,
                        "frame_time": 1.5},
            "noise": {"components": [{"name": "white", "alpha": WHITE}]},
            "output": {"mode": mode}, "scene": terms or {}, **top}


def _split(e):
    data = np.asarray(e.data.data, dtype=np.float64)
    ref = np.asarray(e.reference_pixel_mask())
    return data, ref


def _within(values, expect, sigmas=4.0):
    """The sample variance of ``values`` (mean known to be 0 only across pixels) against
    ``expect``: its standard error for Gaussian values is ``expect sqrt(2 / n)``."""
    n = values.size
    got = values.var()
    assert abs(got - expect) < sigmas * expect * np.sqrt(2.0 / n), (got, expect, n)


@pytest.mark.parametrize("unit", [{}, {"unit": "adu", "gain": 2.0}])
def test_ramps_light_sensitive_pixels_alone_read_the_extra_white_noise(unit):
    """Each read's white variance: the channel's ``alpha fs / 2`` on every pixel, plus
    ``active_read_noise²`` (in the scene's unit) on the light-sensitive pixels only."""
    seeds = range(6)
    diffs = {True: [], False: []}
    for seed in seeds:
        data, ref = _split(simulate(_scene("ramps", {"active_read_noise": SIGMA}, **unit),
                                    seed=seed))
        d = np.diff(data, axis=0) / np.sqrt(2.0)  # reads' differences: twice a read's
        diffs[True].append(d[:, ref])
        diffs[False].append(d[:, ~ref])
    stream = WHITE * 1e5 / 2
    _within(np.concatenate(diffs[True], axis=None), stream)
    _within(np.concatenate(diffs[False], axis=None), stream + SIGMA**2)


def test_slopes_weigh_each_reads_extra_noise_by_the_least_squares_weights():
    """A slope's variance from it: ``σ² Σ w_k²``, ``w`` the least-squares weights of the
    frame times (computed here)."""
    sc = load_scene(_scene("slopes"))
    t = np.arange(8) * sc.schedule.frame_time.to_value("s")
    w = (t - t.mean()) / np.sum((t - t.mean()) ** 2)
    stream = WHITE * 1e5 / 2 * np.sum(w * w)
    light, refs = [], []
    for seed in range(20):
        data, ref = _split(simulate(_scene("slopes", {"active_read_noise": SIGMA}),
                                    seed=seed))
        light.append(data[~ref])
        refs.append(data[ref])
    _within(np.concatenate(refs), stream)
    _within(np.concatenate(light), stream + SIGMA**2 * np.sum(w * w))


@pytest.mark.parametrize("mode", ["ramps", "slopes"])
def test_the_reference_pixels_are_those_of_the_scene_without_it(mode):
    """The extra noise has a generator of its own: everything else, and every reference
    pixel, is drawn as before, to the bit."""
    with_it, ref = _split(simulate(_scene(mode, {"active_read_noise": SIGMA}), seed=3))
    without, _ = _split(simulate(_scene(mode), seed=3))
    np.testing.assert_array_equal(with_it[..., ref], without[..., ref])
    assert np.all(with_it[..., ~ref] != without[..., ~ref])
