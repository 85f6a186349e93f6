"""What every command shares: checked option types, inputs vs outputs, all-or-nothing writes.

Numbers given on the command line are checked by argparse ``type=`` functions
(:func:`finite_float`, :func:`positive_float`, :func:`nonnegative_float`,
:func:`count`), so a bad value is a usage error naming the option (exit 2)
before any work.  :func:`check_paths` refuses an output that is one of the
command's inputs, however either is spelled; :func:`all_or_nothing` writes a
command's outputs together or not at all.
"""

import argparse
import contextlib
import math
import os
from pathlib import Path

from ..core.errors import ResourceError, SpherexReduceError
from ..core.limits import check_count
from ..io import atomic_output

__all__ = ["add_config_option", "all_or_nothing", "check_paths", "count", "finite_float",
           "input_config", "named_files", "nonnegative_float", "positive_float"]


def _float(text):
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"must be a finite number, got {text!r}")
    return value


def finite_float(text):
    """A finite number (not nan or inf).

    Examples
    --------
    >>> from spherex_reduce.cli._common import finite_float
    >>> finite_float("-1.5")
    -1.5
    >>> finite_float("nan")
    Traceback (most recent call last):
    ...
    argparse.ArgumentTypeError: must be a finite number, got 'nan'
    """
    return _float(text)


def positive_float(text):
    """A finite number > 0.

    Examples
    --------
    >>> from spherex_reduce.cli._common import positive_float
    >>> positive_float("6.2")
    6.2
    >>> positive_float("0")
    Traceback (most recent call last):
    ...
    argparse.ArgumentTypeError: must be > 0, got '0'
    """
    value = _float(text)
    if value <= 0:
        raise argparse.ArgumentTypeError(f"must be > 0, got {text!r}")
    return value


