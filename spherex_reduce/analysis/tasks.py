"""The records a sweep's and a comparison's tasks carry to a worker and bring back.

A sweep sends one `SweepTask` per cell (`~spherex_reduce.analysis.sweep.run_cell`)
and gets a `CellResult` or a `CellFailure`; a comparison sends one
`RealizationTask` per realisation
(`~spherex_reduce.analysis.compare.run_realization`) and gets a
`RealizationResult`, one `PipelineRow` per pipeline, or a `RealizationFailure`.
They are plain values (picklable: dask sends them between processes); the
tables are built from their attributes.
"""

from dataclasses import dataclass

__all__ = ["CellFailure", "CellResult", "PipelineRow", "RealizationFailure",
           "RealizationResult", "RealizationTask", "SweepTask"]


@dataclass(frozen=True)
class SweepTask:
    """One cell of a sweep, as `~spherex_reduce.analysis.sweep.Sweep.task` describes it.

    Attributes
    ----------
    cell : dict
        ``{grid values..., 'pipeline', 'realization'}``.
    scene : dict
        The sweep's scene with the cell's readout values.
    pipeline : str or dict
        Shipped name, path or inline config.
    entropy : int or sequence of int
        Entropy of the cell's `~numpy.random.SeedSequence`.
    mode : str
        ``slopes`` or ``ramps``.
    measure : dict
        The ``measure:`` mapping (`~spherex_reduce.analysis.case.SpectrumMeasure`).
    """

    cell: dict
    scene: dict
    pipeline: object
    entropy: object
    mode: str
    measure: dict


@dataclass(frozen=True)
class CellResult:
    """The measure of one cell: a row of the sweep's table (columns in
    `~spherex_reduce.analysis.sweep.SWEEP_COLUMNS`).

    ``seed`` is the cell's entropy as JSON text; ``unit`` that of the band power
    (``k`` and ``power`` are the binned P(k), arrays).
    """

    cell: dict
    seed: str
    band_power: float
    band_power_err: float
    unit: str
    std: float
    masked_fraction: float
    k: object
    power: object
    seconds: float


@dataclass(frozen=True)
class CellFailure:
    """A cell that failed: its values, the error in one line and, when the cell's own
    code raised, the traceback."""

    cell: dict
    error: str
    traceback: str | None = None

    def as_dict(self):
        """``{"cell", "error"}`` (and ``"traceback"`` if any): how a sweep reports it."""
        out = {"cell": self.cell, "error": self.error}
        if self.traceback is not None:
            out["traceback"] = self.traceback
        return out


@dataclass(frozen=True)
class RealizationTask:
    """One realisation of a comparison, as `~spherex_reduce.analysis.compare.Comparison.task`
    describes it.

    Attributes
    ----------
    realization : int
    scene : dict
        The comparison's scene, without its seed.
    pipelines : dict
        Label -> shipped name, path or inline config.
    entropy, sky_entropy : int or sequence of int
        Entropies of the noise's and the sky's `~numpy.random.SeedSequence`.
    rms, index : float
        The sky's rms (e/s) and spectral index.
    measure : dict
        The ``measure:`` mapping.
    """

    realization: int
    scene: dict
    pipelines: dict
    entropy: object
    sky_entropy: object
    rms: float
    index: float
    measure: dict


@dataclass(frozen=True)
class PipelineRow:
    """One pipeline's measure of one realisation: a row of the comparison's table.

    The values of `~spherex_reduce.analysis.sky.measure_against_sky` and
    ``seconds``, those of the reduction alone.
    """

    pipeline: str
    realization: int
    noise_band_power: float
    noise_band_power_err: float
    unit: str
    k: object
    power: object
    transfer: object
    sky_transfer: float
    masked_fraction: float
    seconds: float


@dataclass(frozen=True)
class RealizationResult:
    """Every pipeline's `PipelineRow` of one realisation, its seeds (JSON text) and the
    warnings it raised or logged, one line each."""

    realization: int
    rows: tuple
    seed: str
    sky_seed: str
    warnings: tuple = ()


@dataclass(frozen=True)
class RealizationFailure:
    """A realisation that failed: the error in one line, the traceback when its own code
    raised."""

    realization: int
    error: str
    traceback: str | None = None
