"""The step screen (`StepModel.screen`) against brute-force weighted least squares."""

import numpy as np
import pytest

from spherex_reduce.reduce.steps.fit_ramp.step_model import StepModel


def _rss(x, y, w):
    """Weighted residual sum of squares of ``y`` (n, m) on the design ``x`` (n, p)."""
    sw = np.sqrt(w)[:, None]
    coef, *_ = np.linalg.lstsq(x * sw, y * sw, rcond=None)
    r = y - x @ coef
    return (w[:, None] * r * r).sum(axis=0)


@pytest.mark.parametrize("reads", ["single", "groups", "unequal"])
@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_screen_is_the_largest_drop_of_chi2_a_step_gives(reads, dtype):
    """``max_k R_k**2 / q_k`` is the largest drop of the weighted chi2 of a line that a step
    at one read gives, and the RSS the line's own (numpy lstsq on each design): for single
    reads, equal groups of 4 frames (weights 4) and groups of 1, 2, 4, 8 frames read at
    their mean times."""
    rng = np.random.default_rng(3)
    if reads == "single":
        t, f = np.arange(20) * 1.5, np.ones(20)
    elif reads == "groups":
        t, f = (np.arange(10) * 6 + 2.25) * 1.0, np.full(10, 0.25)
    else:
        sizes = np.array([1, 2, 4, 8, 8, 4, 2, 1])
        starts = np.concatenate([[0], np.cumsum(sizes)[:-1]])
        t, f = (starts + (sizes - 1) / 2) * 1.5, 1.0 / sizes
    n, m = t.size, 500
    y = 3.0 + 0.2 * t[:, None] + rng.standard_normal((n, m)) * np.sqrt(f)[:, None]
    y[n // 2:, ::3] += rng.uniform(-8, 8, (m + 2) // 3)  # steps in a third of them
    w = 1.0 / f
    line = np.column_stack([np.ones(n), t - t[0]])
    base = _rss(line, y, w)
    drops = [base - _rss(np.column_stack([line, np.arange(n) >= k]), y, w)
             for k in range(1, n)]
    model = StepModel(t, f)
    rel = (y - y[0]).astype(dtype)
    best, rss = model.screen(rel, True)
    assert best.dtype == dtype and rss.dtype == dtype
    tol = 1e-9 if dtype == np.float64 else 2e-4
    np.testing.assert_allclose(best, np.max(drops, axis=0), rtol=tol, atol=tol * base.mean())
    np.testing.assert_allclose(rss, base, rtol=tol, atol=tol * base.mean())
    # a work buffer wider than the ramps gives the same numbers and no RSS unless asked
    work = np.full((n, m + 7), np.nan, dtype)
    again, none = model.screen(rel, False, work)
    np.testing.assert_array_equal(again, best)
    assert none is None
