"""A pipeline: steps and parameters in the order a YAML file lists them."""

import copy
import hashlib
import json
import time

import yaml
from tqdm.auto import tqdm

from ._version import __version__
from .config import (
    GEOMETRY_PARAMETERS,
    READOUT_PARAMETERS,
    load_yaml,
    resolve_config,
    schedule_from_config,
    section_values,
)
from .errors import ConfigError, StepSkipped
from .exposure import Exposure
from .fits_format import read
from .parameters import Parameter, validate_parameters
from .plugins import Registry

__all__ = ["Pipeline"]

_TOP_KEYS = ("steps", "geometry", "readout", "name", "description")


class Pipeline:
    """Run steps from a YAML configuration on an `Exposure` or a FITS file.

    The configuration is a mapping::

        name: my-reduction              # optional
        geometry: {nrows: 2048, ...}    # optional: for files lacking the keywords
        readout:  {skip: 24, ...}       # optional: idem
        steps:                          # run in this order
          - unchop: {}
          - correct_reference: {strategy: mean}

    Every step and parameter is validated when the pipeline is built: an
    unknown name or a wrong type raises `~spherex_reduce.errors.ConfigError`
    naming the YAML path and the valid names.

    Parameters
    ----------
    config : dict
        The configuration mapping.
    registry : `~spherex_reduce.plugins.Registry`, optional
        Where step names are looked up (default: built-in and installed plugins).
    source : str
        Label of the configuration in messages and provenance.

    Examples
    --------
    >>> import numpy as np
    >>> from spherex_reduce import DetectorGeometry, Exposure, Pipeline, ReadoutSchedule
    >>> s = ReadoutSchedule(DetectorGeometry(8, 4, 1, ref_border=1), skip=3, ref_reads=2,
    ...                     phantom_reads=0, nframes=1)
    >>> raw = Exposure.from_arrays(np.zeros((s.n_reads, 4)), s)
    >>> out = Pipeline({"steps": [{"unchop": {}}]}).run(raw)
    >>> out.order, out.header["S_UNCHOP"]
    ('physical', 'COMPLETE')
    """

    def __init__(self, config, registry=None, source="config"):
        self.registry = registry or Registry()
        self.source = source
        self._config = self._validate(copy.deepcopy(config), source)

    # -- construction ----------------------------------------------------------
    @classmethod
    def from_yaml(cls, path_or_name, registry=None):
        """Build from a YAML file path, or the name of a shipped config."""
        text, label = resolve_config(path_or_name)
        config, _ = load_yaml(text, label)
        return cls(config, registry=registry, source=label)

    def _validate(self, config, label):
        if not isinstance(config, dict):
            raise ConfigError(f"{label}: a pipeline config must be a mapping")
        for key in config:
            if key not in _TOP_KEYS:
                raise ConfigError(f"{key}: unknown top-level key; valid: {', '.join(_TOP_KEYS)}")
        steps = config.get("steps")
        if not isinstance(steps, list) or not steps:
            raise ConfigError("steps: a non-empty list of {step_name: {parameters}} is required")
        geometry = section_values(config, "geometry", GEOMETRY_PARAMETERS)
        readout = section_values(config, "readout", READOUT_PARAMETERS)
        effective = []
        for i, item in enumerate(steps):
            path = f"steps[{i}]"
            if isinstance(item, str):
                item = {item: {}}
            if not isinstance(item, dict) or len(item) != 1:
                raise ConfigError(f"{path}: each step is a one-key mapping {{name: {{...}}}}")
            (name, params), = item.items()
            try:
                cls = self.registry.step(name)
            except KeyError as exc:
                raise ConfigError(f"{path}.{name}: {exc.args[0]}") from None
            effective.append({name: self._step_params(cls, params, f"{path}.{name}")})
        out = {k: config[k] for k in ("name", "description") if k in config}
        if geometry:
            out["geometry"] = geometry
        if readout:
            out["readout"] = readout
        out["steps"] = effective
        return out

    def _step_params(self, cls, params, path):
        declared = list(cls.parameters)
        if cls.strategy_kind:
            options = sorted(self.registry.strategies.get(cls.strategy_kind, {}))
            name = (params or {}).get("strategy", cls.default_strategy)
            strategy_param = Parameter("strategy", cls.default_strategy, (str,),
                                       f"{cls.strategy_kind} strategy", choices=tuple(options))
            strategy_param.check(name, f"{path}.strategy")
            declared = [strategy_param, *declared,
                        *self.registry.strategy(cls.strategy_kind, name).parameters]
        return validate_parameters(params, declared, path)

    # -- what it is -----------------------------------------------------------
    @property
    def config(self):
        """The effective configuration: every parameter, defaults filled in (a copy)."""
        return copy.deepcopy(self._config)

    @property
    def steps(self):
        """``[(name, params), ...]`` in run order."""
        return [next(iter(item.items())) for item in self.config["steps"]]

    def to_yaml(self):
        """The effective configuration as YAML text."""
        return yaml.safe_dump(self.config, sort_keys=False)

    @property
    def config_hash(self):
        """SHA-256 (first 16 hex digits) of the effective configuration."""
        text = json.dumps(self._config, sort_keys=True, default=str)
        return hashlib.sha256(text.encode()).hexdigest()[:16]

    def schedule(self):
        """The schedule the ``geometry:``/``readout:`` sections describe (defaults filled)."""
        return schedule_from_config(self._config.get("geometry"), self._config.get("readout"))

    # -- running ------------------------------------------------------------------
    def read(self, path):
        """Read a FITS file, with this config's geometry/readout for missing keywords."""
        supplied = {**self._config.get("geometry", {}), **self._config.get("readout", {})}
        return read(path, **supplied)

    def run(self, exposure, progress=False):
        """Run every step in order and return the reduced exposure.

        Parameters
        ----------
        exposure : `Exposure` or path
            The input (a path is read with :meth:`read`); never modified.
        progress : bool
            Show a progress bar over the steps.

        Returns
        -------
        `Exposure`
            With each step's status keyword, parameters, the package version
            (``SXRVERS``) and the config hash (``SXRCONF``) in its header.
        """
        if not isinstance(exposure, Exposure):
            exposure = self.read(exposure)
        hook = self.registry.pm.hook
        current = exposure
        bar = tqdm(self.steps, desc="reduce", unit="step", disable=not progress, leave=False)
        for name, params in bar:
            bar.set_postfix_str(name)
            step = self.registry.step(name)(self.registry)
            hook.before_step(step=step, exposure=current, params=params)
            t0 = time.perf_counter()
            try:
                result, status, reason = step.run(current, **params), "COMPLETE", None
            except StepSkipped as skip:
                result, status, reason = current, "SKIPPED", skip.reason
            elapsed = time.perf_counter() - t0
            replies = hook.after_step(step=step, exposure=current, result=result, params=params,
                                      status=status, reason=reason, elapsed=elapsed)
            header = result.header.copy()
            for cards in replies:
                for key, value, comment in cards or ():
                    if key in ("HISTORY", "COMMENT"):
                        header.add_history(value) if key == "HISTORY" else header.add_comment(
                            value)
                    else:
                        header[key] = (value, comment)
            current = result.replace(header=header)
        header = current.header.copy()
        header["SXRVERS"] = (__version__, "spherex_reduce version")
        header["SXRCONF"] = (self.config_hash, "SHA-256 of the effective pipeline config")
        header.add_history(f"pipeline {self.source}: "
                           + json.dumps(self._config, sort_keys=True, default=str))
        return current.replace(header=header)