def nonnegative_float(text):
    """A finite number >= 0.

    Examples
    --------
    >>> from spherex_reduce.cli._common import nonnegative_float
    >>> nonnegative_float("0")
    0.0
    """
    value = _float(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be >= 0, got {text!r}")
    return value


def count(maximum, minimum=1):
    """An argparse type: a whole number from ``minimum`` (0 or 1) to ``maximum``.

    ``3e8`` is accepted as a whole number (and then refused if too large), so
    the message says what is wrong with it.  The check is
    `spherex_reduce.core.limits.check_count`.

    Examples
    --------
    >>> from spherex_reduce.cli._common import count
    >>> count(100)("30")
    30
    >>> count(100, minimum=0)("0")
    0
    >>> count(100)("1e8")
    Traceback (most recent call last):
    ...
    argparse.ArgumentTypeError: must be a whole number from 1 to 100, got 100000000
    """
    def parse(text):
        try:
            value = int(text)
        except ValueError:
            value = _float(text)
        if minimum == 0 and value == 0:
            return 0
        try:
            return check_count(value, "", maximum)
        except ResourceError:
            shown = int(value) if value == int(value) else value
            lo = 1 if minimum else 0
            raise argparse.ArgumentTypeError(
                f"must be a whole number from {lo} to {maximum}, got {shown}") from None

    parse.__name__ = "count"  # argparse names the type in some messages
    return parse


def named_files(obj, base=None, _depth=0):
    """Existing files named by strings anywhere in a config (dicts, lists, strings).

    Parameters
    ----------
    obj : object
        A parsed configuration, e.g. a pipeline's steps and parameters.
    base : str or path-like, optional
        A directory relative paths may also be relative to (e.g. that of the
        config file).

    Returns
    -------
    list of str
        Each string of ``obj`` that names an existing file (relative to the
        current directory or ``base``), e.g. a ``subtract_dark`` step's dark.

    Examples
    --------
    >>> import tempfile, pathlib
    >>> from spherex_reduce.cli._common import named_files
    >>> f = pathlib.Path(tempfile.mkdtemp()) / "dark.fits"
    >>> _ = f.write_bytes(b"")
    >>> named_files({"steps": [{"subtract_dark": {"dark": str(f)}}], "x": "no such"}) == [str(f)]
    True
    """
    if _depth > 50:  # configs are shallow; a deeper one names nothing we would miss
        return []
    if isinstance(obj, (str, os.PathLike)):
        text = os.fspath(obj)
        found = []
        if isinstance(text, str) and 0 < len(text) < 4096 and "\0" not in text:
            for path in (text, None if base is None else os.path.join(base, text)):
                with contextlib.suppress(OSError, ValueError, TypeError):
                    if path is not None and os.path.isfile(path):
                        found.append(path)
        return found
    if isinstance(obj, dict):
        obj = list(obj.values())
    if isinstance(obj, (list, tuple)):
        return [f for item in obj for f in named_files(item, base, _depth + 1)]
    return []


def add_config_option(parser):
    """``-c PIPELINE.yaml`` of a command that reads FITS files without reducing them.

    See `input_config`.
    """
    parser.add_argument(
        "-c", "--config", metavar="PIPELINE.yaml",
        help="pipeline YAML file or shipped config name (see show-config --list) whose "
        "input:, geometry: and readout: sections say how to read the input files (unit, "
        "gain, keywords they lack), as for reduce -c (its steps are validated, not run)")


def input_config(config):
    """The `~spherex_reduce.Pipeline` of a ``-c`` option and the files it reads.

    Parameters
    ----------
    config : str or None
        A pipeline YAML file or a shipped config name, as ``reduce -c`` takes.

    Returns
    -------
    pipeline : `~spherex_reduce.Pipeline` or None
        Its `Pipeline.read <spherex_reduce.Pipeline.read>` reads a FITS file
        with the config's ``geometry:``/``readout:`` for missing keywords.
    files : list of str
        The config file and every existing file it names (e.g. a dark), the
        inputs `check_paths` must protect; empty without ``config``.

    Raises
    ------
    FileNotFoundError
        No such file and no shipped config of that name.
    ConfigError
        The config is not valid YAML, not a mapping, or not a valid pipeline.

    Examples
    --------
    >>> from spherex_reduce.cli._common import input_config
    >>> pipeline, files = input_config("unchop")
    >>> pipeline.steps, files
    ([('unchop', {})], ['unchop'])
    >>> input_config(None)
    (None, [])
    """
    from ..reduce.pipeline import Pipeline

    if config is None:
        return None, []
    pipeline = Pipeline.from_yaml(config)
    return pipeline, [config, *named_files(pipeline.steps, Path(config).parent)]


def _same(a, b):
    try:
        return os.path.samefile(a, b)
    except (OSError, ValueError):
        return os.path.abspath(a) == os.path.abspath(b)


def check_paths(inputs, outputs):
    """Refuse, before any work, an output that is an input or another output.

    Paths are compared as files (`os.path.samefile`: symbolic links, ``./x``
    and hard links are the same file) and, for files that do not exist yet, as
    absolute paths.

    Parameters
    ----------
    inputs : iterable of str or None
        Every file the command reads (None entries are ignored).
    outputs : iterable of str or None
        Every file it writes.

    Raises
    ------
    SpherexReduceError
        Naming both paths.

    Examples
    --------
    >>> import tempfile, pathlib
    >>> from spherex_reduce.cli._common import check_paths
    >>> d = pathlib.Path(tempfile.mkdtemp())
    >>> _ = (d / "raw.fits").write_bytes(b"")
    >>> check_paths([d / "raw.fits"], [d / "red.fits"])
    >>> check_paths([d / "raw.fits"], [d / "." / "raw.fits"])
    Traceback (most recent call last):
    ...
    spherex_reduce.core.errors.SpherexReduceError: output .../raw.fits is the input ...
    """
    inputs = [os.fspath(p) for p in inputs if p is not None]
    outputs = [os.fspath(p) for p in outputs if p is not None]
    for i, out in enumerate(outputs):
        for src in inputs:
            if _same(out, src):
                raise SpherexReduceError(
                    f"output {out} is the input {src}; writing it would destroy the input: "
                    "choose another output")
        for other in outputs[:i]:
            if _same(out, other):
                raise SpherexReduceError(
                    f"outputs {other} and {out} are the same file; give each its own name")


@contextlib.contextmanager
def all_or_nothing(paths, overwrite):
    """Temporary paths for several outputs, all renamed into place only if all were written.

    Parameters
    ----------
    paths : sequence of str or None
        The outputs (None: not written; its temporary path is None too).
    overwrite : bool
        Replace existing outputs.

    Yields
    ------
    list of `pathlib.Path` or None
        Where to write each output.  If the block raises, every temporary file
        is removed and no output is touched.

    Examples
    --------
    >>> import tempfile, pathlib
    >>> from spherex_reduce.cli._common import all_or_nothing
    >>> d = pathlib.Path(tempfile.mkdtemp())
    >>> try:
    ...     with all_or_nothing([d / "a.txt", d / "b.txt"], False) as (a, b):
    ...         _ = a.write_text("a")
    ...         raise OSError(28, "No space left on device")
    ... except OSError:
    ...     pass
    >>> sorted(p.name for p in d.iterdir())
    []
    """
    with contextlib.ExitStack() as stack:
        yield [None if p is None else stack.enter_context(atomic_output(p, overwrite))
               for p in paths]


def add_dask_options(parser):
    """``--scheduler`` and ``--workers`` of a command that runs tasks on dask."""
    from ..core.limits import MAX_WORKERS

    parser.add_argument("--scheduler", metavar="ADDRESS",
                        help="dask scheduler address (tcp://host:8786); 'serial' runs "
                        "in-process")
    parser.add_argument("--workers", type=count(MAX_WORKERS), default=2,
                        help="worker processes of the embedded LocalCluster (default 2)")


def plot_path(args):
    """The ``--plot`` of a command whose ``--plot`` may be given alone: its value, or the
    output's path with ``.png`` (None without ``--plot``)."""
    return str(Path(args.output).with_suffix(".png")) if args.plot is True else args.plot


def dask_run_inputs(args, what):
    """Checks shared by the commands that run a YAML file of tasks on dask (``sweep``,
    ``compare-strategies``), before any work: dask's INFO lines silenced unless ``-v``,
    the input file and the scene and pipeline files it names against the outputs, the
    scheduler reachable.  Returns the plot's path (``--plot`` alone: OUTPUT with .png)."""
    from ..io.config import load_yaml
    from ..reduce.scheduler import check_scheduler, quiet_dask_logs

    if not args.verbose:  # dask's INFO lines about workers and connections
        quiet_dask_logs()
    plot = plot_path(args)
    named = load_yaml(args.input, what)[0]
    check_paths([args.input, *named_files(named, Path(args.input).parent)],
                [args.output, plot])
    check_scheduler(args.scheduler, name="--scheduler")
    return plot
