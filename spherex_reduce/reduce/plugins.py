"""Plugin manager factory and the registry of steps, strategies and simulators.

Plugins are found through the entry-point group ``spherex_reduce``.  Set the
environment variable ``SPHEREX_REDUCE_BLOCK_PLUGINS`` to a comma-separated
list of entry-point names to keep those plugins from loading (e.g. a broken
one).  Every call of :func:`get_plugin_manager` builds a new manager;
:func:`default_registry` keeps one `Registry` per process (rebuilt when the
installed or blocked plugins change), where a step run without a registry
looks up its strategies.
"""

import functools
import importlib
import importlib.metadata
import inspect
import logging
import os
import sys
import threading
from dataclasses import dataclass

import pluggy

from .._version import __version__
from ..core.errors import PluginError, UnknownNameError
from . import hookspecs
from .step import Simulator, Step, Strategy

__all__ = ["BLOCK_ENV", "ENTRY_POINT_GROUP", "Registry", "blame_plugin", "default_registry",
           "describe_plugin", "get_plugin_manager", "get_registry", "plugin_distributions"]

ENTRY_POINT_GROUP = "spherex_reduce"
#: Modules of the package that are plugins themselves, registered under their
#: short names; they are always present and cannot be blocked.
BUILTIN_PLUGINS = {
    "builtin.unchop": "spherex_reduce.reduce.steps.unchop",
    "builtin.phantom": "spherex_reduce.reduce.steps.phantom",
    "builtin.reference": "spherex_reduce.reduce.steps.reference.step",
    "builtin.jumps": "spherex_reduce.reduce.steps.jumps.step",
    "builtin.fit_ramp": "spherex_reduce.reduce.steps.fit_ramp.step",
    "builtin.clipping": "spherex_reduce.reduce.steps.clipping",
    "builtin.pairs": "spherex_reduce.reduce.steps.pairs",
    "builtin.dark": "spherex_reduce.reduce.steps.dark",
    "simulation": "spherex_reduce.simulation.plugin",
}
BLOCK_ENV = "SPHEREX_REDUCE_BLOCK_PLUGINS"
log = logging.getLogger("spherex_reduce")


def blocked_plugins(block=None):
    """Names blocked by argument and by ``SPHEREX_REDUCE_BLOCK_PLUGINS``."""
    names = set(block or ())
    names |= {n.strip() for n in os.environ.get(BLOCK_ENV, "").split(",") if n.strip()}
    return names


def _distribution(ep):
    """``'name version'`` of the distribution providing entry point ``ep``, or None."""
    dist = getattr(ep, "dist", None)
    if dist is None:
        return None
    try:
        return f"{dist.name} {dist.version}"
    except Exception:  # a damaged METADATA file: the entry-point name will do
        return None


def plugin_distributions():
    """``{plugin name: "distribution version"}`` of the built-in and installed plugins.

    Named as pytest names its plugins: the distribution that installs the entry
    point, and its version; the package's own plugins are the package's.  An
    entry point whose distribution metadata cannot be read is left out.

    Returns
    -------
    dict of str

    Examples
    --------
    >>> from spherex_reduce.reduce.plugins import plugin_distributions
    >>> plugin_distributions()["builtin.unchop"]
    'spherex-reduce ...'
    """
    dists = dict.fromkeys(BUILTIN_PLUGINS, f"spherex-reduce {__version__}")
    for ep in importlib.metadata.entry_points(group=ENTRY_POINT_GROUP):
        dist = _distribution(ep)
        if dist is not None:
            dists.setdefault(ep.name, dist)
    return dists


