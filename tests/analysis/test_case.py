"""`run_case`: the one simulate -> reduce -> measure route of demo, figures and sweeps."""

import numpy as np
import pytest

from spherex_reduce.analysis import (
    SpectrumMeasure,
    as_pipeline,
    band_power,
    power_spectrum,
    run_case,
)
from spherex_reduce.analysis.sweep import load_sweep, run_cell
from spherex_reduce.core.errors import SpherexReduceError
from spherex_reduce.simulation import simulate

SCENE = {"geometry": {"nrows": 64, "ncols": 64, "nchannels": 2, "ref_border": 4},
         "readout": {"skip": 4, "ref_reads": 8, "nframes": 5, "phantom_reads": 2}}
RAW = {"name": "raw", "steps": [{"unchop": {}}]}


def test_one_case_is_simulate_then_reduce_then_measure():
    """Each step done by hand, with the public functions, gives the same numbers: the
    measure sees the light-sensitive pixels, the 56 x 56 inside the 4-pixel border."""
    res = run_case(SCENE, {"raw": RAW, "corrected": "spherex-default"},
                   {"bins": 6, "exclude_horizontal": True}, seed=4, keep=True)
    raw = simulate(SCENE, seed=4)
    for label, pipe in (("raw", RAW), ("corrected", "spherex-default")):
        whole = as_pipeline(pipe).run(raw).to_ccddata()
        np.testing.assert_array_equal(res.reduced[label].to_ccddata().data, whole.data)
        image = whole[4:60, 4:60]
        m = res.measured[label]
        edges = np.geomspace(2 * np.pi / 56, np.pi, 7)
        spec = power_spectrum(image, bins=edges, exclude_horizontal=True)
        np.testing.assert_array_equal(np.asarray(m["spectrum"]["power"]),
                                      np.asarray(spec["power"]))
        assert m["band_power"] == band_power(image, exclude_horizontal=True)
        assert m["std"] == float(np.std(np.asarray(image.data, float)))
        assert m["k"].shape == (6,)  # every bin, empty ones NaN
    assert set(res.seconds) == {"simulate", "raw", "corrected"}
    # the pipelines saw one exposure: the corrected one differs, the simulation does not
    assert res.measured["raw"]["band_power"] != res.measured["corrected"]["band_power"]


def test_streamed_from_a_file_equals_in_memory(tmp_path):
    scene = {**SCENE, "output": {"mode": "ramps"}}
    mem = run_case(scene, "spherex-default", SpectrumMeasure(), seed=3, keep=True)
    disk = run_case(scene, "spherex-default", SpectrumMeasure(), seed=3, keep=True,
                    raw_path=tmp_path / "raw.fits")
    assert disk.raw == tmp_path / "raw.fits" and disk.raw.is_file()
    np.testing.assert_array_equal(mem.reduced["spherex-default"].to_ccddata().data,
                                  disk.reduced["spherex-default"].to_ccddata().data)
    assert mem.measurement["band_power"] == disk.measurement["band_power"]


def test_a_measure_needs_an_image():
    scene = {**SCENE, "output": {"mode": "ramps"}}
    with pytest.raises(SpherexReduceError, match="left ramps"):
        run_case(scene, RAW, lambda image: image, seed=1)
    res = run_case(scene, RAW, seed=1, keep=True)  # no measure: ramps are fine
    assert res.reduced["raw"].is_ramp and res.measured == {}
    with pytest.raises(SpherexReduceError, match="0 measurements"):
        _ = res.measurement


def test_a_sweep_cell_is_a_case():
    sw = load_sweep({"scene": SCENE, "grid": {"skip": [4]}, "seed": 9,
                     "measure": {"bins": 5}})
    cell = sw.cells()[0]
    task = sw.task(cell)
    row = run_cell(task)
    seed = int(np.random.SeedSequence(task.entropy).generate_state(1, np.uint64)[0])
    m = run_case(task.scene, "spherex-default", {"bins": 5}, seed=seed,
                 mode="slopes").measurement
    assert row.band_power == m["band_power"].value and row.cell == cell
    np.testing.assert_array_equal(row.power, m["power"])


def test_the_measure_never_sees_the_reference_pixels():
    """Reference pixels at 1e6 (injected into the raw slopes; ``unchop`` passes them
    through): the std and band power measured are numpy's and `power_spectrum`'s of the
    inner 20 x 20 pixels of a border {top: 4, left: 4} (the border in, the std was 460641
    against 144)."""
    scene = {"geometry": {"nrows": 24, "ncols": 24, "nchannels": 2,
                          "ref_border": {"top": 4, "left": 4}},
             "readout": {"skip": 4, "ref_reads": 4, "nframes": 5, "phantom_reads": 0}}

    def extreme(raw):
        ref = np.zeros((24, 24), bool)
        ref[:4] = True
        ref[:, :4] = True
        values = np.where(ref[raw.schedule.rows], 1e6, raw.data.data)
        return raw.replace(data=values)

    res = run_case(scene, RAW, {"bins": 4, "kmin": 0.3, "kmax": 1.0}, seed=2, keep=True,
                   inject=extreme)
    whole = res.reduced["raw"].to_ccddata()
    assert whole.data[:4].min() == 1e6 and whole.data[:, :4].min() == 1e6
    light = np.asarray(whole.data[4:, 4:], float)
    m = res.measured["raw"]
    assert m["std"] == pytest.approx(float(np.std(light)), rel=1e-12)
    edges = np.geomspace(2 * np.pi / 20, np.pi, 5)
    np.testing.assert_allclose(np.asarray(m["spectrum"]["power"]),
                               np.asarray(power_spectrum(light, bins=edges)["power"]),
                               rtol=1e-12)
    assert m["band_power"].value == pytest.approx(band_power(light, 0.3, 1.0).value,
                                                  rel=1e-12)


