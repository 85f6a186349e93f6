"""A pipeline: steps and parameters in the order a YAML file lists them."""

import copy
import hashlib
import json
from pathlib import Path

import yaml
from astropy.io import fits
from tqdm.auto import tqdm

from .._version import __version__
from ..core.errors import ConfigError, SpherexReduceError, StepSkipped
from ..core.exposure import Exposure
from ..io import FrameReader, is_raw_ramp_file, read
from ..io.config import (
    GEOMETRY_PARAMETERS,
    READOUT_PARAMETERS,
    load_yaml,
    resolve_config,
    schedule_from_config,
    section_values,
)
from ..io.input import InputOptions
from .executor import FileSource, MemorySource, execute
from .plugins import Registry, blame_plugin
from .step import Step

__all__ = ["Pipeline", "as_pipeline"]

_TOP_KEYS = ("steps", "input", "geometry", "readout", "name", "description")


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

    @property
    def config_hash(self):
        """SHA-256 (first 16 hex digits) of the effective configuration."""
        text = json.dumps(self._config, sort_keys=True, default=str)
        return hashlib.sha256(text.encode()).hexdigest()[:16]

    def schedule(self):
        """The schedule the ``geometry:``/``readout:`` sections describe (defaults filled)."""
        return schedule_from_config(self._config.get("geometry"), self._config.get("readout"))

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
        """The ``geometry:`` and ``readout:`` values, one mapping: what a reader takes for
        keywords a file lacks (with `input_options` for the ``input:`` section)."""
        return {**self._config.get("geometry", {}), **self._config.get("readout", {})}

    def run(self, exposure, progress=False, threads=None):
        """Run every step in order and return the reduced exposure.

        Consecutive steps that have kernels (``unchop``, ``subtract_phantom``,
        ``correct_reference`` with a streaming strategy, a plugin's) run in one
        pass of the executor (`spherex_reduce.reduce.executor`), ending in a step that
        consumes bands (``fit_ramp``) if one follows: a raw file is then read
        once, a band of rows of every frame at a time, and memory stays near
        the output plus a few bands.  Other steps run on the whole exposure.
        The numbers are those of the steps run one by one, bit for bit.

        Parameters
        ----------
        exposure : `Exposure`, path, or an open reader
            The input, never modified: a path is read as :meth:`read` does; an
            open reader of raw ramps (`~spherex_reduce.io.FrameReader`, or
            `~spherex_reduce.io.read_files.ReadFiles` for one file per read) is
            read in bands, or whole when a pass cannot stream it (the caller
            closes it).
        progress : bool
            Show progress bars (steps, and rows of a pass).
        threads : int, optional
            Bands corrected at once (default: the cores available, at most 4).

        Returns
        -------
        `Exposure`
            With each step's status keyword, parameters, a row of the
            ``PROVENANCE`` table, the package version (``SXRVERS``) and the
            config hash (``SXRCONF``) in its header.

        Raises
        ------
        PluginError
            An installed plugin's code failed (other than with a
            `~spherex_reduce.core.errors.SpherexReduceError`); the message names the
            plugin, its distribution and the step.
        """
        try:
            return self._run(exposure, progress, threads)
        except SpherexReduceError:
            raise
        except (Exception, SystemExit) as exc:
            blame = blame_plugin(exc, self.registry)
            if blame is None:
                raise
            raise blame from exc

    def _steps(self, threads):
        sections = {key: dict(self._config[key]) for key in ("geometry", "readout")
                    if self._config.get(key)}
        steps = []
        for name, params in self.steps:
            step = self.registry.step(name)(self.registry, threads=threads)
            step.file_sections = sections
            steps.append((name, params, step))
        return steps

    def _run(self, exposure, progress, threads):
        steps = self._steps(threads)
        current = self._run_steps(exposure, steps, progress, threads)
        header = current.header.copy()
        header["SXRVERS"] = (__version__, "spherex_reduce version")
        header["SXRCONF"] = (self.config_hash, "SHA-256 of the effective pipeline config")
        header.add_history(f"pipeline {self.source}: "
                           + json.dumps(self._config, sort_keys=True, default=str))
        return current.replace(header=header)

    def _run_steps(self, exposure, steps, progress, threads):
        """Run ``steps`` (``(name, params, step)``) on an exposure or a file, pass by pass."""
        current, i = exposure, 0
        status = {}  # step index -> 'COMPLETE' or 'SKIPPED'
        # shown after a second: a bad input is refused before any bar is drawn
        bar = tqdm(total=len(steps), desc="reduce", unit="step", disable=not progress,
                   leave=False, delay=1.0)
        with bar:
            while i < len(steps):
                done, current = self._pass(current, steps, i, status, progress, threads)
                if done == i:  # no kernel: the step on the whole exposure
                    current = self._whole(current, steps, i, status, progress, threads)
                    done = i + 1
                bar.update(done - i)
                i = done
        return self._loaded(current)

    @staticmethod
    def _is_reader(current):
        """An open reader of raw ramps (`~spherex_reduce.io.FrameReader`, ``ReadFiles``)."""
        return hasattr(current, "reads") and hasattr(current, "exposure")

    def _loaded(self, current):
        """``current`` (an exposure, an open reader or a path) as an exposure in memory."""
        if isinstance(current, Exposure):
            return current
        return current.exposure() if self._is_reader(current) else self.read(current)

    def _source(self, current):
        """Where a pass reads from: ``(source, reader, opened)``.

        The source is the file in bands if it can be, else the exposure in memory;
        the reader is what the bands come from (the whole file comes from it too if
        the pass cannot stream); ``opened`` says the pipeline opened it (and closes it).
        """
        if isinstance(current, Exposure):
            return MemorySource(current), None, False
        if self._is_reader(current):
            reader, opened = current, False
        elif is_raw_ramp_file(current):
            reader = FrameReader(current, input=self.input_options, **self.supplied())
            opened = True
        else:
            return MemorySource(self.read(current)), None, False
        if FileSource.usable(reader):
            return FileSource(reader), reader, opened
        try:  # read whole from the file already open and checked
            return MemorySource(reader.exposure()), None, False
        finally:
            if opened:
                reader.close()

    def _pass(self, current, steps, i, status, progress, threads):
        """Steps ``i, i+1, ...`` that have kernels (and a consumer after them) in one pass.

        Returns the index of the first step not run and the result (``current``
        itself if no step could run in a pass).
        """
        first = steps[i][2]
        if first.inputs or (type(first).kernel is Step.kernel
                            and type(first).consumer is Step.consumer):
            return i, current
        source, reader, opened = self._source(current)
        try:
            done, result = self._pass_on(source, current, steps, i, status, progress, threads)
            if done == i and reader is not None:  # the step runs whole: on the file open here
                result = reader.exposure()
            return done, result
        finally:
            if opened:
                reader.close()

    def _plan(self, source, steps, i, threads=None):
        """The kernels and consumer of the pass from step ``i``: ``(kernels, consumer,
        members, skipped, end)``."""
        context = source.context.replace(threads=threads)
        kernels, consumer, members, skipped = [], None, [], {}
        j = i
        while j < len(steps):
            _, params, step = steps[j]
            if step.inputs:
                break
            try:
                kernel = step.kernel(context, **params)
                consumer = None if kernel is not None else step.consumer(context, **params)
            except StepSkipped as skip:
                skipped[j] = skip.reason
                members.append(j)
                j += 1
                continue
            if kernel is not None:
                if kernel.needs_exposure and (kernels or not isinstance(source, MemorySource)):
                    break  # its prepare needs the exposure as it comes to it, in memory
                kernels.append(kernel)
                context = kernel.output
                members.append(j)
                j += 1
                continue
            if consumer is not None:
                members.append(j)
                j += 1
            break
        return kernels, consumer, members, skipped, j

    def _pass_on(self, source, current, steps, i, status, progress, threads):
        kernels, consumer, members, skipped, j = self._plan(source, steps, i, threads)
        if not kernels and consumer is None:
            if not members:  # the step runs whole: on what was read, if it was
                return i, (source.exposure if isinstance(source, MemorySource) else current)
            # only skipped steps (e.g. subtract_phantom without phantom values)
            if not isinstance(current, Exposure):
                current = (source.exposure if isinstance(source, MemorySource)
                           else self._loaded(current))
            for k in members:
                self.registry.pm.hook.before_step(step=steps[k][2], exposure=current,
                                                  params=steps[k][1])
            return j, self._record_pass(current, steps, members, skipped, {}, status, "",
                                        current)
        hook = self.registry.pm.hook
        before = source.exposure if isinstance(source, MemorySource) else None
        for k in members:
            hook.before_step(step=steps[k][2], exposure=before, params=steps[k][1])
        timings = {}
        rows = tqdm(total=source.nrows, desc="reduce rows", unit="row", disable=not progress,
                    leave=False, delay=1.0)
        with rows:
            result = execute(source, kernels, consumer, threads=threads, progress=rows.update,
                             timings=timings)
        ran = [k for k in members if k not in skipped]
        where = "a file" if isinstance(source, FileSource) else "memory"
        route = (f"executor pass of {len(ran)} step(s): {timings['bands']} band(s) of rows "
                 f"from {where} on {timings['threads']} thread(s)")
        # each step's busy seconds (over threads); reading counts for the first
        busy = dict(zip(ran, [*timings["kernels"], timings["consumer"]], strict=False))
        busy[ran[0]] += timings["read"]
        return j, self._record_pass(result, steps, members, skipped, busy, status, route,
                                    before)

    def _record_pass(self, result, steps, members, skipped, busy, status, route, before=None):
        for k in members:
            _, params, step = steps[k]
            if k in skipped:
                result = step.record(before, result, params, "SKIPPED", skipped[k], 0.0,
                                     route="skipped")
                status[k] = "SKIPPED"
            else:
                result = step.record(before, result, params, "COMPLETE", None,
                                     busy.get(k, 0.0), route=route)
                status[k] = "COMPLETE"
        return result

    def _whole(self, current, steps, i, status, progress, threads):
        """Step ``i`` on the whole exposure, its declared inputs prepared by the pipeline."""
        _, params, step = steps[i]
        current = self._loaded(current)
        inputs = {}
        for key in step.inputs:
            path = params.get(key)
            reduces = step.reduces_input
            if isinstance(path, str) and reduces is not None and reduces(key, params):
                inputs[key] = self._same_stage(path, key, steps, i, status, progress,
                                               threads, step)
        result = step.apply_to(current, params, inputs=inputs)
        status[i] = result.header.get(step.keyword, "COMPLETE")
        return result

    def _same_stage(self, path, key, steps, i, status, progress, threads, step):
        """The file ``path`` with the steps before ``i`` that completed here and not there
        (None: nothing to do, the step reads it as it is)."""
        if not Path(path).is_file():
            raise FileNotFoundError(f"{step.name}.{key}: no such file: {path}")
        there = fits.getheader(path)
        todo = [steps[k] for k in range(i) if status.get(k) == "COMPLETE"
                and there.get(steps[k][2].keyword) != "COMPLETE"]
        if not todo:
            return None
        return self._run_steps(path, todo, progress, threads)


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
