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
