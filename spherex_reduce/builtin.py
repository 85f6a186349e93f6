"""The built-in plugin: core steps, and the provenance and timing hooks.

It is registered by `~spherex_reduce.plugins.get_plugin_manager` under the
name ``builtin`` and cannot be blocked.
"""

import json
import logging

from .hookspecs import hookimpl
from .step import Step
from .steps import unchop

log = logging.getLogger("spherex_reduce")


class UnchopStep(Step):
    """Readout order to physical order; reference re-reads kept aside (`unchop`)."""

    name = "unchop"
    keyword = "S_UNCHOP"
    per_frame = True

    def run(self, exposure):
        return unchop(exposure)


@hookimpl
def register_steps():
    return [UnchopStep]


@hookimpl
def before_step(step, exposure, params):
    log.info("step %s: start %s", step.name, json.dumps(params, default=str))


def _short_value(value):
    if isinstance(value, (bool, int, float, str)):
        return value
    return json.dumps(value, default=str)


@hookimpl
def after_step(step, exposure, result, params, status, reason, elapsed):
    """Record status, parameters and timing in the header (provenance)."""
    cards = [(step.keyword, status, f"{step.name} step")]
    for key, value in params.items():
        value = _short_value(value)
        card = f"HIERARCH SXR {step.name.upper()} {key.upper()}"
        if len(card) + len(repr(value)) + 3 <= 80:  # fits one card; HISTORY has all
            cards.append((card, value, None))
    text = json.dumps(params, default=str, sort_keys=True)
    cards.append(("HISTORY", f"{step.name} {status.lower()} in {elapsed:.3g} s: {text}", None))
    if reason:
        cards.append(("HISTORY", f"{step.name} skipped: {reason}", None))
    log.info("step %s: %s in %.3g s%s", step.name, status.lower(), elapsed,
             f" ({reason})" if reason else "")
    return cards
