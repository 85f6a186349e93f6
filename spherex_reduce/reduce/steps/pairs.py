"""Pair differences of two exposures taken the same way (paper §5.3, measured darks)."""

import numpy as np
from astropy.nddata import StdDevUncertainty

from ...core.errors import ConfigError, SpherexReduceError
from ...core.parameters import Parameter
from ..hookspecs import hookimpl
from ..noise_effect import NoiseEffect
from ..step import Step

__all__ = ["PairDifferenceStep", "pair_difference"]


def _differences(a, b):
    """Why two exposures cannot be differenced, or an empty list."""
    problems = []
    if a.schedule != b.schedule:
        da = {**a.schedule.geometry.to_dict(), **a.schedule.to_dict()}
        db = {**b.schedule.geometry.to_dict(), **b.schedule.to_dict()}
        diff = [f"{k}: {da[k]!r} vs {db.get(k)!r}" for k in da if da[k] != db.get(k)]
        problems.append("readout parameters differ (" + (", ".join(diff) or "frame time")
                        + ")")
    if a.order != b.order:
        problems.append(f"row order differs ({a.order} vs {b.order})")
    if a.shape != b.shape:
        problems.append(f"shapes differ ({a.shape} vs {b.shape}): reduce both to the same stage")
    if (a.unit or None) != (b.unit or None):
        problems.append(f"units differ ({a.unit} vs {b.unit})")
    return problems


def pair_difference(a, b):
    """Difference of two exposures scaled by 1/√2 (paper §5.3, measured darks).

    Subtracting a second exposure taken the same way removes the dark current
    and fixed pattern; the factor ``1/sqrt(2)`` keeps the noise per exposure.

    Parameters
    ----------
    a, b : `~spherex_reduce.Exposure`
        Same readout parameters, row order, shape (both ramps or both images)
        and unit.

    Returns
    -------
    `~spherex_reduce.Exposure`
        ``(a - b) / sqrt(2)`` with uncertainty ``sqrt(ua**2 + ub**2) / sqrt(2)``,
        the union of the masks, phantom values and reference reads differenced
        the same way (when both have them) and ``a``'s header (``PAIRDIFF``).

    Raises
    ------
    SpherexReduceError
        The readout parameters, order, shape or unit differ (all reasons are
        listed).

    Examples
    --------
    >>> import numpy as np
    >>> from spherex_reduce import DetectorGeometry, Exposure, ReadoutSchedule
    >>> from spherex_reduce import pair_difference
    >>> s = ReadoutSchedule(DetectorGeometry(4, 4, 1, ref_border=1), skip=1, ref_mode="none",
    ...                     phantom_reads=0, nframes=1)
    >>> a = Exposure.from_arrays(np.full((4, 4), 3.0), s)
    >>> b = Exposure.from_arrays(np.full((4, 4), 1.0), s)
    >>> bool(pair_difference(a, b).data.data[0, 0] == 2 / np.sqrt(2))
    True
    """
    return PairDifferenceStep().apply_to(a, {}, inputs={"other": b})


def _pair_difference(a, b):
    """`pair_difference` itself (its step's run)."""
    problems = _differences(a, b)
    if problems:
        raise SpherexReduceError("pair_difference: cannot difference these exposures: "
                                 + "; ".join(problems))
    root2 = np.sqrt(2.0)
    da, db = np.asarray(a.data.data), np.asarray(b.data.data)
    dtype = np.result_type(da.dtype, db.dtype, np.float32)
    data = ((da - db) / dtype.type(root2)).astype(dtype, copy=False)
    ua, ub = a.data.uncertainty, b.data.uncertainty
    unc = None
    if ua is not None or ub is not None:
        va = 0.0 if ua is None else ua.represent_as(StdDevUncertainty).array ** 2
        vb = 0.0 if ub is None else ub.represent_as(StdDevUncertainty).array ** 2
        unc = (np.sqrt(va + vb) / root2).astype(dtype)
    if a.dq is None and b.dq is None:
        flags = None
    else:
        flags = (np.zeros(data.shape, np.uint32) if a.dq is None else a.dq) | (
            np.zeros(data.shape, np.uint32) if b.dq is None else b.dq)
    phantom = None
    if a.phantom is not None and b.phantom is not None:
        phantom = (a.phantom - b.phantom) / root2
    reference = None
    ra, rb = a.reference, b.reference
    if ra is not None and rb is not None and np.shape(ra.data) == np.shape(rb.data):
        rph = None
        if ra.phantom is not None and rb.phantom is not None:
            rph = (ra.phantom - rb.phantom) / root2
        reference = ra.replace(data=(np.asarray(ra.data) - rb.data) / root2, phantom=rph)
    header = a.header.copy()
    header["PAIRDIFF"] = (True, "pair difference (a - b)/sqrt(2)")
    return a.replace(data=data, uncertainty=unc, dq=flags, phantom=phantom,
                     reference=reference, tables=_provenance_only(a.tables), header=header)


def _provenance_only(tables):
    """The tables a difference keeps: the provenance of ``a`` (the others, e.g. ``REFOFFS``,
    describe one exposure of the pair, not the difference)."""
    return {name: t for name, t in tables.items() if name == "PROVENANCE"}


class PairDifferenceStep(Step):
    """``(this - other) / sqrt(2)`` with a second exposure (`~spherex_reduce.pair_difference`).

    ``other`` names the second exposure's FITS file, a declared input: run
    alone, the step reads it as it is; in a `~spherex_reduce.Pipeline` with
    ``reduce_other`` (default), the pipeline first runs on it the steps it has
    completed so far (those not already complete in that file), streamed like
    the first exposure, so both are at the same stage.
    """

    name, keyword = "pair_difference", "S_PAIRDF"
    inputs = ("other",)
    parameters = (
        Parameter("other", None, (str, type(None)), "FITS file of the second exposure"),
        Parameter("reduce_other", True, (bool,), "run the preceding steps on it first"),
    )
    #: two exposures reduced alike, independent noise: the spectrum of one (the identity);
    #: an other exposure not reduced the same way is not; a detector's fixed pattern cancels
    noise_effect = NoiseEffect("identity", linear={"reduce_other": (True,)},
                               cancels_fixed=True)

    def run(self, exposure, other, reduce_other):
        if other is None:
            raise ConfigError(
                "pair_difference.other: give the second exposure's FITS file (copy the "
                "config with `spherex-reduce show-config NAME > my.yaml` and set it)")
        return _pair_difference(exposure, other)

    def reduces_input(self, name, params):
        """Whether a pipeline brings input ``name`` to this step's stage first."""
        return bool(params["reduce_other"])

    def input_card(self, name, label):
        return ("PAIROTHR", label[-68:], "second exposure of the pair")


@hookimpl
def register_steps():
    return [PairDifferenceStep]
