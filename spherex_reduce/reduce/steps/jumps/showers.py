"""Large events (snowballs, showers): a halo around a core of jumps, over several reads.

A cosmic ray steps one pixel, or a few by interpixel capacitance.  A snowball
(a large deposit, often saturating its core) or a shower steps a patch of
adjacent pixels at one read, and its halo of lower charge, around the patch
and arriving over the next reads, lies below the threshold of each pixel's
search: left unflagged, it biases those pixels' slopes.  JWST's users expect
the halo flagged (``expand_large_events``: a region enclosing the jumps,
expanded by a factor, also in the following groups).  Here a core is a set of
at least ``area`` jumps at one read, connected on the stored image (8
neighbours), and its halo every pixel within ``expand`` times the core's
radius of its centre, at the read of the core and the ``reads`` after it.
"""

import numpy as np

__all__ = ["large_event_halos"]

#: the 8 neighbours of a pixel on the stored image
_NEIGHBOURS = tuple((dr, dc) for dr in (-1, 0, 1) for dc in (-1, 0, 1) if dr or dc)


def _cores(frames, rows, cols, ncols):
    """A label per jump: jumps at the same read on touching pixels share one."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    n = frames.size
    key = (frames.astype(np.int64) * (rows.max() + 3) + rows + 1) * (ncols + 2) + cols + 1
    order = np.argsort(key, kind="stable")
    sorted_key = key[order]
    src, dst = [], []
    for dr, dc in _NEIGHBOURS:
        other = key + dr * (ncols + 2) + dc  # same read (rows and columns padded by 1)
        pos = np.minimum(np.searchsorted(sorted_key, other), n - 1)
        touch = sorted_key[pos] == other
        src.append(np.flatnonzero(touch))
        dst.append(order[pos[touch]])
    src, dst = np.concatenate(src), np.concatenate(dst)
    graph = coo_matrix((np.ones(src.size, np.int8), (src, dst)), shape=(n, n))
    return connected_components(graph, directed=False)[1]


def large_event_halos(frames, rows, cols, shape, nframes, *, area=5, expand=2.0, reads=1):
    """The reads in the halos of large events: ``(frames, rows, cols)`` on the stored image.

    Parameters
    ----------
    frames, rows, cols : array_like of int
        The read and stored pixel (row, column) of every jump, and of every
        pixel that saturated at that read (a snowball's core often does).
    shape : tuple of int
        ``(nrows, ncols)`` of the stored image.
    nframes : int
        Reads of the ramps (the halo stops at the last).
    area : int
        Fewest jumps, touching on the stored image at one read, that make a
        large event's core (pixels).
    expand : float
        The halo's radius over the core's: the core's radius is that of the
        disc of its area or its farthest jump from its centre, whichever is
        larger (pixels).
    reads : int
        Reads after the core's also flagged in the halo (its charge arrives
        over them).

    Returns
    -------
    frames, rows, cols : `numpy.ndarray`
        Every read in a halo, each once (the cores' own jumps among them).

    Examples
    --------
    >>> import numpy as np
    >>> from spherex_reduce.reduce.steps.jumps.showers import large_event_halos
    >>> r, c = np.divmod(np.arange(9), 3)            # a 3 x 3 core at read 4, at (11, 11)
    >>> f, rr, cc = large_event_halos(np.full(9, 4), r + 10, c + 10, (32, 32), 20)
    >>> sorted(set(f.tolist())), int(rr.min()), int(rr.max())   # radius 2 * 1.7 px
    ([4, 5], 8, 14)
    >>> large_event_halos([4], [10], [10], (32, 32), 20)[0].size  # one jump is no event
    0
    """
    nrows, ncols = shape
    frames, rows, cols = (np.asarray(a, np.int64).ravel() for a in (frames, rows, cols))
    # each read of a pixel once (a row read twice in a frame gives its jumps twice)
    flat = np.unique((frames * nrows + rows) * ncols + cols)
    frames, rest = np.divmod(flat, nrows * ncols)
    rows, cols = np.divmod(rest, ncols)
    empty = np.zeros(0, np.int64)
    if frames.size < area:
        return empty, empty, empty
    labels = _cores(frames, rows, cols, ncols)
    sizes = np.bincount(labels)
    big = np.flatnonzero(sizes >= area)
    if not big.size:
        return empty, empty, empty
    hit = []
    for lab in big:
        at = labels == lab
        r0, c0 = rows[at].mean(), cols[at].mean()
        far = np.sqrt(((rows[at] - r0) ** 2 + (cols[at] - c0) ** 2).max())
        radius = expand * max(np.sqrt(sizes[lab] / np.pi), far)
        n = int(np.floor(radius))
        rr, cc = np.mgrid[max(0, int(r0) - n - 1):min(nrows, int(r0) + n + 2),
                          max(0, int(c0) - n - 1):min(ncols, int(c0) + n + 2)]
        inside = (rr - r0) ** 2 + (cc - c0) ** 2 <= radius * radius
        rr, cc = rr[inside], cc[inside]
        first = int(frames[at][0])
        for f in range(first, min(nframes, first + reads + 1)):
            hit.append((f * nrows + rr) * ncols + cc)
    flat = np.unique(np.concatenate(hit))
    f, rest = np.divmod(flat, nrows * ncols)
    r, c = np.divmod(rest, ncols)
    return f, r, c
