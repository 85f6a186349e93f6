"""Groups of frames averaged into one stored frame: which reads each group is the mean of.

Some electronics do not store every read of the array.  JWST averages
``frames_per_group`` consecutive frames into a *group* and skips
``group_gap`` frames between groups (its ``NFRAMES`` and ``GROUPGAP``);
Roman averages unequal numbers of reads into *resultants* (its read
pattern, e.g. ``[[0], [1, 2], [3, 4, 5, 6]]``).  A
`~spherex_reduce.ReadoutSchedule` states either form; this module turns it
into the reads of every group (0-based frame indices within the exposure,
``frame_time`` apart) and into what a ramp fit needs: each group's mean read
time, the variance of its read noise and the covariance of the charge the
groups accumulate.

Examples
--------
>>> from spherex_reduce.core.readout.groups import pattern_groups, format_groups, parse_groups
>>> [r.tolist() for r in pattern_groups(3, frames_per_group=2, group_gap=1)]
[[0, 1], [3, 4], [6, 7]]
>>> format_groups([[0], [1, 2], [3, 4, 5, 6], [8]])
'0;1-2;3-6;8'
>>> parse_groups("0;1-2;3-6;8")
[[0], [1, 2], [3, 4, 5, 6], [8]]
"""

import itertools

import numpy as np

from ..limits import check_size

__all__ = ["check_groups", "describe_groups", "format_groups", "group_covariance", "group_means",
           "parse_groups", "pattern_groups", "resolve_groups"]

#: Reads a schedule can count (its sample times stay exact in float64).
_MAX_READ = 2**53
#: Most reads a ``groups`` text may list (ranges expanded): 2**24, 128 MB of indices.
MAX_LISTED_READS = 1 << 24


def resolve_groups(ngroups, frames_per_group=1, group_gap=0, groups=None):
    """A schedule's grouping checked: ``(groups, reads)``.

    ``groups`` is the explicit list as a tuple of tuples (or None) and
    ``reads`` the read-only int64 reads of every group, or None when every
    read is stored (``frames_per_group`` 1, ``group_gap`` 0, no ``groups``).

    Raises
    ------
    ValueError
        Both ways given, or a bad list (`check_groups`).
    ResourceError
        A pattern whose reads would not fit in memory.
    """
    pattern = (frames_per_group, group_gap)
    if groups is not None:
        if pattern != (1, 0):
            raise ValueError(f"give groups or frames_per_group/group_gap, not both "
                             f"(frames_per_group={frames_per_group}, group_gap={group_gap})")
        groups = check_groups(groups, ngroups)
        reads = [np.array(r, dtype=np.int64) for r in groups]
    elif pattern != (1, 0):
        check_size(8.0 * ngroups * (frames_per_group + 1),
                   f"the reads of {ngroups} groups of {frames_per_group} frames")
        reads = pattern_groups(ngroups, *pattern)
    else:
        return None, None
    for r in reads:
        r.setflags(write=False)
    return groups, tuple(reads)


def pattern_groups(ngroups, frames_per_group, group_gap):
    """The reads of ``ngroups`` groups of ``frames_per_group`` frames, ``group_gap`` apart.

    Group ``g`` averages frames ``g (n + gap)`` to ``g (n + gap) + n - 1``
    (``n = frames_per_group``), as JWST groups do.

    Returns
    -------
    list of `numpy.ndarray`
        The read indices (int64) of each group.
    """
    step = frames_per_group + group_gap
    reads = step * np.arange(ngroups, dtype=np.int64)[:, None] + np.arange(frames_per_group)
    return list(reads)


def check_groups(groups, ngroups):
    """An explicit list of the reads of each group, checked: a tuple of tuples of int.

    Parameters
    ----------
    groups : sequence of sequence of int
        0-based frame indices, strictly increasing within and across groups
        (groups do not overlap and are in time order); frames between groups
        are read and discarded.
    ngroups : int
        The number of stored frames (``nframes``) the list must describe.

    Raises
    ------
    ValueError
        One line naming the first entry at fault.

    Examples
    --------
    >>> from spherex_reduce.core.readout.groups import check_groups
    >>> check_groups([[0], [1, 2]], 2)
    ((0,), (1, 2))
    >>> check_groups([[0, 1], [1, 2]], 2)
    Traceback (most recent call last):
    ...
    ValueError: groups[1] starts at read 1, not after read 1 that ends groups[0]: ...
    """
    if isinstance(groups, (str, bytes)) or not _is_sequence(groups) or not len(groups):
        raise ValueError("groups must be a non-empty list of lists of read indices "
                         f"(0-based frames), got {groups!r}")
    out = []
    last = -1
    for g, reads in enumerate(groups):
        if isinstance(reads, (str, bytes)) or not _is_sequence(reads) or not len(reads):
            raise ValueError(f"groups[{g}] must be a non-empty list of read indices, "
                             f"got {reads!r}")
        for k, r in enumerate(reads):
            if isinstance(r, (bool, np.bool_)) or not isinstance(r, (int, np.integer)) or r < 0:
                raise ValueError(f"groups[{g}][{k}] must be a read index, an integer >= 0, "
                                 f"got {r!r}")
            if r >= _MAX_READ:
                raise ValueError(f"groups[{g}][{k}] = {r} is out of range: an exposure has "
                                 "fewer than 2**53 frames")
        reads = tuple(int(r) for r in reads)
        if any(b <= a for a, b in itertools.pairwise(reads)):
            raise ValueError(f"groups[{g}] must list strictly increasing reads, "
                             f"got {list(reads)}")
        if reads[0] <= last:
            raise ValueError(f"groups[{g}] starts at read {reads[0]}, not after read {last} "
                             f"that ends groups[{g - 1}]: groups must not overlap and must be "
                             "in time order")
        last = reads[-1]
        out.append(reads)
    if len(out) != ngroups:
        raise ValueError(f"groups lists {len(out)} groups but nframes is {ngroups}: nframes "
                         "is the number of groups (stored frames); make them agree")
    return tuple(out)