def test_paired_case_measures_each_pipeline_with_and_without_the_injection():
    """paired: the measure gets (with, without) of the same noise, the exposure without
    reduced as simulate gives it (numpy: the same seed, reduced by hand)."""
    from spherex_reduce.reduce.pipeline import as_pipeline

    def plus(raw):
        return raw.replace(data=raw.data.data + 3.0)

    seen = []
    res = run_case(SCENE, RAW, lambda image, without: seen.append((image, without)) or 0.0,
                   seed=4, inject=plus, paired=True)
    assert res.measurement == 0.0 and len(seen) == 1
    image, without = (np.asarray(x.data, float) for x in seen[0])
    plain = as_pipeline(RAW).run(simulate(SCENE, seed=4)).to_ccddata()
    np.testing.assert_array_equal(without, np.asarray(plain.data, float)[4:-4, 4:-4])
    np.testing.assert_allclose(image - without, 3.0, rtol=0, atol=1e-3)
    with pytest.raises(SpherexReduceError, match="paired needs inject"):
        run_case(SCENE, RAW, lambda image, without: 0.0, seed=4, paired=True)


# -- the keys a design, a sweep and a comparison share: refused in the same words ---------
SHARED = [
    ({"seed": -1}, "seed: must be >= 0, got -1"),
    ({"seed": 1.5}, "seed: expected integer, got 1.5"),
    ({"seed": True}, "seed: expected integer, got True"),
    ({"seed": None}, "seed: expected integer, got None"),
    ({"realizations": 2.5}, "realizations: expected integer, got 2.5"),
    ({"realizations": "5"}, "realizations: expected integer, got '5'"),
    ({"realizations": 10**9}, "realizations must be a whole number from 1 to 10000, got "
                              "1000000000"),
    ({"scene": 5}, "scene: expected mapping or string or null, got 5"),
    ({"scene": "no-such-scene.yaml"}, "scene: scene file not found: no-such-scene.yaml"),
]
MEASURED = [
    ({"bins": 0}, "measure.bins: must be in [1, 10000], got 0"),
    ({"bins": [0.5]}, "measure.bins: expected a list of 2 to 10001 items, got [0.5]"),
    ({"bins": [0.1, -0.2]}, "measure.bins[1]: must be >= 0, got -0.2"),
    ({"bins": [0.5, 0.2]}, "measure.bins: the bin edges must increase, got [0.5, 0.2]"),
    ({"kmin": "low"}, "measure.kmin: expected integer or number, got 'low'"),
    ({"kmin": -0.1}, "measure.kmin: must be >= 0, got -0.1"),
    ({"kmin": 0.5, "kmax": 0.2}, "measure: kmin must be below kmax, got 0.5 and 0.2"),
    ({"exclude_horizontal": "yes"}, "measure.exclude_horizontal: expected boolean, got 'yes'"),
    ({"colour": 1}, "measure.colour: unknown parameter; valid: kmin, kmax, bins, "
                    "exclude_horizontal"),
]


def _refusal(load, config):
    with pytest.raises(SpherexReduceError) as info:
        load(config)
    return type(info.value).__name__, str(info.value)


def _loaders():
    from spherex_reduce.analysis.compare import load_comparison
    from spherex_reduce.analysis.design.file import load_design

    design = {"scene": SCENE, "search": {"iterations": 0}, "realizations": 0}
    return {"design": (load_design, design),
            "sweep": (load_sweep, {"scene": SCENE, "grid": {"skip": [4]}}),
            "comparison": (load_comparison, {"scene": SCENE, "measure": {
                "kmin": 0.2, "kmax": 1.0, "bins": 6}})}


@pytest.mark.parametrize(("change", "words"), SHARED)
def test_a_design_a_sweep_and_a_comparison_refuse_a_shared_key_in_the_same_words(change,
                                                                                  words):
    for name, (load, base) in _loaders().items():
        kind, text = _refusal(load, {**base, **change})
        assert text == f"{name}: {words}", name
        assert kind == ("ResourceError" if change.get("realizations") == 10**9
                        else "ConfigError")


@pytest.mark.parametrize(("change", "words"), MEASURED)
def test_a_sweep_and_a_comparison_refuse_a_measure_in_the_same_words(change, words):
    for name in ("sweep", "comparison"):
        load, base = _loaders()[name]
        measure = {**base.get("measure", {}), **change}
        said = words  # a sweep's measure takes mask_sources too
        if name == "sweep" and "colour" in change:
            said = words.replace("exclude_horizontal", "exclude_horizontal, mask_sources")
        assert _refusal(load, {**base, "measure": measure}) == ("ConfigError",
                                                                 f"{name}: {said}"), name
