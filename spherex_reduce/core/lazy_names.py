"""Public names attached lazily, also names shown from a layer below (SPEC 1).

`lazy_loader.attach` attaches a package's own modules only; `attach` also
shows names that live in a lower layer's module (``analysis`` shows
``as_pipeline`` of ``reduce``, ``simulation`` the noise model's names), each
imported on first use.
"""

import importlib

import lazy_loader as lazy

__all__ = ["attach"]


def attach(package, submod_attrs, below):
    """``(__getattr__, __dir__, __all__)`` for ``package``'s ``__init__``.

    Parameters
    ----------
    package : str
        The package's ``__name__``.
    submod_attrs : dict
        Its own modules and the names each holds (as for `lazy_loader.attach`).
    below : dict
        Names shown from other modules: ``{name: absolute module name}``.

    Examples
    --------
    >>> from spherex_reduce.core.lazy_names import attach
    >>> below = {"plural": "spherex_reduce.core._text"}
    >>> getattr_, dir_, all_ = attach("spherex_reduce.core", {}, below)
    >>> all_, getattr_("plural")(2, "file")
    (['plural'], '2 files')
    """
    own_getattr, _, own_all = lazy.attach(package, submod_attrs=submod_attrs)
    names = sorted([*own_all, *below])

    def __getattr__(name):
        if name in below:
            return getattr(importlib.import_module(below[name]), name)
        return own_getattr(name)

    def __dir__():
        return names.copy()

    return __getattr__, __dir__, names
