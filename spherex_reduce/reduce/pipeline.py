"""A pipeline: steps and parameters in the order a YAML file lists them."""

import copy
import functools
import hashlib
import json
import os
from pathlib import Path

import numpy as np
import yaml
from astropy.io import fits

from .._version import __version__
from ..core.errors import ConfigError, SpherexReduceError
from ..io import read
from ..io.config import (
    GEOMETRY_PARAMETERS,
    READOUT_PARAMETERS,
    WINDOW_PARAMETERS,
    load_yaml,
    resolve_config,
    schedule_from_config,
    section_values,
)
from ..io.header_text import header_text
from ..io.input import InputOptions
from ..io.sources import MemorySource, open_input
from .options import RunOptions
from .passes import PlannedStep, Whole, plan_pass, run_pass
from .plugins import Registry, blame_plugin
from .progress import terminal_bar

__all__ = ["Pipeline", "as_pipeline"]

_TOP_KEYS = ("steps", "input", "geometry", "readout", "window", "name", "description")


class Pipeline:
    """Run steps from a YAML configuration on an `Exposure` or a FITS file.

    The configuration is a mapping::

        name: my-reduction              # optional
        input: {unit: adu, gain: 1.8}   # optional: what a file needs before the steps
        geometry: {nrows: 2048, ...}    # optional: for files lacking the keywords
        readout:  {skip: 24, ...}       # optional: idem
        steps:                          # run in this order
          - unchop: {}
          - correct_reference: {strategy: mean}

    Every step and parameter is validated when the pipeline is built: an
    unknown name or a wrong type raises `~spherex_reduce.core.errors.ConfigError`
    naming the YAML path and the valid names.

    Parameters
    ----------
    config : dict
        The configuration mapping.
    registry : `~spherex_reduce.reduce.plugins.Registry`, optional
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
        window = section_values(config, "window", WINDOW_PARAMETERS)
        options = InputOptions.from_config(config.get("input"))
        if "nchannels" in geometry:
            options.check_channels(geometry["nchannels"])
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
        if "input" in config:
            out["input"] = options.to_config()
        if geometry:
            out["geometry"] = geometry
        if readout:
            out["readout"] = readout
        if window:
            out["window"] = window
        out["steps"] = effective
        return out

    def _step_params(self, cls, params, path):
        return cls(self.registry).validate(params, path)

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

    @functools.cached_property
    def config_hash(self):
        """SHA-256 (first 16 hex digits) of the effective configuration, less the parameters
        added after outputs were made while they are at their defaults (``quiet_default``:
        the hash stays the one those outputs carry, so a batch still recognises them).
        Computed once: the configuration does not change after the pipeline is made (a
        batch asks for it per file)."""
        config = copy.deepcopy(self._config)
        for item in config["steps"]:
            (name, params), = item.items()
            step = self.registry.step(name)(self.registry)
            for p in step.declared(params, name):
                if (p.quiet_default and p.name in params
                        and _is_value(params[p.name], p.default)):
                    del params[p.name]
        text = json.dumps(config, sort_keys=True, default=_hashable)
        return hashlib.sha256(text.encode()).hexdigest()[:16]

    def schedule(self):
        """The schedule the ``geometry:``/``readout:`` sections describe (defaults filled)."""
        return schedule_from_config(self._config.get("geometry"), self._config.get("readout"),
                                    self._config.get("window"))

    # -- running ------------------------------------------------------------------
    @property
    def input_options(self):
        """The ``input:`` section (`~spherex_reduce.io.input.InputOptions`; defaults if none)."""
        return InputOptions.from_config(self._config.get("input"))

    def read(self, path):
        """Read a FITS file as this config's ``input:`` section says, with its
        ``geometry:``/``readout:`` values for keywords the file lacks (or, with
        ``input: {header: override}``, instead of the file's).

        The same as ``spherex_reduce.read(path, input=config["input"],
        **geometry, **readout)``.  `run` on a path reads it so (streamed when it
        can), and gives the numbers that `run` on the exposure read here gives.
        """
        return read(path, input=self.input_options, **self.supplied())

    def supplied(self):
        """The ``geometry:``, ``readout:`` and ``window:`` values, one mapping: what a reader
        takes for keywords a file lacks (with `input_options` for the ``input:`` section)."""
        return {**self._config.get("geometry", {}), **self._config.get("readout", {}),
                **self._config.get("window", {})}

    def run(self, exposure, progress=False, threads=None):
        """Run every step in order and return the reduced exposure.

        Consecutive steps that have kernels (``unchop``, ``subtract_phantom``,
        ``correct_reference`` with a streaming strategy, a plugin's) run in one
        pass of the executor (`spherex_reduce.reduce.passes`), ending in a step
        that consumes bands (``fit_ramp``) if one follows: a raw file is then
        read once, a band of rows of every frame at a time, and memory stays
        near the output plus a few bands.  Other steps run on the whole
        exposure.  The numbers are those of the steps run one by one, bit for bit.

        Parameters
        ----------
        exposure : `Exposure`, path, sequence of paths, or an open reader or source
            The input, never modified, opened by
            `~spherex_reduce.io.sources.open_input` with this config's
            ``input:``, ``geometry:`` and ``readout:`` sections: a path is read
            as :meth:`read` does (streamed when it can be); a sequence of paths
            (or a glob) is one ramp stored as one file per read; an open reader
            of raw ramps (`~spherex_reduce.io.FrameReader`, or
            `~spherex_reduce.io.readers.read_files.ReadFiles`) is read in bands, or
            whole when a pass cannot stream it (the caller closes it).  A file
            of several integrations is reduced by
            `~spherex_reduce.reduce_integrations`.
        progress : bool
            Show progress bars (steps, and rows of a pass).
        threads : int, optional
            Bands corrected at once (default: the cores available, at most 4).

        Returns
        -------
        `Exposure`
            With each step's status keyword, parameters, a row of the
            ``PROVENANCE`` table, the package version (``SXRVERS``) and the
            config hash (``SXRCONF``) in its header.  An image has its
            reference pixels flagged `~spherex_reduce.core.dq.REFERENCE`
            (`Exposure.with_reference_flags`; informational, it masks nothing).

        Raises
        ------
        PluginError
            An installed plugin's code failed (other than with a
            `~spherex_reduce.core.errors.SpherexReduceError`); the message names the
            plugin, its distribution and the step.
        """
        options = RunOptions(threads=threads, progress=progress)
        try:
            with self.open(exposure) as inp:
                result = _Run(self, self._planned(options), options).on(inp.source())
        except SpherexReduceError:
            raise
        except (Exception, SystemExit) as exc:
            blame = blame_plugin(exc, self.registry)
            if blame is None:
                raise
            raise blame from exc
        return self._stamped(result)

    def open(self, what):
        """Open an input with this config's sections (`~spherex_reduce.io.sources.open_input`)."""
        return open_input(what, input=self.input_options, **self.supplied())

    def _planned(self, options):
        return [PlannedStep(i, name, params, self.registry.step(name)(self.registry,
                                                                       threads=options.threads))
                for i, (name, params) in enumerate(self.steps)]

    def _stamped(self, result):
        """The output: reference pixels flagged (an image's), version and config in its
        header."""
        result = result.with_reference_flags()
        header = result.header.copy()
        header["SXRVERS"] = (__version__, "spherex_reduce version")
        header["SXRCONF"] = (self.config_hash, "SHA-256 of the effective pipeline config")
        header.add_history(f"pipeline {header_text(self.source)}: "
                           + json.dumps(self._config, sort_keys=True, default=str))
        return result.replace(header=header)


def _bar(progress, **kwargs):
    """A tqdm bar shown after a second (a bad input is refused before any bar is drawn) on
    a terminal (`~spherex_reduce.reduce.progress.terminal_bar`)."""
    return terminal_bar(progress, leave=False, delay=1.0, **kwargs)


class _Run:
    """One run of a list of steps: what each step did (``status``), with its
    `~spherex_reduce.reduce.options.RunOptions`.

    `on` loops over what `~spherex_reduce.reduce.passes.plan_pass` plans:
    passes through the executor and steps run whole; every step's hooks and
    provenance go through `_started` and `_recorded`.
    """

    def __init__(self, pipeline, steps, options):
        self.pipeline, self.steps, self.options = pipeline, steps, options
        self.status = {}  # step index -> 'COMPLETE' or 'SKIPPED'

    def on(self, source):
        """Run the steps on ``source`` (a `~spherex_reduce.io.sources.Source`); the result."""
        i = 0
        bar = _bar(self.options.progress, total=len(self.steps), desc="reduce", unit="step")
        with bar:
            while i < len(self.steps):
                plan = plan_pass(self.steps, i, source, self.options)
                if isinstance(plan, Whole):
                    result, end = self._whole(source.exposure(), plan.planned), i + 1
                else:
                    result, end = self._pass(source, plan), plan.end
                bar.update(end - i)
                i = end
                source = MemorySource(result)
        return self._applied(source.exposure())

    def _applied(self, result):
        """``result`` with the status keyword of a step listed more than once saying whether
        the data went through it: COMPLETE if any of its runs completed, though a later
        one was skipped (each run's own status stays in HISTORY and ``PROVENANCE``)."""
        done = {p.step.keyword for p in self.steps if self.status.get(p.index) == "COMPLETE"}
        stale = sorted(k for k in done if result.header.get(k) != "COMPLETE")
        if not stale:
            return result
        header = result.header.copy()
        for key in stale:
            header[key] = "COMPLETE"  # the comment ("fit_ramp step") stays
        return result.replace(header=header)

    def _pass(self, source, plan):
        before = source.exposure() if source.in_memory or not plan.runs else None
        for planned in plan.members:
            planned.step.started(before, planned.params)
        if not plan.runs:  # only skipped steps (e.g. subtract_phantom without phantom values)
            result, busy, route = before, {}, ""
        else:
            rows = _bar(self.options.progress, total=source.nrows, desc="reduce rows",
                        unit="row")
            with rows:
                result, busy, route = run_pass(source, plan, options=self.options,
                                               progress=rows.update)
        for planned in plan.members:
            reason = plan.skipped.get(planned.index)
            if reason is not None:
                result = planned.step.record(before, result, planned.params, "SKIPPED", reason,
                                             0.0, route="skipped")
            else:
                result = planned.step.record(before, result, planned.params, "COMPLETE", None,
                                             busy.get(planned.index, 0.0), route=route)
            self.status[planned.index] = "SKIPPED" if reason is not None else "COMPLETE"
        return result

    def _whole(self, exposure, planned):
        """A step on the whole exposure, its declared inputs prepared here: read with the
        config's ``geometry:``/``readout:`` values, or first brought to this stage."""
        step, params = planned.step, planned.params
        inputs = {}
        for key in step.inputs:
            path = params.get(key)
            if not isinstance(path, (str, os.PathLike)):
                continue
            done = self._same_stage(path, key, planned) if step.reduces_input(key, params) \
                else None
            inputs[key] = (done if done is not None
                           else step.read_input(key, path, self.pipeline.supplied()))
        result = step.apply_to(exposure, params, inputs=inputs)
        self.status[planned.index] = result.header.get(step.keyword, "COMPLETE")
        return result

    def _same_stage(self, path, key, planned):
        """The file ``path`` with the steps before ``planned`` that completed here and not
        there (None: nothing to do, the step reads it as it is)."""
        if not Path(path).is_file():
            raise FileNotFoundError(f"{planned.step.name}.{key}: no such file: {path}")
        there = fits.getheader(path)
        todo = [p for p in self.steps[:planned.index] if self.status.get(p.index) == "COMPLETE"
                and there.get(p.step.keyword) != "COMPLETE"]
        if not todo:
            return None
        todo = [PlannedStep(k, p.name, p.params, p.step) for k, p in enumerate(todo)]
        with self.pipeline.open(path) as inp:
            return _Run(self.pipeline, todo, self.options).on(inp.source())


def as_pipeline(pipeline):
    """A `~spherex_reduce.reduce.pipeline.Pipeline` from a pipeline, a shipped name, a path or
    a config.

    An inline config (dict) is named by its ``name`` (``"pipeline"`` if it has none).

    Examples
    --------
    >>> from spherex_reduce.reduce.pipeline import as_pipeline
    >>> as_pipeline({"name": "raw", "steps": [{"unchop": {}}]}).source
    'raw'
    """
    if isinstance(pipeline, Pipeline):
        return pipeline
    if isinstance(pipeline, dict):
        return Pipeline(pipeline, source=str(pipeline.get("name", "pipeline")))
    return Pipeline.from_yaml(pipeline)


def _is_value(value, default):
    """Whether a parameter's ``value`` is ``default`` (an array given in Python never is)."""
    return not isinstance(value, np.ndarray) and value == default


def _hashable(value):
    """JSON for a configuration's value that JSON has no type for: an array by its type,
    shape and a digest of its bytes (its ``str`` abbreviates a large one, so two maps
    would hash alike) and a Quantity's unit, anything else as its ``str``."""
    if isinstance(value, np.ndarray):
        data = np.ascontiguousarray(getattr(value, "value", value))
        out = {"array": str(data.dtype), "shape": list(data.shape),
               "sha256": hashlib.sha256(data.tobytes()).hexdigest()}
        if hasattr(value, "unit"):  # a Quantity: 10 e and 10 ADU are not one map
            out["unit"] = str(value.unit)
        return out
    return str(value)