def describe_plugin(name):
    """The plugin ``name`` for messages: with its distribution and version if installed.

    Parameters
    ----------
    name : str
        The plugin's name in the plugin manager (for installed plugins, the
        entry-point name).

    Returns
    -------
    str
        E.g. ``"plugin 'destripe' (spherex-reduce-destripe 0.1.0)"``, or
        ``"plugin 'builtin.unchop'"`` for a plugin that no installed distribution provides.

    Examples
    --------
    >>> from spherex_reduce.reduce.plugins import describe_plugin
    >>> describe_plugin("builtin.unchop")
    "plugin 'builtin.unchop'"
    """
    if name not in BUILTIN_PLUGINS:
        for ep in importlib.metadata.entry_points(group=ENTRY_POINT_GROUP):
            if ep.name == name:
                dist = _distribution(ep)
                return f"plugin {name!r} ({dist})" if dist else f"plugin {name!r}"
    return f"plugin {name!r}"


def get_plugin_manager(*, entry_points=True, block=None, plugins=()):
    """Build a plugin manager with the built-in plugin and the installed ones.

    Parameters
    ----------
    entry_points : bool
        Load plugins from the ``spherex_reduce`` entry-point group.
    block : iterable of str, optional
        Plugin names not to load, besides those in ``SPHEREX_REDUCE_BLOCK_PLUGINS``.
    plugins : iterable
        Extra plugin objects or modules to register (e.g. in tests).

    Raises
    ------
    PluginError
        A plugin fails to import or to register; the message names it and
        says how to block it.

    Examples
    --------
    >>> from spherex_reduce.reduce.plugins import get_plugin_manager
    >>> pm = get_plugin_manager(entry_points=False)
    >>> pm.has_plugin("builtin.unchop")
    True
    """
    pm = pluggy.PluginManager(hookspecs.PROJECT)
    pm.add_hookspecs(hookspecs)
    for name, module in BUILTIN_PLUGINS.items():
        pm.register(importlib.import_module(module), name=name)
    blocked = blocked_plugins(block)
    if entry_points:
        for ep in importlib.metadata.entry_points(group=ENTRY_POINT_GROUP):
            if ep.name in blocked or pm.has_plugin(ep.name):
                if ep.name in blocked:
                    log.info("plugin %r blocked", ep.name)
                    pm.set_blocked(ep.name)
                continue
            try:
                obj = ep.load()
            except (Exception, SystemExit) as exc:  # sys.exit() in a plugin must not end us
                dist = _distribution(ep)
                raise PluginError(
                    f"plugin {ep.name!r} ({f'{dist}, ' if dist else ''}{ep.value}) failed to "
                    f"load: {type(exc).__name__}: {exc}. Block it with {BLOCK_ENV}={ep.name}"
                ) from exc
            _register(pm, obj, ep.name)
    for obj in plugins:
        _register(pm, obj, None)
    return pm


def _register(pm, obj, name):
    label = name or getattr(obj, "__name__", type(obj).__name__)
    if name is None:  # plugin objects: a readable, unique name for messages
        name, n = label, 1
        while pm.has_plugin(name) or pm.is_blocked(name):
            n += 1
            name = f"{label}-{n}"
    try:
        pm.register(obj, name=name)
        # a hook implementation no spec matches (e.g. register_stepz) is an error, not a no-op
        pm.check_pending()
    except Exception as exc:
        pm.unregister(name=name) if pm.has_plugin(name) else None
        raise PluginError(
            f"plugin {name!r} failed to register: {exc}. Block it with {BLOCK_ENV}={name}"
        ) from exc


@dataclass(frozen=True)
class Registered:
    """Something a plugin registered, and which plugin."""

    obj: type
    plugin: str