def _is_sequence(value):
    return isinstance(value, (list, tuple, np.ndarray))


def format_groups(groups):
    """The groups as one line of text: groups by ``;``, runs of reads as ``a-b``.

    The form of the ``GRPREADS`` keyword and of ``--groups``; `parse_groups`
    reads it back.
    """
    parts = []
    for reads in groups:
        runs, start = [], reads[0]
        for a, b in zip(reads, [*reads[1:], None], strict=True):
            if b != a + 1:
                runs.append(f"{start}" if start == a else f"{start}-{a}")
                start = b
        parts.append(",".join(runs))
    return ";".join(parts)


def describe_groups(frames_per_group, group_gap, groups):
    """The grouping for a schedule's summary: ``''`` when every read is stored.

    Examples
    --------
    >>> from spherex_reduce.core.readout.groups import describe_groups
    >>> describe_groups(4, 2, None), describe_groups(1, 0, [[0], [1, 2]])
    (', 4 frames per group, 2 apart', ', groups 0;1-2')
    """
    if groups is not None:
        return f", groups {format_groups(groups)}"
    if (frames_per_group, group_gap) == (1, 0):
        return ""
    return f", {frames_per_group} frames per group, {group_gap} apart"


def parse_groups(text):
    """The groups of a `format_groups` text as a list of lists of int (not yet checked).

    Raises
    ------
    ValueError
        Text that is not groups of integers and ranges ``a-b`` (``a <= b``).
    """
    groups, total = [], 0
    for part in str(text).split(";"):
        reads = []
        for item in part.split(","):
            first, dash, end = item.strip().partition("-")
            try:
                a = int(first)
                b = int(end) if dash else a
            except ValueError:
                raise ValueError(f"groups: expected reads like '0;1-2;3,5' (groups separated by "
                                 f"';', ranges a-b), got {text!r}") from None
            if b < a:
                raise ValueError(f"groups: the range {item.strip()!r} in {text!r} runs backwards")
            total += b - a + 1
            if total > MAX_LISTED_READS:  # before a list of them is made
                raise ValueError(f"groups: more than {MAX_LISTED_READS} reads listed in "
                                 f"{_short(text)}")
            reads.extend(range(a, b + 1))
        groups.append(reads)
    return groups


def _short(text, limit=60):
    """``text`` quoted, cut to ``limit`` characters for a message."""
    text = str(text)
    return repr(text if len(text) <= limit else text[:limit] + "...")


def _flat(groups):
    """Every read (float64), the group of each and the group sizes."""
    sizes = np.array([len(reads) for reads in groups])
    flat = np.concatenate([np.asarray(reads, np.float64) for reads in groups])
    return flat, np.repeat(np.arange(sizes.size), sizes), sizes


def group_means(groups):
    """The mean read index of every group, ``(ngroups,)`` float64 (frames).

    Examples
    --------
    >>> from spherex_reduce.core.readout.groups import group_means
    >>> group_means([[0], [1, 2], [3, 4, 5, 6]]).tolist()
    [0.0, 1.5, 4.5]
    """
    flat, which, sizes = _flat(groups)
    return np.bincount(which, flat, sizes.size) / sizes


def group_covariance(groups):
    """Covariance of the charge of groups ``g`` and ``h`` per unit rate, in frames.

    The mean over reads ``a`` of ``g`` and ``b`` of ``h`` of
    ``min(a, b) - first``, ``first`` being the first read of the first group:
    multiplied by the frame time and by a rate, the covariance of the groups'
    Poisson charge counted from the first read.  Groups do not overlap and
    are in time order, so off the diagonal it is the earlier group's mean
    read; on it, for the sorted reads ``t_i`` (``i < n``) of one group,
    ``sum_i t_i (2 (n - i) - 1) / n**2``.

    Returns
    -------
    `numpy.ndarray`
        ``(ngroups, ngroups)`` float64, in frames.

    Examples
    --------
    >>> from spherex_reduce.core.readout.groups import group_covariance
    >>> group_covariance([[0], [2, 3]]).tolist()
    [[0.0, 0.0], [0.0, 2.25]]
    """
    flat, which, sizes = _flat(groups)
    flat = flat - flat[0]
    means = np.bincount(which, flat, sizes.size) / sizes
    cov = np.minimum.outer(means, means)
    n = sizes[which]
    i = np.arange(flat.size) - np.repeat(np.cumsum(sizes) - sizes, sizes)  # place in its group
    cov[np.diag_indices(sizes.size)] = np.bincount(which, flat * (2 * (n - i) - 1),
                                                   sizes.size) / sizes**2
    return cov
