"""The reduction plugin: phantom, reference, ramp-fit, clipping and dark steps.

Registered by `~spherex_reduce.plugins.get_plugin_manager` under the name
``reduction`` (always present).  Each step is a thin wrapper of the plain
function of the same name in `spherex_reduce.steps`; the reference
strategies ``mean``, ``acn`` and ``median`` are registered here too, so that a
plugin's strategy is chosen the same way (``correct_reference: {strategy: ...}``).
"""

from pathlib import Path

from .errors import ConfigError
from .hookspecs import hookimpl
from .parameters import Parameter
from .step import Step
from .steps.clip import pair_difference, recorded_steps, sigma_clip
from .steps.dark import subtract_dark
from .steps.phantom import subtract_phantom
from .steps.reference import AcnReference, MeanReference, MedianReference

__all__ = [
    "CorrectReferenceStep",
    "PairDifferenceStep",
    "SigmaClipStep",
    "SubtractDarkStep",
    "SubtractPhantomStep",
]

_OPT_NUM = (int, float, type(None))


class SubtractPhantomStep(Step):
    """Subtract each row read's phantom value (`~spherex_reduce.subtract_phantom`)."""

    name, keyword = "subtract_phantom", "S_PHANTM"
    per_frame = True

    def run(self, exposure):
        return subtract_phantom(exposure)


class CorrectReferenceStep(Step):
    """Remove channel offsets with a reference strategy (`~spherex_reduce.correct_reference`)."""

    name, keyword = "correct_reference", "S_REFCOR"
    strategy_kind, default_strategy = "reference", "mean"
    #: every reference strategy corrects ramps frame by frame (one offset per
    #: frame and channel), so the pipeline may stream frames through it
    per_frame = True

    def run(self, exposure, strategy="mean", **params):
        return self.strategy(strategy)()(exposure, **params)

    def streams(self, params):
        # source masking detects sources on the last-minus-first frame: needs the whole ramp
        return not params.get("mask_sources", False)

    def merge_frames(self, exposure, params):
        table = exposure.tables.get("REFOFFS")
        if table is None or "flag" not in table.colnames:
            return exposure
        header = exposure.header.copy()
        header["NNOREF"] = (int((table["flag"] != 0).sum()),
                            "offsets without usable reference pixels")
        return exposure.replace(header=header)


class SigmaClipStep(Step):
    """Iterative clip of hot pixels into the mask (`~spherex_reduce.sigma_clip`)."""

    name, keyword = "sigma_clip", "S_SIGCLP"
    parameters = (
        Parameter("sigma", 5.0, (float,), "threshold (standard deviations)", minimum=0,
                  exclusive_minimum=True),
        Parameter("sigma_lower", None, _OPT_NUM, "lower threshold (default sigma)", minimum=0,
                  exclusive_minimum=True),
        Parameter("sigma_upper", None, _OPT_NUM, "upper threshold (default sigma)", minimum=0,
                  exclusive_minimum=True),
        Parameter("maxiters", None, (int, type(None)), "iterations (null: until converged)",
                  minimum=1, maximum=1000),
        Parameter("cenfunc", "median", (str,), "centre", choices=("median", "mean")),
        Parameter("stdfunc", "std", (str,), "spread", choices=("std", "mad_std")),
    )

    def run(self, exposure, **params):
        return sigma_clip(exposure, **params)


class PairDifferenceStep(Step):
    """``(this - other) / sqrt(2)`` with a second exposure (`~spherex_reduce.pair_difference`).

    ``other`` names the second exposure's FITS file.  With ``reduce_other``
    (default) the steps this pipeline has completed so far (read from the
    provenance in the header) are run on it first, streamed frame by frame
    where they allow, so both are at the same stage; steps already complete
    in that file are not repeated.
    """

    name, keyword = "pair_difference", "S_PAIRDF"
    parameters = (
        Parameter("other", None, (str, type(None)), "FITS file of the second exposure"),
        Parameter("reduce_other", True, (bool,), "run the preceding steps on it first"),
    )

    def run(self, exposure, other=None, reduce_other=True):
        from astropy.io import fits

        from .fits_format import read
        from .pipeline import Pipeline
        from .plugins import Registry

        if not other:
            raise ConfigError(
                "pair_difference.other: give the second exposure's FITS file (copy the "
                "config with `spherex-reduce show-config NAME > my.yaml` and set it)")
        registry = self.registry or Registry()
        todo = []
        if reduce_other:
            if not Path(other).is_file():
                raise FileNotFoundError(f"pair_difference.other: no such file: {other}")
            done = fits.getheader(other)
            todo = [{name: params} for name, status, params in recorded_steps(exposure.header)
                    if status == "COMPLETE"
                    and done.get(registry.step(name).keyword) != "COMPLETE"]
        # a file lacking read-order keywords gets them from the pipeline config too
        sections = dict(self.file_sections)
        if todo:  # the same steps, streamed frame by frame like the first exposure
            b = Pipeline({"steps": todo, **sections}, registry=registry,
                         source="pair_difference.other").run(other)
        else:
            b = read(other, **{k: v for section in sections.values() for k, v in section.items()})
        result = pair_difference(exposure, b)
        header = result.header.copy()
        header["PAIROTHR"] = (str(other)[-68:], "second exposure of the pair")
        return result.replace(header=header)


class SubtractDarkStep(Step):
    """Subtract a master dark image (`~spherex_reduce.subtract_dark`)."""

    name, keyword = "subtract_dark", "S_DARK"
    parameters = (
        Parameter("dark", None, (str, type(None)), "FITS file of the master dark (e.g. from "
                  "spherex-reduce combine)"),
    )

    def run(self, exposure, dark=None):
        if not dark:
            raise ConfigError("subtract_dark.dark: give the master dark's FITS file")
        return subtract_dark(exposure, dark)


@hookimpl
def register_steps():
    return [SubtractPhantomStep, CorrectReferenceStep, SigmaClipStep,
            PairDifferenceStep, SubtractDarkStep]


@hookimpl
def register_strategies():
    return [MeanReference, AcnReference, MedianReference]
