"""A pipeline: steps and parameters in the order a YAML file lists them."""

import copy
import hashlib
import json
import queue
import threading
import time

import numpy as np
import yaml
from astropy.table import vstack
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
from .errors import ConfigError, SpherexReduceError, StepSkipped
from .exposure import Exposure
from .fused import fused_plan
from .io import FrameReader, is_raw_ramp_file, read
from .parameters import Parameter, validate_parameters
from .plugins import Registry, blame_plugin
from .step import Step

__all__ = ["Pipeline"]

_PREPARE = 4  # frames whose offsets are computed together by the fused path (in cache)

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
        return read(path, **self._supplied())

    def _supplied(self):
        return {**self._config.get("geometry", {}), **self._config.get("readout", {})}

    def _stream_split(self, steps):
        """Index of the accumulating step if every step before it is per-frame, else None."""
        for i, (_, params, step) in enumerate(steps):
            if type(step).accumulator is not Step.accumulator:
                return i
            if not step.streams(params):
                return None
        return None

    def run(self, exposure, progress=False, stream=True, fuse=True):
        """Run every step in order and return the reduced exposure.

        Parameters
        ----------
        exposure : `Exposure` or path
            The input (a path is read with :meth:`read`); never modified.
        progress : bool
            Show progress bars (steps, and frames when streaming).
        stream : bool
            When the steps allow it (per-frame steps followed by one with an
            accumulator, e.g. ``unchop, subtract_phantom, correct_reference,
            fit_ramp``) and the input is ramps, push the frames through one at
            a time: a raw file is then read frame by frame and memory stays near
            a few frames plus the output.  The result is the same either way
            (to float32 rounding: the fit's sums are formed in another order).
        fuse : bool
            When streaming ``unchop``, then ``subtract_phantom`` (if the input
            has phantom values) and optionally ``correct_reference``
            (``mean`` or ``acn``), into ``fit_ramp``, compute each frame's
            offsets from its phantom values and reference reads, and apply them
            while the fit reads the pixels (see `spherex_reduce.fused`): when
            nothing is flagged, every frame is fitted at once a band of rows at
            a time, giving bit for bit the numbers of ``stream=False``; else
            frame by frame, giving those of ``fuse=False``.

        Returns
        -------
        `Exposure`
            With each step's status keyword, parameters, the package version
            (``SXRVERS``) and the config hash (``SXRCONF``) in its header.

        Raises
        ------
        PluginError
            An installed plugin's code failed (other than with a
            `~spherex_reduce.errors.SpherexReduceError`); the message names the
            plugin, its distribution and the step.
        """
        try:
            return self._run(exposure, progress, stream, fuse)
        except SpherexReduceError:
            raise
        except (Exception, SystemExit) as exc:
            blame = blame_plugin(exc, self.registry)
            if blame is None:
                raise
            raise blame from exc

    def _run(self, exposure, progress, stream, fuse):
        steps = [(name, params, self.registry.step(name)(self.registry))
                 for name, params in self.steps]
        sections = {key: dict(self._config[key]) for key in ("geometry", "readout")
                    if self._config.get(key)}
        for _, _, step in steps:
            step.file_sections = sections
        split = self._stream_split(steps) if stream else None
        current, done = exposure, 0
        if split is not None:
            source = self._frame_source(exposure)
            if source is not None:
                with source:
                    current = self._run_streamed(source, steps[: split + 1], progress, fuse)
                done = split + 1
        if not isinstance(current, Exposure):
            current = self.read(current)
        bar = tqdm(steps[done:], desc="reduce", unit="step", disable=not progress, leave=False)
        for name, params, step in bar:
            bar.set_postfix_str(name)
            self.registry.pm.hook.before_step(step=step, exposure=current, params=params)
            t0 = time.perf_counter()
            try:
                result, status, reason = step.run(current, **params), "COMPLETE", None
            except StepSkipped as skip:
                result, status, reason = current, "SKIPPED", skip.reason
            current = self._record(step, params, current, result, status, reason,
                                   time.perf_counter() - t0)
        header = current.header.copy()
        header["SXRVERS"] = (__version__, "spherex_reduce version")
        header["SXRCONF"] = (self.config_hash, "SHA-256 of the effective pipeline config")
        header.add_history(f"pipeline {self.source}: "
                           + json.dumps(self._config, sort_keys=True, default=str))
        return current.replace(header=header)

    def _record(self, step, params, before, result, status, reason, elapsed):
        """Call the after-step hooks and put their cards in a copy of the result's header."""
        replies = self.registry.pm.hook.after_step(
            step=step, exposure=before, result=result, params=params, status=status,
            reason=reason, elapsed=elapsed)
        header = result.header.copy()
        for cards in replies:
            for key, value, comment in cards or ():
                if key == "HISTORY":
                    header.add_history(value)
                elif key == "COMMENT":
                    header.add_comment(value)
                else:
                    header[key] = (value, comment)
        return result.replace(header=header)

    def _frame_source(self, exposure):
        """Frames of a ramp input (file or Exposure), or None if it is not ramps."""
        if isinstance(exposure, Exposure):
            return _ExposureFrames(exposure) if exposure.is_ramp else None
        if not is_raw_ramp_file(exposure):
            return None
        return FrameReader(exposure, **self._supplied())

    def _run_streamed(self, source, steps, progress, fuse=True):
        """Per-frame steps on each frame in turn, into the last step's accumulator."""
        hook = self.registry.pm.hook
        *prefix, (_, cparams, consumer) = steps
        first = source.frame(0)
        for _, params, step in steps:
            hook.before_step(step=step, exposure=first, params=params)
        acc = _Background(consumer.accumulator(source.schedule, source.header, **cparams))
        elapsed = [0.0] * len(steps)
        status = [("COMPLETE", None)] * len(prefix)
        tables = {}
        frames = tqdm(range(source.nframes), desc="reduce frames", unit="frame",
                      disable=not progress, leave=False)
        plan = fused_plan(prefix, consumer, cparams, source) if fuse else None
        try:
            fused = self._stream_frames(source, first, prefix, acc, frames, elapsed, status,
                                        tables, plan, progress)
        except BaseException:
            acc.stop()
            close = getattr(acc.accumulator, "close", None)
            if close is not None:  # its own threads too
                close()
            raise
        finally:
            acc.stop()  # also when a step failed: no thread is left waiting
        t0 = time.perf_counter()
        result = acc.finish()
        elapsed[-1] = acc.busy + time.perf_counter() - t0
        merged = {name: vstack(parts, metadata_conflicts="silent")
                  for name, parts in tables.items()}
        result = result.replace(tables={**result.tables, **merged})
        if fused:
            how = ("every frame fitted at once, a band of rows at a time (the numbers of "
                   "the steps on the whole ramp)" if fused == "bands" else
                   "frame by frame (the numbers of the steps frame by frame)")
            header = result.header.copy()
            header.add_history(
                f"{', '.join(name for name, _, _ in prefix)} fused into {consumer.name} for "
                f"frames 1-{source.nframes - 1}: offsets from the phantom values and "
                f"reference reads, one pass over the pixels; {how}")
            result = result.replace(header=header)
        for j, (_, params, step) in enumerate(prefix):
            if status[j][0] == "COMPLETE":
                result = step.merge_frames(result, params)
            result = self._record(step, params, first, result, *status[j], elapsed[j])
        return self._record(consumer, cparams, first, result, "COMPLETE", None, elapsed[-1])

    @staticmethod
    def _stream_frames(source, first, prefix, acc, frames, elapsed, status, tables, plan,
                       progress=False):
        """Each frame through the per-frame steps, then to the accumulator.

        With a fused ``plan`` (see `spherex_reduce.fused`), the frames after the
        first go the fused way if every step completed on the first.  Returns
        None if no frame did, else ``'bands'`` or ``'frames'`` (how they were
        fitted).
        """
        frames = iter(frames)
        for k in frames:
            frame = first if k == 0 else source.frame(k)
            for j, (_, params, step) in enumerate(prefix):
                t0 = time.perf_counter()
                try:
                    out = step.run(frame, **params)
                except StepSkipped as skip:
                    out, status[j] = frame, ("SKIPPED", skip.reason)
                elapsed[j] += time.perf_counter() - t0
                for name, table in out.tables.items():
                    if table is not frame.tables.get(name):  # recorded by this step
                        t = table.copy()
                        t["frame"] = np.full(len(t), k, dtype=np.int32)
                        tables.setdefault(name, []).append(t)
                frame = out
            if k == 0 and plan is not None and all(st == "COMPLETE" for st, _ in status):
                return Pipeline._fuse(source, frame, frames, acc, elapsed, tables, plan,
                                      progress)
            acc.add(k, frame)
        return None

    @staticmethod
    def _fuse(source, first, frames, acc, elapsed, tables, plan, progress):
        """The frames after ``first`` (frame 0 after the steps) the fused way.

        Their offsets come first (`FusedFrames.prepare_frames`, from the phantom values
        and reference reads).  Then, if nothing is flagged, the fit reads every
        frame a band of rows at a time (`RampAccumulator.fit_bands`); else the
        frames are copied one by one into the fit's buffer.
        """
        parts = []
        ks = list(frames)
        for c in range(0, len(ks), _PREPARE):  # a few frames per call: temporaries in cache
            chunk = ks[c:c + _PREPARE]
            raws = [source.raw(k) for k in chunk]
            prepared = plan.prepare_frames(chunk, [r for r, _, _ in raws],
                                           [p for _, p, _ in raws], template=first)
            for k, part, (_, _, release) in zip(chunk, prepared, raws, strict=True):
                # the reference reads are copied; the pixels are read again later (the
                # page cache may map a frame's pages in large pieces: release them now)
                release()
                part.release = release
                for j, dt in zip(plan.slots, part.elapsed, strict=True):
                    if j is not None:
                        elapsed[j] += dt
                for name, table in part.tables.items():
                    table["frame"] = np.full(len(table), k, dtype=np.int32)
                    tables.setdefault(name, []).append(table)
                parts.append(part)
        if plan.bandable(first, parts):
            t0 = time.perf_counter()
            with tqdm(desc="fit bands", unit="band", disable=not progress,
                      leave=False) as bar:
                filling = acc.accumulator.fit_bands(first, plan.band_fill(first, parts, source),
                                                  plan.order, plan.reference_reads(first, parts),
                                                  progress=bar)
            # the share of the time spent reading and correcting counts as un-chopping
            wall = time.perf_counter() - t0
            elapsed[plan.slots[0]] += wall * filling
            acc.busy += wall * (1 - filling)
            return "bands"
        acc.add(0, first)
        acc.drain()  # the first frame is in; the later ones go in from here
        for part in parts:
            # straight into the fit's buffer, from this thread (the fit sums full
            # buffers in a thread of its own)
            before, t0 = part.elapsed[0], time.perf_counter()
            acc.accumulator.add_fused(part.k, part)
            part.release()
            # the copy counts as un-chopping (part.elapsed[0]), the rest as fitting
            dt = part.elapsed[0] - before
            elapsed[plan.slots[0]] += dt
            acc.busy += time.perf_counter() - t0 - dt
        return "frames"


