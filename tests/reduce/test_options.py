"""`in_threads`: work in threads, results in order, reads in the calling thread."""

import threading

import pytest

from spherex_reduce.reduce.options import in_threads


@pytest.mark.parametrize("nthreads", [1, 2, 3])
def test_results_in_order_and_reads_in_the_calling_thread(nthreads):
    here, read_in = threading.get_ident(), []

    def read(i):
        read_in.append(threading.get_ident())
        return i * 10

    got = list(in_threads(range(7), lambda i, v: (i, v), nthreads, read=read))
    assert got == [(i, i * 10) for i in range(7)]
    assert read_in == [here] * 7
    assert list(in_threads(range(7), lambda i: -i, nthreads)) == [-i for i in range(7)]


def test_at_most_one_read_ahead_of_the_threads():
    """With reads, no more than ``nthreads + 1`` items are read and not yet given back."""
    given, ahead = [], []

    def read(i):
        ahead.append(i - len(given))
        return i

    for value in in_threads(range(10), lambda i, v: v, 2, read=read):
        given.append(value)
    assert max(ahead) <= 2  # items read but not given back, besides this one


@pytest.mark.parametrize("where", ["work", "caller"])
def test_a_failure_stops_the_reads_and_is_raised(where):
    """Band 0 fails (in its work, or in the caller given its result): no band beyond the
    two in the threads and the one read ahead is read, and the error is raised."""
    read = []

    def work(i, value):
        if i == 0 and where == "work":
            raise RuntimeError("band 0")
        return value

    with pytest.raises(RuntimeError, match="band 0"):
        for _ in in_threads(range(50), work, 2, read=lambda i: read.append(i) or i):
            raise RuntimeError("band 0")
    assert read == [0, 1, 2]


def test_without_reads_every_item_is_queued_and_a_failure_is_raised():
    with pytest.raises(RuntimeError, match="item 3"):
        list(in_threads(range(20), _fail_at_3, 2))


def _fail_at_3(i):
    if i == 3:
        raise RuntimeError("item 3")
    return i
