"""`RecentlyUsed`: the caches a readout search shares (lag tables, light functionals, column
phases), checked against a list kept by hand and under threads."""

import threading

import numpy as np

from spherex_reduce.core.recently_used import RecentlyUsed


def test_lets_go_of_the_least_recently_used_by_count_and_by_size():
    made = []

    def make(key, nbytes=1):
        made.append(key)
        return np.zeros(nbytes, np.uint8)

    kept = RecentlyUsed(2)
    for key in ("a", "b", "a", "c", "b", "a"):  # by hand: a b | a b | b a -> a c | c b | b a
        kept.get(key, lambda key=key: make(key))
    assert made == ["a", "b", "c", "b", "a"]
    made.clear()
    by_bytes = RecentlyUsed(10, size=lambda v: v.nbytes)
    for key, n in (("x", 4), ("y", 4), ("z", 4), ("y", 4), ("big", 20), ("big", 20)):
        by_bytes.get(key, lambda key=key, n=n: make(key, n))
    # x, y fit (8); z pushes x out; y kept; big alone is over the limit but kept as the newest
    assert made == ["x", "y", "z", "big"]
    assert by_bytes.get("y", lambda: make("y", 4)) is not None and made[-1] == "y"


def test_threads_share_one_cache_without_errors():
    """Forecasts called from threads: every get returns the value of its key, none raises
    (an OrderedDict changed while another thread summed it raised RuntimeError)."""
    kept = RecentlyUsed(64, size=lambda v: v.nbytes)
    errors = []

    def work(seed):
        rng = np.random.default_rng(seed)
        try:
            for key in rng.integers(0, 40, 3000):
                value = kept.get(int(key), lambda key=key: np.full(int(key) % 7 + 1, key))
                assert value[0] == key
        except Exception as exc:  # collected for the assertion below
            errors.append(exc)

    threads = [threading.Thread(target=work, args=(s,)) for s in range(6)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert errors == []