class _Background:
    """An accumulator fed from a thread of its own, so that its work on frame ``k``
    overlaps the reading and per-frame steps of frame ``k + 1`` (the two use
    different cores: numpy releases the GIL in its loops).  At most ``depth``
    frames wait in the queue.  An error in the accumulator is raised in the
    caller at the next `add` or at `finish`.
    """

    def __init__(self, accumulator, depth=2):
        self.accumulator = accumulator
        self.busy = 0.0  # seconds spent in the accumulator's add
        self._queue = queue.Queue(maxsize=depth)
        self._error = None
        self._thread = threading.Thread(target=self._work, name="spherex-reduce-accumulate",
                                        daemon=True)
        self._thread.start()

    def _work(self):
        while (item := self._queue.get()) is not None:
            if self._error is None:
                t0 = time.perf_counter()
                try:
                    self.accumulator.add(*item)
                except BaseException as exc:  # raised again in the caller
                    self._error = exc
                self.busy += time.perf_counter() - t0

    def _raise(self):
        if self._error is not None:
            error, self._error = self._error, None
            raise error

    def add(self, index, frame):
        self._raise()
        self._queue.put((index, frame))

    def finish(self):
        self.stop()
        self._raise()
        return self.accumulator.finish()

    def drain(self):
        """Wait for the frames already queued; raise what the accumulator raised."""
        self.stop()
        self._raise()

    def stop(self):
        """End the thread (after the frames already queued)."""
        if self._thread.is_alive():
            self._queue.put(None)
            self._thread.join()


