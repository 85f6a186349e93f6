"""Some rows of every frame: what step kernels correct and the ramp fit consumes.

A `Block` is the unit of work of the executor (`spherex_reduce.reduce.executor`):
the pixels of a few rows of every frame of a ramp (or of a 2-D image), with
their phantom values, flags and uncertainties when the input has them.  Step
kernels (`spherex_reduce.reduce.step.Kernel`) take a block and return one; a step run
on a whole exposure is its kernel applied to one block holding every row.
"""

import dataclasses
from dataclasses import dataclass

import numpy as np

__all__ = ["ARRAYS", "Block", "Context", "frames_contiguous"]

#: The arrays a block may hold besides its index.
ARRAYS = frozenset({"data", "phantom", "dq", "uncertainty"})


def frames_contiguous(values):
    """Whether the rows of each frame of ``values`` ``(frames, rows, columns)`` are one
    C-contiguous run (a C-ordered array, or its rows ``[:, lo:hi]``).

    Examples
    --------
    >>> import numpy as np
    >>> from spherex_reduce.core.block import frames_contiguous
    >>> a = np.zeros((3, 8, 4))
    >>> frames_contiguous(a[:, 2:5]), frames_contiguous(a[:, :, 1:3])
    (True, False)
    """
    if values.ndim < 2:
        return values.flags.c_contiguous
    return values[0].flags.c_contiguous if values.shape[0] else True


@dataclass(frozen=True, eq=False)
class Block:
    """Rows of every frame, in readout or physical order.

    Parameters
    ----------
    data : `numpy.ndarray`
        Pixels ``(frames, n, ncols)``; a 2-D image is one frame.
    index : `numpy.ndarray` of int
        Position of each of the ``n`` rows along the exposure's row axis:
        read index within a frame in readout order, physical row in physical
        order.
    order : {'readout', 'physical'}
    phantom : `numpy.ndarray` or None
        Phantom values ``(frames, n, nchannels)`` (same unit as ``data``).
    dq : `numpy.ndarray` of uint32 or None
        Flags, same shape as ``data``.
    uncertainty : `numpy.ndarray` or None
        Standard deviations, same shape as ``data``.
    read_phantom : `numpy.ndarray` or None
        On the side block only: the phantom values of every read of every
        frame ``(frames, n_reads, nchannels)``, in readout order whatever
        ``order`` is (for a strategy that estimates from them); None once the
        phantom is subtracted, and on the blocks of rows.
    owned : frozenset of str, or bool
        Names of the arrays (``'data'``, ``'phantom'``, ``'dq'``,
        ``'uncertainty'``) that belong to the executor (read from a file into
        its buffers, or made by a kernel): a kernel may write into those, and
        only those.  Arrays of a caller's `~spherex_reduce.Exposure` are
        never written.  ``True`` means all four, ``False`` none.
    """

    data: np.ndarray
    index: np.ndarray
    order: str
    phantom: np.ndarray | None = None
    dq: np.ndarray | None = None
    uncertainty: np.ndarray | None = None
    owned: frozenset = frozenset()
    read_phantom: np.ndarray | None = None

    def __post_init__(self):
        if isinstance(self.owned, bool):
            object.__setattr__(self, "owned", ARRAYS if self.owned else frozenset())

    def replace(self, **changes):
        """A copy with some fields changed."""
        return dataclasses.replace(self, **changes)

    @property
    def nframes(self):
        return self.data.shape[0]

    def writable(self, dtype):
        """``data`` as an array of ``dtype`` that may be written, each frame's rows
        C-contiguous: itself if owned, of that type and layout (e.g. rows of an exposure
        the executor made), else a C-contiguous copy (a caller's arrays are never
        written)."""
        dtype = np.dtype(dtype)
        d = self.data
        if ("data" in self.owned and d.dtype == dtype and d.flags.writeable
                and frames_contiguous(d)):
            return d
        return np.array(d, dtype=dtype, order="C")

    def with_flags(self, flags, at=None):
        """A copy whose ``dq`` has ``flags`` or-ed in: broadcast to the data's shape, or
        only at the elements ``at`` (an index, e.g. ``(frames, rows, columns)`` arrays)."""
        if self.dq is None:
            dq = np.zeros(self.data.shape, np.uint32)
        elif "dq" in self.owned and self.dq.flags.writeable:
            dq = self.dq
        else:
            dq = self.dq.copy()
        if at is None:
            dq |= flags
        else:
            dq[at] |= flags
        return self.replace(dq=dq, owned=self.owned | {"dq"})


@dataclass(frozen=True, eq=False)
class Context:
    """What a kernel is built for: the input's schedule, row order, shape and unit.

    Parameters
    ----------
    schedule : `~spherex_reduce.ReadoutSchedule`
    order : {'readout', 'physical'}
        Row order of the blocks the kernel receives.
    ramp : bool
        Frames up the ramp (else a 2-D image, one frame).
    unit : `astropy.units.Unit` or None
        Unit of the pixels.
    header : `astropy.io.fits.Header`
        The input's header (read only).
    has_phantom : bool
        Whether the blocks carry phantom values (`Block.phantom`).
    threads : int or None
        Threads a kernel's ``prepare`` may use (None: the executor's default).
    """

    schedule: object
    order: str
    ramp: bool
    unit: object = None
    header: object = None
    has_phantom: bool = False
    threads: int | None = None

    def replace(self, **changes):
        """A copy with some fields changed."""
        return dataclasses.replace(self, **changes)

    @property
    def geometry(self):
        return self.schedule.geometry
