"""Noise components of the readout electronics (paper §3, Table 2) as data.

Every component has a one-sided power spectral density (PSD) in e²/Hz of the
timestream of one readout channel sampled at the pixel rate ``fs``::

    p(f) = alpha + beta / f + gamma / f**exponent,     0 < f <= fs / 2

a *scope* (``channel``: an independent stream per channel; ``common``: one
stream for all channels), a *visibility* (which samples see it: ``pixels``,
``phantom`` or ``both``) and ``acn`` (independent even/odd-column
realisations, paper §3.2).  A sampled stream with this PSD has the
per-sample white variance ``alpha * fs / 2``.
"""

import functools
import importlib.resources
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
from astropy import units as u
from astropy.table import Table

from ..core.errors import ConfigError
from .structure_functions import inv_f_structure, power_structure, white_structure

__all__ = [
    "BUILTIN_TABLES",
    "NoiseComponent",
    "load_noise_table",
    "noise_components",
]

SCOPES = ("channel", "common")
VISIBILITIES = ("pixels", "phantom", "both")
#: Built-in noise tables (name -> file in ``spherex_reduce/data``).
BUILTIN_TABLES = {"spherex-table2": "spherex-table2.ecsv"}
_PSD_UNIT = u.electron**2 / u.Hz
#: Largest noise table file accepted, in bytes.
MAX_TABLE_BYTES = 1 << 20
#: Largest PSD coefficient accepted (in the units of each term): a white level of 1e12 e²/Hz
#: is a standard deviation of 2e8 e per 100 kHz sample, far beyond any detector, while the
#: simulated numbers stay finite in float32.
MAX_COEFFICIENT = 1e12


@dataclass(frozen=True)
class NoiseComponent:
    """One noise source: its PSD coefficients, scope, visibility and ACN.

    Parameters
    ----------
    name : str
        Identifier (``video8``, ``roic``, ...).
    alpha : float
        White level, e²/Hz.
    beta : float
        ``1/f`` coefficient, e².
    gamma : float
        ``1/f**exponent`` coefficient, e² Hz^(exponent - 1).
    exponent : float
        Power of the ``gamma`` term, in (0, 3) and not 1 (the paper: 1.3).
    scope : {'channel', 'common'}
        ``channel``: an independent stream per readout channel;
        ``common``: one stream shared by all channels.
    visibility : {'pixels', 'phantom', 'both'}
        Which samples see the component: the array pixels, the phantom
        (Video8 reference) samples, or both.
    acn : bool
        Split into two independent realisations, one for even and one for
        odd columns (alternating column noise).  Channel scope only.

    Examples
    --------
    >>> from spherex_reduce.simulation import NoiseComponent
    >>> c = NoiseComponent("white", alpha=2e-3)
    >>> float(c.psd(10.0))                        # e^2/Hz
    0.002
    >>> c.white_variance(1e5)                     # e^2 per sample
    100.0
    """

    name: str
    alpha: float = 0.0
    beta: float = 0.0
    gamma: float = 0.0
    exponent: float = 1.3
    scope: str = "channel"
    visibility: str = "pixels"
    acn: bool = False

    def __post_init__(self):
        for key in ("alpha", "beta", "gamma"):
            value = float(getattr(self, key))
            if not np.isfinite(value) or not 0 <= value <= MAX_COEFFICIENT:
                raise ValueError(f"component {self.name!r}: {key} must be >= 0 and <= "
                                 f"{MAX_COEFFICIENT:g}, got {value}")
            object.__setattr__(self, key, value)
        e = float(self.exponent)
        if not (0 < e < 3) or e == 1:
            raise ValueError(f"component {self.name!r}: exponent must be in (0, 3) and not 1 "
                             f"(use beta for 1/f), got {e}")
        object.__setattr__(self, "exponent", e)
        if self.scope not in SCOPES:
            raise ValueError(f"component {self.name!r}: scope must be one of {SCOPES}")
        if self.visibility not in VISIBILITIES:
            raise ValueError(f"component {self.name!r}: visibility must be one of "
                             f"{VISIBILITIES}")
        if self.acn and self.scope != "channel":
            raise ValueError(f"component {self.name!r}: acn applies to channel-scope "
                             "components only (the common bias terms are not split)")
        object.__setattr__(self, "acn", bool(self.acn))

    # -- properties -----------------------------------------------------------
    @property
    def is_zero(self):
        """True if all coefficients are zero (the component costs nothing)."""
        return self.alpha == 0 and self.beta == 0 and self.gamma == 0

    @property
    def seen_by_pixels(self):
        return self.visibility in ("pixels", "both")

    @property
    def seen_by_phantom(self):
        return self.visibility in ("phantom", "both")

    def to_dict(self):
        """Plain values (the inline YAML form)."""
        return asdict(self)

    def replace(self, **changes):
        """A copy with some fields changed."""
        return NoiseComponent(**{**self.to_dict(), **changes})

    # -- spectra --------------------------------------------------------------
    def psd(self, f):
        """One-sided PSD at frequencies ``f`` (Hz, > 0), in e²/Hz (plain floats)."""
        f = np.asarray(f, dtype=float)
        with np.errstate(divide="ignore"):
            out = self.alpha + self.beta / f + self.gamma * f ** (-self.exponent)
        return out

    def white_variance(self, fs):
        """Per-sample variance (e²) of the white part at sample rate ``fs`` (Hz)."""
        return self.alpha * fs / 2

    def structure_function(self, lag, fs):
        """``D(lag) = E[(x(t + lag) - x(t))^2]`` of the sampled stream, e².

        ``D(tau) = 2 * integral_0^{fs/2} p(f) (1 - cos(2 pi f tau)) df`` with
        ``tau = lag / fs``; finite for all three terms.  Closed forms: the
        white term gives ``alpha * fs`` for integer lags > 0, the ``1/f``
        term ``2 beta Cin(pi lag)`` and the power-law term uses the
        asymptotic or numerical cosine integral.

        Parameters
        ----------
        lag : array_like
            Lags in samples (integers for the white term to be exact).
        fs : float
            Sample rate, Hz.
        """
        lag = np.abs(np.asarray(lag, dtype=float))
        out = np.zeros_like(lag)
        if self.alpha:
            out += self.alpha * white_structure(lag, fs)
        if self.beta:
            out += self.beta * inv_f_structure(lag)
        if self.gamma:
            out += self.gamma * power_structure(lag, fs, self.exponent)
        return out