class _ExposureFrames:
    """Frames of an in-memory ramp Exposure, as one-frame views."""

    def __init__(self, exposure):
        self.exposure = exposure
        self.schedule = exposure.schedule
        self.header = exposure.header
        self.unit = exposure.unit
        self.nframes = exposure.schedule.nframes
        self._one = exposure.schedule.replace(nframes=1)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False

    @property
    def has_phantom(self):
        return self.exposure.phantom is not None

    def fusable(self):
        e = self.exposure
        return (e.dq is None and e.data.uncertainty is None and e.order == "readout"
                and e.data.data.dtype.kind == "f"
                and (e.phantom is None or e.phantom.dtype.kind == "f"))

    def raw(self, k):
        e = self.exposure
        return (e.data.data[k], None if e.phantom is None else e.phantom[k],
                lambda: None)

    def reads(self, k, first, stop):
        return self.exposure.data.data[k, first:stop]

    def frame(self, k):
        e = self.exposure
        sl = slice(k, k + 1)
        unc = None if e.data.uncertainty is None else e.data.uncertainty.array[sl]
        return Exposure.from_arrays(
            e.data.data[sl], self._one, unit=e.unit, uncertainty=unc,
            mask=None if e.dq is None else e.dq[sl],
            phantom=None if e.phantom is None else e.phantom[sl], header=e.header,
            order=e.order,
            reference=None if e.reference is None else e.reference.replace(
                data=e.reference.data[sl],
                phantom=None if e.reference.phantom is None else e.reference.phantom[sl],
                dq=None if e.reference.dq is None else e.reference.dq[sl]),
            tables=e.tables)
