"""Scenes: errors name the YAML path; the paper's defaults, the example, the simulator plugin."""

import pytest
from _paper import TABLE2
from _paths import ROOT

from spherex_reduce import ConfigError
from spherex_reduce.reduce.plugins import Registry, get_plugin_manager
from spherex_reduce.simulation import SpherexSimulator, load_scene


@pytest.mark.parametrize("scene, path", [
    ({"noise": {"components": ["video8", "nope"]}}, "noise.components[1]"),
    ({"noise": {"components": [{"name": "x", "beta": -1.0}]}}, "noise.components[0].beta"),
    ({"noise": {"components": ["roic", {"name": "y", "gamma": "big"}]}},
     "noise.components[1].gamma"),
    ({"noise": {"components": [{"name": "z", "scope": "common", "acn": True}]}},
     "noise.components[0]"),
    ({"noise": {"colour": 1}}, "noise.colour"),
    ({"scene": {"dark_current": -1}}, "scene.dark_current"),
    ({"scene": {"rtn": {"fraction": 0.1, "amp": 1}}}, "scene.rtn.amp"),
    ({"output": {"mode": "cube"}}, "output.mode"),
    ({"readout": {"skip": 0}}, "readout.skip"),
    ({"geometry": {"ncols": "x"}}, "geometry.ncols"),
    ({"synthesis": {"method": "pink"}}, "synthesis.method"),
    ({"seed": -3}, "seed"),
    ({"scnee": {}}, "scnee"),
])
def test_scene_errors_name_the_yaml_path(scene, path):
    with pytest.raises(ConfigError, match=path.replace("[", r"\[").replace("]", r"\]")):
        load_scene(scene)


def test_scene_defaults_are_the_paper_case(tmp_path):
    sc = load_scene()
    assert [c.name for c in sc.components] == list(TABLE2)
    assert sc.schedule.nframes == 74 and sc.schedule.skip == 24
    assert sc.mode == "slopes"
    f = tmp_path / "scene.yaml"
    f.write_text("readout: {nframes: 3}\nnoise:\n  components: [roic, {name: extra, beta: 1e-3,"
                 " scope: channel, visibility: both}]\n  acn: false\nseed: 5\n")
    sc = load_scene(f)
    assert [c.name for c in sc.components] == ["roic", "extra"]
    assert not sc.components[0].acn and sc.seed == 5


def test_simulator_registered_as_plugin():
    reg = Registry(get_plugin_manager(entry_points=False))
    assert reg.simulator("spherex") is SpherexSimulator
    assert reg.providers["simulator"]["spherex"] == "simulation"


def test_example_scene_is_the_default_case():
    f = ROOT / "data" / "examples" / "simulate-paper.yaml"
    sc, default = load_scene(f), load_scene()
    assert sc.schedule == default.schedule and sc.components == default.components
    assert sc.seed == 1234 and sc.mode == "slopes"


def test_scene_terms_are_a_record_and_the_simulation_history_names_them_as_written():
    """The ``scene:`` section read into `SceneTerms` (defaults from the file's table) and
    written to the simulated file's HISTORY as the same mapping, keys in table order."""
    import json

    from spherex_reduce.simulation import simulate
    from spherex_reduce.simulation.scene import SceneTerms, Telegraph

    given = {"readout": {"nframes": 4}, "geometry": {"nrows": 16, "ncols": 16, "nchannels": 2,
                                                     "ref_border": 4},
             "noise": {"components": []},
             "scene": {"photocurrent": 2, "rtn": {"fraction": 0.5, "amplitude": 3}}}
    terms = load_scene(given).terms
    assert terms == SceneTerms(dark_current=0.0, hot_pixel_fraction=0.0,
                               hot_pixel_current=10.0, photocurrent=2.0, leakage=0.0,
                               poisson=True, rtn=Telegraph(0.5, 3.0, 0.1, "active"))
    assert terms.rtn.on and load_scene({}).terms.rtn is None
    history = "".join(str(h) for h in simulate(given, seed=1).header["HISTORY"])
    written, _ = json.JSONDecoder().raw_decode(history, history.index("scene {") + 6)
    assert written == {
        "dark_current": 0.0, "hot_pixel_fraction": 0.0, "hot_pixel_current": 10.0,
        "photocurrent": 2.0, "leakage": 0.0, "poisson": True,
        "rtn": {"fraction": 0.5, "amplitude": 3.0, "rate": 0.1, "pixels": "active",
                "amplitude_spread": 0.0, "rate_spread": 0.0},
        "dark_current_spread": 0.0, "hot_pixel_current_spread": 0.0, "active_read_noise": 0.0,
        "population_seed": None}
    assert list(written) == [
        "dark_current", "hot_pixel_fraction", "hot_pixel_current", "photocurrent", "leakage",
        "poisson", "rtn", "dark_current_spread", "hot_pixel_current_spread",
        "active_read_noise", "population_seed"]
