"""Families of read orders of the active rows: skips, nested skips, low-discrepancy orders.

Each function returns a permutation ``p`` of ``0 ... n - 1``: ``p[t]`` is the
active row (counted from the first active row) read in slot ``t``.  They are
the starting points of `~spherex_reduce.analysis.design.search`; an order
becomes a schedule through `explicit_order`, which places the reference reads
as a ``'distributed'`` (or ``'repeated'``) schedule of the same ``r`` does.

Examples
--------
>>> from spherex_reduce.analysis.design.row_orders import nested_order, radical_inverse_order
>>> nested_order(8, (2, 2)).tolist()            # bit reversal of 0 ... 7
[0, 4, 2, 6, 1, 5, 3, 7]
>>> radical_inverse_order(8, 2).tolist()
[0, 4, 2, 6, 1, 5, 3, 7]
"""

import numpy as np

from ...core.readout.schedule import ReadoutSchedule, chopped_order

__all__ = ["FAMILIES", "explicit_order", "family_orders", "golden_order", "max_skip",
           "nested_order", "radical_inverse_order"]

#: The families `family_orders` builds.
FAMILIES = ("skip", "nested", "radical_inverse", "golden")

_GOLDEN = (np.sqrt(5.0) - 1) / 2


def nested_order(n, skips):
    """Nested skips: rows sorted by ``i mod s1``, then ``(i // s1) mod s2``, ... then ``i``.

    ``(S,)`` is the paper's skip ``S`` (`~spherex_reduce.core.readout.schedule.chopped_order`); each
    further skip chops the rows of every pass again.

    Examples
    --------
    >>> from spherex_reduce.analysis.design.row_orders import nested_order
    >>> nested_order(12, (3, 2)).tolist()
    [0, 6, 3, 9, 1, 7, 4, 10, 2, 8, 5, 11]
    """
    i = np.arange(n)
    keys, div = [], 1
    for s in skips:
        keys.append((i // div) % s)
        div *= s
    keys.append(i // div)
    return np.lexsort(keys[::-1])


def radical_inverse_order(n, base):
    """Rows in the order of their radical inverse in ``base`` (base 2: bit reversal; a van der
    Corput sequence: every stretch of slots reads rows spread evenly over the array).

    Examples
    --------
    >>> from spherex_reduce.analysis.design.row_orders import radical_inverse_order
    >>> radical_inverse_order(9, 3).tolist()
    [0, 3, 6, 1, 4, 7, 2, 5, 8]
    """
    i = np.arange(n)
    value = np.zeros(n)
    scale = 1.0 / base
    rest = i.copy()
    while rest.any():
        value += (rest % base) * scale
        rest //= base
        scale /= base
    return np.argsort(value, kind="stable")


def golden_order(n, step=_GOLDEN):
    """Rows in the order of ``frac(i * step)`` (a Kronecker sequence; default the golden
    ratio, the most evenly spread).

    Examples
    --------
    >>> from spherex_reduce.analysis.design.row_orders import golden_order
    >>> golden_order(5).tolist()
    [0, 2, 4, 1, 3]
    """
    return np.argsort(np.mod(np.arange(n) * step, 1.0), kind="stable")


def max_skip(n):
    """The largest skip ``S`` whose order of ``n`` active rows is its own: ``S >= n`` reads
    them in physical order, as ``S = 1`` does.

    Examples
    --------
    >>> from spherex_reduce.analysis.design.row_orders import max_skip
    >>> max_skip(24), max_skip(1)
    (23, 1)
    """
    return max(n - 1, 1)


def family_orders(n, families=FAMILIES, skips=range(1, 65)):
    """``[(family, label, permutation)]``: the orders of ``n`` active rows of each family.

    ``skip``: every ``S`` of ``skips`` up to `max_skip`; ``nested``: ``(S, s2)`` for those ``S``
    that are multiples of 4 and ``s2`` of 2, 3, 4, 8; ``radical_inverse``: bases 2, 3, 5;
    ``golden``: the golden ratio and its square.  Duplicate permutations are dropped.

    Examples
    --------
    >>> from spherex_reduce.analysis.design.row_orders import family_orders
    >>> [label for _, label, _ in family_orders(16, ["skip", "golden"], skips=[1, 4])]
    ['S=1', 'S=4', 'golden', 'golden^2']
    """
    skips = [int(s) for s in skips if 1 <= s <= max_skip(n)]
    out = []
    for family in families:
        if family == "skip":
            out += [("skip", f"S={s}", chopped_order(n, s)) for s in skips]
        elif family == "nested":
            out += [("nested", f"S={s}x{t}", nested_order(n, (s, t)))
                    for s in skips if s % 4 == 0 for t in (2, 3, 4, 8) if s * t < n]
        elif family == "radical_inverse":
            out += [("radical_inverse", f"base {b}", radical_inverse_order(n, b))
                    for b in (2, 3, 5)]
        elif family == "golden":
            out += [("golden", "golden", golden_order(n)),
                    ("golden", "golden^2", golden_order(n, _GOLDEN**2))]
        else:
            raise ValueError(f"unknown family {family!r}; valid: {', '.join(FAMILIES)}")
    seen, unique = set(), []
    for family, label, perm in out:
        key = np.asarray(perm, np.int64).tobytes()
        if key not in seen:
            seen.add(key)
            unique.append((family, label, np.asarray(perm, dtype=int)))
    return unique


def explicit_order(geometry, permutation, ref_reads, ref_mode="distributed"):
    """The explicit read order (physical rows, reference reads included) of a permutation of
    the active rows, with the ``ref_reads`` reference reads placed as the schedule places them
    for ``ref_mode`` (``'distributed'``: evenly through the frame; ``'repeated'``: at its
    ends).

    Examples
    --------
    >>> from spherex_reduce import DetectorGeometry
    >>> from spherex_reduce.analysis.design.row_orders import explicit_order
    >>> g = DetectorGeometry(8, 4, 1, ref_border={"top": 1, "bottom": 1})
    >>> explicit_order(g, [0, 2, 4, 1, 3, 5], 2)
    [0, 1, 3, 5, 7, 2, 4, 6]
    """
    s = ReadoutSchedule(geometry, skip=1, ref_reads=int(ref_reads), ref_mode=ref_mode,
                        phantom_reads=0, nframes=2)
    rows = np.array(s.rows)
    rows[~s.is_reference] = geometry.active_rows[np.asarray(permutation, dtype=int)]
    return rows.tolist()
