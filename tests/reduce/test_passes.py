"""plan_pass, the one planner: which steps run together in a pass and which run whole.

The expectations are written by hand from the steps' declared capabilities
(a kernel, a consumer, file inputs, a strategy that needs the whole exposure)
and checked on built-in pipelines, in memory and on a raw file.
"""

import pytest

from spherex_reduce import Pipeline, write
from spherex_reduce.io.examples import example_raw_exposure
from spherex_reduce.io.sources import MemorySource, open_input
from spherex_reduce.reduce.options import RunOptions
from spherex_reduce.reduce.passes import Pass, Whole, plan_pass, run_pass

ONE = RunOptions(threads=1)


def _plan(steps, source, start=0):
    planned = Pipeline({"steps": steps})._planned(ONE)
    return planned, plan_pass(planned, start, source, ONE)


def _names(items):
    return [p.name for p in items]


def test_the_papers_reduction_is_one_pass_into_fit_ramp_then_a_whole_clip():
    steps = ["unchop", "subtract_phantom", "correct_reference", "fit_ramp", "sigma_clip"]
    source = MemorySource(example_raw_exposure())
    planned, plan = _plan(steps, source)
    assert isinstance(plan, Pass) and plan.end == 4 and not plan.skipped
    assert _names(p for p, _ in plan.kernels) == steps[:3]
    assert plan.consumer[0].name == "fit_ramp"
    image, busy, route = run_pass(source, plan, options=ONE)
    assert image.data.data.ndim == 2 and set(busy) == {0, 1, 2, 3}
    assert route.startswith("executor pass of 4 step(s)") and route.endswith("from memory "
                                                                            "on 1 thread(s)")
    rest = plan_pass(planned, 4, MemorySource(image), ONE)
    assert isinstance(rest, Whole) and rest.planned.name == "sigma_clip"


def test_a_step_with_nothing_to_do_is_planned_as_skipped_with_its_reason():
    raw = example_raw_exposure()
    no_phantom = raw.replace(phantom=None, header=raw.header)
    _, plan = _plan(["subtract_phantom", "unchop"], MemorySource(no_phantom))
    assert isinstance(plan, Pass) and list(plan.skipped) == [0]
    assert "phantom" in plan.skipped[0]
    assert _names(p for p, _ in plan.kernels) == ["unchop"]


def test_a_strategy_that_needs_the_exposure_joins_a_pass_but_not_first_over_a_file(tmp_path):
    steps = ["unchop", {"correct_reference": {"strategy": "median"}}, "fit_ramp"]
    raw = example_raw_exposure()
    # after unchop: one pass, the executor stages it (its estimate sees unchopped pixels)
    _, plan = _plan(steps, MemorySource(raw))
    assert _names(p for p, _ in plan.kernels) == ["unchop", "correct_reference"]
    assert plan.consumer[0].name == "fit_ramp" and plan.end == 3
    # first of a pass over an exposure in memory: a kernel of the pass
    _, plan = _plan(steps, MemorySource(raw), start=1)
    assert _names(p for p, _ in plan.kernels) == ["correct_reference"]
    # first of a pass over a file: runs whole, on the exposure read from it
    path = tmp_path / "raw.fits"
    write(raw, path)
    with open_input(path) as inp:
        _, plan = _plan([{"correct_reference": {"strategy": "median"}}], inp.source())
        assert isinstance(plan, Whole)
        # after unchop, from the file: one pass
        _, plan = _plan(steps, inp.source())
        assert isinstance(plan, Pass) and plan.end == 3


@pytest.mark.parametrize("step", [{"pair_difference": {"other": "b.fits"}}, "sigma_clip"])
def test_steps_with_file_inputs_or_without_kernels_run_whole(step):
    _, plan = _plan([step, "unchop"], MemorySource(example_raw_exposure()))
    assert isinstance(plan, Whole) and plan.planned.index == 0


def test_a_pass_stops_before_a_step_with_file_inputs():
    steps = ["unchop", {"subtract_dark": {"dark": "dark.fits"}}]
    _, plan = _plan(steps, MemorySource(example_raw_exposure()))
    assert isinstance(plan, Pass) and plan.end == 1