# -- tables ---------------------------------------------------------------------
def _table_path(source):
    if str(source) in BUILTIN_TABLES:
        return importlib.resources.files("spherex_reduce") / "data" / BUILTIN_TABLES[source]
    path = Path(source)
    if not path.is_file():
        raise ConfigError(
            f"noise.table: {source!r} is neither a built-in table "
            f"({', '.join(BUILTIN_TABLES)}) nor an existing file"
        )
    return path


@functools.cache
def _builtin_table(name):
    with importlib.resources.as_file(_table_path(name)) as p:
        return Table.read(p, format="ascii.ecsv")


def load_noise_table(source="spherex-table2"):
    """The noise table as an astropy `~astropy.table.Table` with units and provenance.

    Parameters
    ----------
    source : str or path
        A built-in table name (``'spherex-table2'``, the paper's Table 2) or
        an ECSV file with the columns ``name alpha beta gamma exponent scope
        visibility acn``.

    Examples
    --------
    >>> from spherex_reduce.simulation import load_noise_table
    >>> t = load_noise_table()
    >>> [str(n) for n in t["name"]]
    ['video8', 'roic', 'bias_correlated', 'bias_phantom_only', 'bias_pixels_only']
    >>> t["alpha"].unit
    Unit("electron2 / Hz")
    """
    if str(source) in BUILTIN_TABLES:  # parsed once per process
        return _builtin_table(str(source)).copy()
    path = _table_path(source)
    with importlib.resources.as_file(path) as p:
        if p.stat().st_size > MAX_TABLE_BYTES:
            raise ConfigError(f"noise.table: {source} is larger than {MAX_TABLE_BYTES >> 20} MiB, "
                              "the limit for a noise table")
        try:
            table = Table.read(p, format="ascii.ecsv")
        except Exception as exc:  # astropy raises many kinds for a file that is not ECSV
            first = str(exc).strip().splitlines()[0] if str(exc).strip() else ""
            raise ConfigError(f"noise.table: {source} is not a readable ECSV table "
                              f"({type(exc).__name__}: {first})") from None
    missing = [c for c in ("name", "alpha", "beta", "gamma") if c not in table.colnames]
    if missing:
        raise ConfigError(f"noise.table: {source} lacks column(s) {missing}")
    return table


def noise_components(source="spherex-table2"):
    """Components of a noise table as ``{name: NoiseComponent}`` (in table order).

    Examples
    --------
    >>> from spherex_reduce.simulation import noise_components
    >>> comps = noise_components()
    >>> comps["roic"].visibility, comps["bias_correlated"].scope
    ('pixels', 'common')
    """
    if str(source) in BUILTIN_TABLES:  # parsed once per process (components are frozen)
        return dict(_builtin_components(str(source)))
    return _components_of(load_noise_table(source))


@functools.cache
def _builtin_components(name):
    return _components_of(load_noise_table(name))


def _components_of(table):
    """``{name: NoiseComponent}`` of the rows of a noise table."""
    out = {}
    for i, row in enumerate(table):
        kw = {"name": str(row["name"])}
        where = f"noise.table[{i}] ({kw['name']})"
        try:
            exponent = float(row["exponent"]) if "exponent" in table.colnames else 1.3
            if not (0 < exponent < 3) or exponent == 1:
                raise ValueError(f"exponent must be in (0, 3) and not 1, got {exponent}")
            kw["exponent"] = exponent
            for key, unit in (("alpha", _PSD_UNIT), ("beta", u.electron**2),
                              ("gamma", u.electron**2 * u.Hz ** (exponent - 1))):
                kw[key] = _value(table, row, key, unit)
        except (TypeError, ValueError, u.UnitsError) as exc:
            raise ConfigError(f"{where}: {exc}") from None
        for key in ("scope", "visibility"):
            if key in table.colnames:
                kw[key] = str(row[key])
        if "acn" in table.colnames:
            kw["acn"] = bool(row["acn"])
        try:
            out[kw["name"]] = NoiseComponent(**kw)
        except ValueError as exc:
            raise ConfigError(f"{where}: {exc}") from exc
    return out


def _value(table, row, key, unit):
    col = table[key]
    if col.unit is None:
        return float(row[key])
    return float((row[key] * col.unit).to_value(unit))