class Registry:
    """Steps, strategies and simulators by name, each with the plugin providing it.

    Parameters
    ----------
    plugin_manager : `pluggy.PluginManager`, optional
        Defaults to :func:`get_plugin_manager`.

    Examples
    --------
    >>> from spherex_reduce.reduce.plugins import Registry, get_plugin_manager
    >>> reg = Registry(get_plugin_manager(entry_points=False))
    >>> reg.step("unchop").keyword
    'S_UNCHOP'
    >>> reg.providers["step"]["unchop"]
    'builtin.unchop'
    """

    def __init__(self, plugin_manager=None):
        self.pm = plugin_manager or get_plugin_manager()
        self.steps = self._collect("register_steps", Step, "step")
        strategies = self._collect("register_strategies", Strategy, "strategy", key=_kind_name)
        self.strategies = {}
        for (kind, name), reg in strategies.items():
            self.strategies.setdefault(kind, {})[name] = reg
        for reg in self.steps.values():
            cls = reg.obj
            if cls.strategy_kind and cls.default_strategy is not None and (
                cls.default_strategy not in self.strategies.get(cls.strategy_kind, {})
            ):
                raise PluginError(
                    f"plugin {reg.plugin!r}: step {cls.name!r} defaults to strategy "
                    f"{cls.default_strategy!r} of kind {cls.strategy_kind!r}, which no plugin "
                    "registers"
                )

    def _collect(self, hook, base, what, key=None):
        key = key or (lambda cls: cls.name)
        found = {}
        for impl in getattr(self.pm.hook, hook).get_hookimpls():
            plugin = self.pm.get_name(impl.plugin) or repr(impl.plugin)
            try:
                items = impl.function() or []
            except (Exception, SystemExit) as exc:
                raise PluginError(
                    f"{describe_plugin(plugin)} failed in {hook}: {type(exc).__name__}: {exc}. "
                    f"Block it with {BLOCK_ENV}={plugin}"
                ) from exc
            for cls in items:
                if not (inspect.isclass(cls) and issubclass(cls, base)) or not cls.name:
                    raise PluginError(
                        f"plugin {plugin!r}: {hook} returned {cls!r}, which is not a named "
                        f"{base.__name__} subclass"
                    )
                if what == "step" and not (cls.keyword and len(cls.keyword) <= 8):
                    raise PluginError(
                        f"plugin {plugin!r}: step {cls.name!r} needs a FITS status keyword of "
                        f"1 to 8 characters, got {cls.keyword!r}"
                    )
                k = key(cls)
                if k in found:
                    raise PluginError(
                        f"{what} {k!r} is registered by both plugin {found[k].plugin!r} and "
                        f"plugin {plugin!r}; block one with {BLOCK_ENV}"
                    )
                found[k] = Registered(cls, plugin)
        return found

    @functools.cached_property
    def simulators(self):
        """Registered simulators by name (collected when first asked for: the built-in
        simulator's import is slow, and reducing a file does not need it)."""
        return self._collect("register_simulators", Simulator, "simulator")

    @property
    def providers(self):
        """``{'step': {name: plugin}, 'strategy': {'kind/name': plugin}, 'simulator': ...}``."""
        return {
            "step": {n: r.plugin for n, r in self.steps.items()},
            "strategy": {f"{k}/{n}": r.plugin for k, d in self.strategies.items()
                         for n, r in d.items()},
            "simulator": {n: r.plugin for n, r in self.simulators.items()},
        }

    def step(self, name):
        """The step class called ``name``; `~spherex_reduce.core.errors.UnknownNameError` (a
        `KeyError`) lists the valid names."""
        try:
            return self.steps[name].obj
        except KeyError:
            raise UnknownNameError(
                f"unknown step {name!r}; valid: {', '.join(sorted(self.steps))}") from None

    def strategy(self, kind, name):
        """The strategy class ``name`` of ``kind``; `~spherex_reduce.core.errors.UnknownNameError`
        lists the valid names."""
        options = self.strategies.get(kind, {})
        try:
            return options[name].obj
        except KeyError:
            raise UnknownNameError(
                f"unknown {kind} strategy {name!r}; valid: {', '.join(sorted(options)) or 'none'}"
            ) from None

    def simulator(self, name):
        """The simulator class ``name``; `~spherex_reduce.core.errors.UnknownNameError` lists the
        valid names."""
        try:
            return self.simulators[name].obj
        except KeyError:
            raise UnknownNameError(
                f"unknown simulator {name!r}; valid: {', '.join(sorted(self.simulators)) or 'none'}"
            ) from None


def _kind_name(cls):
    return (cls.kind, cls.name)


def get_registry(**kwargs):
    """Shortcut: ``Registry(get_plugin_manager(**kwargs))``."""
    return Registry(get_plugin_manager(**kwargs))


