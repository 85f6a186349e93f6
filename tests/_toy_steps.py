"""Toy steps and plugins the pipeline, plugin, executor and one-by-one tests share."""

import numpy as np
from astropy.table import Table

from spherex_reduce import Exposure, Step, StepSkipped
from spherex_reduce.core.parameters import Parameter
from spherex_reduce.reduce.hookspecs import hookimpl
from spherex_reduce.reduce.plugins import Registry, get_plugin_manager
from spherex_reduce.reduce.step import Consumer, Kernel, Record


class Offset(Step):
    name, keyword = "offset", "S_OFFSET"
    parameters = (Parameter("value", 0.0, (float,), "added (e)"),
                  Parameter("mode", "add", (str,), "add or skip", choices=("add", "skip")))

    def run(self, exposure, value, mode):
        if mode == "skip":
            raise StepSkipped("asked to skip")
        return exposure.replace(data=exposure.data.data + value)


class OffsetPlugin:
    def __init__(self):
        self.calls = []

    @hookimpl
    def register_steps(self):
        return [Offset]

    @hookimpl
    def before_step(self, step, exposure, params):
        self.calls.append(("before", step.name, dict(params)))

    @hookimpl
    def after_step(self, step, exposure, result, params, status, reason, elapsed):
        self.calls.append(("after", step.name, status))
        return [("QA_" + step.name[:5].upper(), float(elapsed >= 0), "qa")]


def registry_with(*plugins):
    return Registry(get_plugin_manager(entry_points=False, plugins=plugins))


class SumConsumer(Consumer):
    """Toy consumer: the sum of the frames (a stand-in for fit_ramp), band by band."""

    def __init__(self, context):
        self.context = context
        n = (context.schedule.n_reads if context.order == "readout"
             else context.geometry.nrows)
        self.total = np.full((n, context.geometry.ncols), np.nan)
        self.bands = []

    def band(self, block):
        self.bands.append(len(block.index))
        self.total[block.index] = block.data.sum(axis=0, dtype=np.float64)

    def finish(self, reference, header, tables):
        c = self.context
        return Exposure.from_arrays(self.total, c.schedule, order=c.order, header=header,
                                    tables=tables)


class FrameSum(Step):
    name, keyword = "framesum", "S_FSUM"

    def consumer(self, context):
        if not context.ramp:
            raise StepSkipped("not ramps")
        return SumConsumer(context)


class NoteKernel(Kernel):
    """Toy kernel: minus each frame's mean reference read; the means in a table."""

    def prepare(self, side):
        return side.data.mean(axis=(1, 2), dtype=np.float64)

    def apply(self, means, block):
        return block.replace(data=block.data - means[:, None, None], owned=True)

    def record(self, means):
        return Record({"NOTE": Table({"frame": np.arange(means.size), "mean": means})})


class PerFrameNote(Step):
    name, keyword = "note", "S_NOTE"

    def kernel(self, context):
        return NoteKernel(context)


class ToyPlugin:
    @hookimpl
    def register_steps(self):
        return [FrameSum, PerFrameNote]


def write_raw(tmp_path, raw):
    from spherex_reduce import write

    return write(raw, tmp_path / "raw.fits")
