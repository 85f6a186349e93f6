"""Built-in plugin registering the noise simulator (`spherex_reduce.simulation`)."""

from ..reduce.hookspecs import hookimpl


@hookimpl
def register_simulators():
    from . import SpherexSimulator

    return [SpherexSimulator]