_DEFAULT = {}  # {(blocked names, what is installed): Registry}: at most one entry
_DEFAULT_LOCK = threading.Lock()


def _installed():
    """The folders of ``sys.path`` with their modification times: installing or removing a
    distribution adds or removes a folder (``*.dist-info``) in one of them."""
    folders = []
    for entry in sys.path:
        try:
            folders.append((entry, os.stat(entry or ".").st_mtime_ns))
        except OSError:
            folders.append((entry, None))
    return tuple(folders)


def default_registry():
    """The `Registry` of the built-in and installed plugins, made once per process.

    What a step run without a registry (`~spherex_reduce.correct_reference`
    called alone) looks its strategies up in, so that an installed plugin's
    strategy works there as in a `~spherex_reduce.Pipeline`.  It is made
    again when the plugins that would load may differ from those it was made
    with: when the names blocked by ``SPHEREX_REDUCE_BLOCK_PLUGINS`` change,
    or a distribution is installed or removed (a folder of ``sys.path`` or its
    contents change).  Asking costs a few file-system ``stat`` calls.

    Returns
    -------
    `Registry`

    Raises
    ------
    PluginError
        An installed plugin fails to load or to register (see `get_plugin_manager`).

    Examples
    --------
    >>> from spherex_reduce.reduce.plugins import default_registry
    >>> default_registry() is default_registry()
    True
    >>> default_registry().providers["strategy"]["reference/mean"]
    'builtin.reference'
    """
    key = (frozenset(blocked_plugins()), _installed())
    with _DEFAULT_LOCK:
        registry = _DEFAULT.get(key)
        if registry is None:
            registry = Registry(get_plugin_manager())
            _DEFAULT.clear()
            _DEFAULT[key] = registry
    return registry


def blame_plugin(exc, registry):
    """A `PluginError` naming the installed plugin whose code raised ``exc``, or None.

    The plugin is the owner of the innermost frame of the traceback that lies
    in the package of a plugin other than the built-in ones (its module, or
    the module of a step or strategy it registers); the step is the innermost
    step whose method is on the traceback.  A plugin's bug is then reported as
    that plugin's failure, not as the user's error nor as a bug of this package.

    Parameters
    ----------
    exc : BaseException
        The exception, with its traceback.
    registry : `Registry`
        The plugins that may have raised it.

    Returns
    -------
    `~spherex_reduce.core.errors.PluginError` or None
        None if no installed plugin's code is on the traceback.

    Examples
    --------
    >>> from spherex_reduce.reduce.plugins import blame_plugin, get_registry
    >>> try:
    ...     {}["x"]
    ... except KeyError as exc:
    ...     print(blame_plugin(exc, get_registry(entry_points=False)))
    None
    """
    owners = {}  # top-level package of a plugin's code -> plugin name
    for name, plugin in registry.pm.list_name_plugin():
        if plugin is None or name in BUILTIN_PLUGINS:
            continue
        module = plugin.__name__ if inspect.ismodule(plugin) else type(plugin).__module__
        owners.setdefault(module.split(".")[0], name)
    for regs in (registry.steps, *registry.strategies.values()):
        for reg in regs.values():
            if reg.plugin not in BUILTIN_PLUGINS:
                owners.setdefault(reg.obj.__module__.split(".")[0], reg.plugin)
    owners.pop(__name__.split(".")[0], None)  # this package's own code is not a plugin
    culprit = step = None
    tb = exc.__traceback__
    while tb is not None:
        frame = tb.tb_frame
        top = str(frame.f_globals.get("__name__", "")).split(".")[0]
        culprit = owners.get(top, culprit)
        this = frame.f_locals.get("self")
        if isinstance(this, Step):
            step = this.name
        tb = tb.tb_next
    if culprit is None:
        return None
    where = f" in step {step!r}" if step else ""
    return PluginError(f"{describe_plugin(culprit)} failed{where}: {type(exc).__name__}: {exc}. "
                       f"Report it to the plugin's authors, or block it with "
                       f"{BLOCK_ENV}={culprit}")
