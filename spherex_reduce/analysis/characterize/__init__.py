"""Learn a detector from its darks: `characterize` fits the noise the simulator models.

From raw darks (`~spherex_reduce.analysis.characterize.streams`: per channel,
the light-sensitive pixels' mean, the even-odd difference, the phantom reads
and the reference pixels, in time order, each pixel's straight line across
frames removed), spectra and their fits
(`~spherex_reduce.analysis.characterize.spectra`), and the simulator's
components with uncertainties from the scatter between darks
(`~spherex_reduce.analysis.characterize.model`), as a scene
(`Characterization.scene`) that ``simulate``, ``forecast``, ``sweep`` and
``design-readout`` take as it is.
"""

from .result import Characterization
from .run import characterize, check_model

__all__ = ["Characterization", "characterize", "check_model"]
