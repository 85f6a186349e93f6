"""Exceptions raised for bad input.

Every error a user can fix derives from :class:`SpherexReduceError`, which is
also a :class:`ValueError`, so callers may catch either.  The command line turns
these into a one-line message and exit code 2.
"""

__all__ = [
    "ConfigError",
    "FormatError",
    "PluginError",
    "ResourceError",
    "SpherexReduceError",
    "StepSkipped",
    "UnknownNameError",
]


class SpherexReduceError(ValueError):
    """Base class of errors caused by input the user can correct."""


class ConfigError(SpherexReduceError):
    """A YAML configuration (pipeline, scene, sweep) is invalid.

    The message names the YAML path of the offending entry, e.g.
    ``steps[2].correct_reference.clip``, and lists the valid choices.
    """


class FormatError(SpherexReduceError):
    """A FITS file does not follow the format, or disagrees with itself."""


class PluginError(SpherexReduceError):
    """A plugin failed to load or register; the message names the plugin."""


class UnknownNameError(ConfigError, KeyError):
    """A step, strategy or simulator name that no plugin registers.

    Also a `KeyError` (it is a failed lookup by name); its message lists the
    valid names and is printed without quotes.
    """

    def __str__(self):
        return str(self.args[0]) if self.args else ""


class ResourceError(SpherexReduceError):
    """The work asked for needs more memory or time than is reasonable here.

    Raised before allocating, e.g. for a header claiming 1e15 rows, with the
    size needed and the size available in the message.
    """


class StepSkipped(Exception):
    """Raised by a step to tell the pipeline it did nothing, and why.

    The pipeline records ``SKIPPED`` in the step's status keyword and the
    reason as ``HISTORY``; the exposure passes on unchanged.
    """

    def __init__(self, reason):
        super().__init__(reason)
        self.reason = reason
