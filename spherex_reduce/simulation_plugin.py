"""Built-in plugin registering the noise simulator (`spherex_reduce.simulation`)."""

from .hookspecs import hookimpl


@hookimpl
def register_simulators():
    from .simulation import SpherexSimulator

    return [SpherexSimulator]
