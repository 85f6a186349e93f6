"""Provenance of every step run: status keyword, parameters, HISTORY and a ``PROVENANCE`` row.

`record_step` is called by `~spherex_reduce.Step.__call__` and by the
`~spherex_reduce.Pipeline` for each step, whether the step ran alone, in a
pipeline, or streamed with others over a file.  The header keeps what a person
reads (the status keyword ``S_*``, short ``HIERARCH SXR STEP PARAM`` cards and
a HISTORY line); the ``PROVENANCE`` table keeps the structured record, one row
per step run: step, status, parameters (JSON), inputs (JSON), versions (JSON),
elapsed seconds and route (``spherex_reduce.io.layout.PROVENANCE_COLUMNS``).
"""

import functools
import importlib.metadata
import json
import logging

from astropy.table import Table

from .._version import __version__
from ..io.header_text import header_text
from ..io.layout import PROVENANCE_COLUMNS

__all__ = ["provenance_rows", "record_step"]

log = logging.getLogger("spherex_reduce")


def _described(value):
    """How a parameter value that JSON cannot hold is recorded (an array: its shape)."""
    if hasattr(value, "shape") and hasattr(value, "dtype"):
        return f"array {'x'.join(map(str, value.shape))} of {value.dtype}"
    return str(value)


def _short_value(value):
    if isinstance(value, str):  # e.g. a file name: any text a user gave
        return header_text(value)
    if isinstance(value, (bool, int, float)):
        return value
    return json.dumps(value, default=_described)


@functools.lru_cache(maxsize=64)
def _version_of(module):
    """``{distribution: version}`` of the distribution providing ``module`` (top package)."""
    top = module.split(".")[0]
    if top == "spherex_reduce":
        return {"spherex-reduce": __version__}
    dists = importlib.metadata.packages_distributions().get(top, [])
    out = {"spherex-reduce": __version__}
    for dist in dists:
        try:
            out[dist] = importlib.metadata.version(dist)
        except importlib.metadata.PackageNotFoundError:  # pragma: no cover
            pass
    return out


def provenance_rows(tables):
    """The rows of a ``PROVENANCE`` table as a list of dicts (empty if there is none)."""
    table = tables.get("PROVENANCE")
    if table is None:
        return []
    names = [c for c in PROVENANCE_COLUMNS if c in table.colnames]
    return [{name: (row[name].item() if hasattr(row[name], "item") else row[name])
             for name in names} for row in table]


def _table(rows):
    cols = {name: [row.get(name, "" if name != "elapsed" else 0.0) for row in rows]
            for name in PROVENANCE_COLUMNS}
    table = Table(cols, dtype=[str, str, str, str, str, float, str])
    table["elapsed"].unit = "s"
    table.meta["comments"] = ["one row per step run, oldest first"]
    return table


def record_step(step, result, params, status, reason, elapsed, route, inputs=None,
                extra_cards=()):
    """``result`` with the provenance of one run of ``step`` (a new exposure).

    Parameters
    ----------
    step : `~spherex_reduce.Step`
    result : `~spherex_reduce.Exposure`
        What the step returned (its input if it was skipped).
    params : dict
        The validated parameters.
    status : {'COMPLETE', 'SKIPPED'}
    reason : str or None
        Why it was skipped.
    elapsed : float
        Seconds spent in the step.
    route : str
        How it ran (``'whole exposure'``, ``'streamed in bands'`` ...).
    inputs : dict, optional
        Other files the step used, by parameter name.
    extra_cards : iterable of ``(keyword, value, comment)``
        Cards from the plugins' ``after_step`` hooks.

    Returns
    -------
    `~spherex_reduce.Exposure`
    """
    cards = [(step.keyword, status, f"{step.name} step")]
    for key, value in params.items():
        value = _short_value(value)
        card = f"HIERARCH SXR {step.name.upper()} {key.upper()}"
        if len(card) + len(repr(value)) + 3 <= 80:  # fits one card; HISTORY and table have all
            cards.append((card, value, None))
    text = json.dumps(params, default=_described, sort_keys=True)
    cards.append(("HISTORY", f"{step.name} {status.lower()} in {elapsed:.3g} s: {text}", None))
    if reason:
        cards.append(("HISTORY", f"{step.name} skipped: {reason}", None))
    log.info("step %s: %s in %.3g s%s", step.name, status.lower(), elapsed,
             f" ({reason})" if reason else "")
    header = result.header.copy()
    for key, value, comment in [*cards, *extra_cards]:
        if key == "HISTORY":
            header.add_history(value)
        elif key == "COMMENT":
            header.add_comment(value)
        else:
            header[key] = (value, comment)
    row = {"step": step.name, "status": status, "parameters": text,
           "inputs": json.dumps(inputs or {}, default=str, sort_keys=True),
           "versions": json.dumps(_version_of(type(step).__module__), sort_keys=True),
           "elapsed": float(elapsed),
           "route": route if status == "COMPLETE" else f"skipped: {reason}"}
    rows = [*provenance_rows(result.tables), row]
    return result.replace(header=header, tables={**result.tables, "PROVENANCE": _table(rows)})
