"""The forecast of a sweep: the exact expected band power and P(k) of every grid point.

A sweep's Monte Carlo estimates, at each grid point and pipeline, the band
power and P(k) of the reduced slope image; `~spherex_reduce.analysis.forecast`
gives their expectation with no random numbers (0.7-0.8 s per point warm at
the paper's full size through ``spherex-default`` on 2 idle cores, 3.4-4.0 s
with the machine loaded).  `SweepForecast` computes it once per point (the scene of the point,
its pipeline and the sweep's ``measure``), and adds it to a sweep's
results as the columns ``band_power_forecast`` and ``power_forecast`` (the
same bins as ``power``, empty ones NaN) of every row of that point.  A sweep
of no realisations (``realizations: 0``) has no Monte Carlo rows: its table
has one row per point, with ``k`` and the forecast columns only.

The forecast is of the slopes route; the ramps route reduced with uniform
``fit_ramp`` has the same expectation, so a ramps sweep is forecast the same way.
"""

import json

import numpy as np
from astropy import units as u
from astropy.table import Table

from ...core.errors import ConfigError, SpherexReduceError
from ..case import SpectrumMeasure
from ..table_cells import plain_value
from .engine import forecast, forecast_measure
from .steps import linear_steps

__all__ = ["FORECAST_COLUMNS", "SweepForecast"]

_UNIT = (u.electron / u.s) ** 2 * u.pix**2
#: The columns the forecast adds to a sweep's results (also a forecast-only table's ``k``).
FORECAST_COLUMNS = {
    "band_power_forecast": "expected band power of the point (forecast, no random numbers)",
    "power_forecast": "expected P(k) of the point in each bin of power (forecast)",
}


class SweepForecast:
    """The forecast of each point (grid values and pipeline) of a sweep, computed once.

    Parameters
    ----------
    sweep : `~spherex_reduce.analysis.sweep.Sweep`

    Raises
    ------
    ConfigError
        A pipeline with a step the forecast does not propagate, or a measure
        that masks sources (not linear); checked here, before any cell runs.

    Examples
    --------
    >>> from spherex_reduce.analysis.sweep import load_sweep
    >>> from spherex_reduce.analysis.forecast.sweep import SweepForecast
    >>> sw = load_sweep({"scene": {"geometry": {"nrows": 64, "ncols": 64, "nchannels": 4},
    ...                            "readout": {"nframes": 8}},
    ...                  "pipeline": "unchop", "grid": {"skip": [1, 8]}, "realizations": 0,
    ...                  "measure": {"bins": 4}})
    >>> t = SweepForecast(sw).points()
    >>> t["skip"].tolist(), t["band_power_forecast"].unit
    ([1, 8], Unit("electron2 pix2 / s2"))
    """

    def __init__(self, sweep):
        self.sweep = sweep
        label = sweep.source
        for name, config in sweep.pipeline_configs.items():
            try:
                linear_steps(config)
            except ConfigError as exc:
                raise ConfigError(f"{label}: pipeline {name}: {exc}") from None
        try:
            forecast_measure(sweep.measure)
        except ConfigError as exc:
            raise ConfigError(f"{label}: {exc}") from None
        self._done = {}
        #: points whose forecast failed: ``{"cell": point, "error": message}``
        self.failed = []

    def key(self, row):
        """The key of a point: its grid values and pipeline (a result row or a cell)."""
        return tuple(json.dumps(plain_value(row[k])) for k in (*self.sweep.keys, "pipeline"))

    def of(self, row):
        """``(band power, P(k) on every bin, k)`` of the point of ``row``: floats and arrays in
        (e/s)² pix² and rad/pixel (NaN if its forecast failed, recorded in `failed`)."""
        key = self.key(row)
        if key not in self._done:
            point = {k: plain_value(row[k]) for k in (*self.sweep.keys, "pipeline")}
            task = self.sweep.task({**point, "realization": 0})
            m = SpectrumMeasure(**task.measure)
            try:
                t = forecast(task.scene, task.pipeline, m)
            except SpherexReduceError as exc:
                self.failed.append({"cell": point, "error": f"forecast: {exc}"})
                nan = np.full(m.edges((2, 2)).size - 1, np.nan)
                self._done[key] = (np.nan, nan, nan)
            else:
                k, power = m.every_bin(t)
                band = t.meta["band_power"]
                self._done[key] = (np.nan if band is None else band, power, k)
        return self._done[key]

    def add_columns(self, table):
        """A copy of a sweep's results with the forecast columns of each row's point."""
        out = table.copy(copy_data=False)
        out.remove_columns([c for c in FORECAST_COLUMNS if c in out.colnames])
        values = [self.of(row) for row in out]
        nbins = max((len(v[1]) for v in values), default=0)
        out["band_power_forecast"] = np.array([v[0] for v in values], float) * _UNIT
        out["power_forecast"] = (np.array([v[1] for v in values], float).reshape(-1, nbins)
                                 * _UNIT)
        for name, text in FORECAST_COLUMNS.items():
            out[name].description = text
        return out

    def points(self):
        """The forecast-only table: one row per grid point and pipeline, in the sweep's order,
        with ``k`` and the forecast columns."""
        sw = self.sweep
        rows = sw.points()
        cols = {k: [r[k] for r in rows] for k in (*sw.keys, "pipeline")}
        table = self.add_columns(Table(cols) if rows else Table())
        nbins = table["power_forecast"].shape[1] if rows else 0
        table["k"] = np.array([self.of(r)[2] for r in rows], float).reshape(-1, nbins) * (
            u.rad / u.pix)
        table["k"].description = "mean |k| of each bin of the point's P(k)"
        return table

