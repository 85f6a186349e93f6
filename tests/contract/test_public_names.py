"""Every public name resolves, lazily attached or not, from a fresh interpreter.

The packages attach their names lazily (``lazy_loader``, SPEC 1): a name is
imported when first asked for, so a wrong module in a table, or an import cycle
that only shows when nothing is loaded yet, surfaces on first use.  Each module
is checked in a new interpreter: ``getattr`` and ``from ... import`` of every name
of its ``__all__``, and ``dir()`` lists them.
"""

import json
import subprocess
import sys

import pytest

PUBLIC_MODULES = [
    "spherex_reduce", "spherex_reduce.io", "spherex_reduce.reduce.steps", "spherex_reduce.noise",
    "spherex_reduce.simulation", "spherex_reduce.analysis", "spherex_reduce.plugin",
    "spherex_reduce.core", "spherex_reduce.reduce", "spherex_reduce.cli",
]

RESOLVE = """\
import importlib, json, sys
mod = importlib.import_module(sys.argv[1])
names = list(mod.__all__)
missing = [n for n in names if not hasattr(mod, n)]
exec(f"from {sys.argv[1]} import {', '.join(names)}")
print(json.dumps({"names": names, "missing": missing, "dir": sorted(dir(mod)),
                  "kinds": {n: type(getattr(mod, n)).__name__ for n in names}}))
"""


def resolve(module):
    done = subprocess.run([sys.executable, "-c", RESOLVE, module], capture_output=True,
                          text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    return json.loads(done.stdout)


@pytest.mark.parametrize("module", PUBLIC_MODULES)
def test_every_public_name_resolves_in_a_fresh_interpreter(module):
    found = resolve(module)
    assert found["names"], f"{module} has an empty __all__"
    assert found["missing"] == []
    assert set(found["names"]) <= set(found["dir"])
    assert len(set(found["names"])) == len(found["names"])


def test_functions_named_as_their_module_stay_functions():
    # the registry imports reduce.steps.fit_ramp and .unchop by name: the import system then
    # sets the package's attribute to the module (lazy_loader >= 0.6 keeps the function)
    code = ("import spherex_reduce.reduce.steps.fit_ramp.step, spherex_reduce.reduce.steps.unchop\n"
            "from spherex_reduce.reduce.steps import fit_ramp, unchop\n"
            "from spherex_reduce import fit_ramp as top\n"
            "print(type(fit_ramp).__name__, type(unchop).__name__, type(top).__name__)")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=300)
    assert done.returncode == 0, done.stderr
    assert done.stdout.split() == ["function", "function", "function"]


#: (package, public function, the subpackage of that name's module that holds it, another
#: module of the subpackage, imported first): the function stays the package's attribute
SHADOWED = [
    ("spherex_reduce.analysis", "forecast", "spherex_reduce.analysis.forecast.engine",
     "spherex_reduce.analysis.forecast.fft"),
    ("spherex_reduce.reduce.steps", "fit_ramp", "spherex_reduce.reduce.steps.fit_ramp.step",
     "spherex_reduce.reduce.steps.fit_ramp.segments"),
]

SHADOW_CHECK = """\
import importlib, sys
package, name, home, first = sys.argv[1:]
importlib.import_module(first)  # sets the package's attribute to the subpackage
pkg = sys.modules[package]
function = getattr(importlib.import_module(home), name)
print(getattr(pkg, name) is function, callable(getattr(pkg, name)),
      importlib.import_module(f"{package}.{name}").__name__ == f"{package}.{name}")
"""


@pytest.mark.parametrize("package, name, home, first", SHADOWED, ids=[s[1] for s in SHADOWED])
def test_a_subpackage_named_as_a_function_does_not_shadow_it(package, name, home, first):
    # analysis/forecast/ beside analysis.forecast, reduce/steps/fit_ramp/ beside fit_ramp:
    # importing any module of the subpackage makes the import system set the package's
    # attribute to the subpackage; lazy_loader (>= 0.6) refuses that for names it attaches
    done = subprocess.run([sys.executable, "-c", SHADOW_CHECK, package, name, home, first],
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    assert done.stdout.split() == ["True", "True", "True"]


def test_a_name_shown_in_two_layers_is_one_object():
    import spherex_reduce
    from spherex_reduce import analysis, noise, simulation
    from spherex_reduce.core import source_mask
    from spherex_reduce.reduce import pipeline

    assert simulation.expected_slope_variance is noise.expected_slope_variance
    assert spherex_reduce.expected_slope_variance is noise.expected_slope_variance
    assert simulation.NoiseComponent is noise.NoiseComponent
    assert analysis.source_mask is source_mask.source_mask
    assert analysis.as_pipeline is pipeline.as_pipeline
    assert spherex_reduce.dq is sys.modules["spherex_reduce.core.dq"]


def test_an_unknown_name_is_an_attribute_error():
    import spherex_reduce
    from spherex_reduce import analysis, simulation

    for mod in (spherex_reduce, analysis, simulation):
        with pytest.raises(AttributeError):
            mod.no_such_name  # noqa: B018
