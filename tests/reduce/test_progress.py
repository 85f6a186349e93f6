"""The expected duration of long runs, and their progress bar only on a terminal."""

import io
import time

import pytest

from spherex_reduce.reduce.progress import Progress, format_duration, run_tasks


@pytest.mark.parametrize(("parallel", "expected"), [
    (1, "about 21 s for 10 cells (2.0 s each)"),  # 3 s until the first, then 9 x 2 s
    (2, "about 11 s for 10 cells (2.0 s each, 2 at a time)"),  # then 4 rounds of 2 s
    (None, "about 21 s for 10 cells (2.0 s each, one at a time)"),
])
def test_the_estimate_is_the_first_task_then_the_rounds_left(parallel, expected):
    out = io.StringIO()
    with Progress(10, "cell", True, parallel, stream=out) as p:
        p.start = time.perf_counter() - 3.0
        p.done(2.0)
        p.done(2.0)
    assert out.getvalue() == expected + "\n"  # no bar: the stream is not a terminal


def test_quiet_prints_nothing_and_one_task_needs_no_estimate():
    out = io.StringIO()
    with Progress(10, "cell", False, stream=out) as p:
        p.done(1.0)
    with Progress(1, "cell", True, stream=out) as p:
        p.done(1.0)
    assert out.getvalue() == "" and p.expected is not None


def test_a_terminal_gets_a_bar():
    class Terminal(io.StringIO):
        def isatty(self):
            return True

    out = Terminal()
    with Progress(3, "realisation", True, stream=io.StringIO(), bar_stream=out) as p:
        for _ in range(3):
            p.done(0.01)
    assert "realisations: 100%" in out.getvalue()


def test_serial_tasks_run_in_order_and_are_counted():
    got = []
    p = run_tasks(lambda x: x * x, [1, 2, 3], "serial", None, lambda t, r: got.append((t, r)),
                  None, noun="square", progress=False)
    assert got == [(1, 1), (2, 4), (3, 9)] and p.count == 3


@pytest.mark.parametrize(("seconds", "text"), [(0.04, "0.0 s"), (9.96, "10.0 s"), (59.6, "1 min"),
                                               (3600, "1 h"), (3661, "1 h 1 min"),
                                               (90000, "1 d 1 h"), (float("inf"), "forever")])
def test_durations_read_as_people_write_them(seconds, text):
    assert format_duration(seconds) == text


def test_a_warm_up_task_does_not_time_the_run_and_skipped_tasks_never_do():
    """warmup=1: the first task (one-off work) is left out; a task skipped at once is
    counted but never times the run: 3 s so far plus the 7 tasks left at 2 s each."""
    out = io.StringIO()
    with Progress(10, "timing", True, stream=out, warmup=1) as p:
        p.skip()
        p.done(30.0)  # the warm-up: a table the later tasks reuse
        assert out.getvalue() == ""
        p.start = time.perf_counter() - 3.0
        p.done(2.0)
    assert out.getvalue() == "about 17 s for 10 timings (2.0 s each)\n"
    assert p.count == 3


def test_a_run_that_may_stop_early_says_up_to():
    out = io.StringIO()
    with Progress(20, "pair", True, stream=out, until="stopping once it is known") as p:
        p.start = time.perf_counter() - 2.0
        p.done(2.0)
    assert out.getvalue() == ("up to about 40 s for up to 20 pairs (2.0 s each; "
                              "stopping once it is known)\n")
