"""The ``spherex-reduce`` command line.

Each subcommand lives in its own module exposing ``add_parser(subparsers)``;
:data:`COMMANDS` lists them in the order ``--help`` shows, with the line it shows
for each, so that ``--help``, ``--version`` and finding the chosen command import
no command's module: only the chosen command's module is imported, with what it
uses.  Exit codes: 0 ok, 2 usage, input or environment error (one line on stderr,
no traceback: bad input, a failing plugin, a full disk or read-only file system),
1 unexpected failure (a bug), 130 interrupted, 143 terminated (SIGTERM).
"""

import argparse
import contextlib
import errno
import importlib
import logging
import signal
import sys
import warnings

from .._version import __version__
from ..core.errors import SpherexReduceError

__all__ = ["COMMANDS", "main"]

#: The subcommands in the order ``--help`` lists them, each with its line there (the
#: ``help`` its module's ``add_parser`` gives).  The module of ``NAME`` is
#: ``spherex_reduce.cli.NAME`` with ``_`` for ``-``, or the one `PACKAGED` names.
COMMANDS = {
    "demo": "simulate, reduce and measure the paper's case on built-in defaults",
    "readout": "build a readout schedule; print, save or draw it",
    "reduce": "run a pipeline on raw FITS files",
    "show-config": "print a pipeline config with every default filled in",
    "plugins": "list steps, strategies and simulators and their plugins",
    "simulate": "simulate raw ramps or a slope image from a scene",
    "combine": "combine reduced exposures into a master dark",
    "spectrum": "azimuthally averaged power spectrum P(k) of an image",
    "forecast": "expected P(k) of a scene reduced by a pipeline, exact, no simulation",
    "fit-noise": "fit the noise model of paper eq. 1 to a raw file's reference and phantom "
                 "streams",
    "characterize": "fit a noise model (a scene) to raw darks: per channel and common, "
                    "ACN, what the phantom sees",
    "sweep": "simulate, reduce and measure a grid of readout parameters on dask",
    "compare-strategies": "reduce the same simulated noise and injected sky with several "
                          "pipelines; residual noise, white floor, sky transfer",
    "design-readout": "search the readout (row order, c, r) of least forecast 5-20' noise "
                      "within a frame time",
    "figures": "reproduce the paper's simulated figures (PNG + Markdown report)",
}

#: Commands whose module is in a subpackage (the others: ``spherex_reduce.cli.NAME``).
PACKAGED = {"fit-noise": "darks.fit_noise", "characterize": "darks.characterize"}

#: Commands that read FITS files: they take ``--ignore-checksum`` and ``--dq-bits``.
READS_FITS = ("reduce", "combine", "spectrum", "fit-noise", "characterize")

#: Errors caused by the user's input: exit code 2, one line, no traceback.
INPUT_ERRORS = (SpherexReduceError, FileNotFoundError, FileExistsError, IsADirectoryError,
                NotADirectoryError, PermissionError)

#: Errors of the machine, not of the package (a full disk, a read-only file
#: system): exit code 2, one line naming the path and the reason.
ENVIRONMENT_ERRNOS = frozenset(getattr(errno, name) for name in (
    "EROFS", "ENOSPC", "EDQUOT", "EACCES", "EPERM", "EFBIG", "EIO", "EMFILE", "ENFILE",
    "ENAMETOOLONG", "ELOOP", "EXDEV", "ETXTBSY", "ENODEV", "ENXIO") if hasattr(errno, name))


class Terminated(BaseException):
    """SIGTERM, raised in the main thread so that temporary files are removed."""


def _terminate(signum, frame):
    raise Terminated()


def _message(exc):
    """One line for an input or environment error."""
    if isinstance(exc, OSError) and exc.strerror and exc.filename is not None:
        return f"{exc.filename}: {exc.strerror}"
    return " ".join(str(exc).split()) or type(exc).__name__


@contextlib.contextmanager
def _one_line_warnings(command):
    """Show each distinct warning once, as one line ``spherex-reduce CMD: warning: ...``.

    Replaces the default display (file, line and source of the warning) and
    astropy's, which is also logged, so each warning would appear twice.
    """
    # astropy's own logger, which has a handler of its own: not the root's too.  Imported,
    # not looked up: logging.getLogger("astropy") before astropy is imported (a command
    # imports it when it runs) would make a plain logger that astropy's import then fails on.
    from astropy import log as astropy_log

    seen = set()
    propagate, astropy_log.propagate = astropy_log.propagate, False

    def show(message, category, filename, lineno, file=None, line=None):
        text = " ".join(str(message).split())
        if (category, text) in seen:
            return
        seen.add((category, text))
        print(f"spherex-reduce {command}: warning: {text}", file=file or sys.stderr)

    try:
        with warnings.catch_warnings():
            warnings.showwarning = show
            yield
    finally:
        astropy_log.propagate = propagate


@contextlib.contextmanager
def _sigterm_raises():
    """Turn SIGTERM into `Terminated` while a command runs (main thread only)."""
    try:
        old = signal.signal(signal.SIGTERM, _terminate)
    except ValueError:  # not the main thread: leave signals alone
        yield
        return
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, old)


class _LogFormat(logging.Formatter):
    """Logged warnings and errors as ``spherex-reduce CMD: warning: ...``, like the others."""

    command = None

    def format(self, record):
        if record.levelno >= logging.WARNING and self.command:
            text = " ".join(record.getMessage().split())
            return f"spherex-reduce {self.command}: {record.levelname.lower()}: {text}"
        return super().format(record)


class _Parser(argparse.ArgumentParser):
    """Usage errors as one line naming the command and option (exit 2)."""

    def error(self, message):
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def build_parser(commands=None):
    """The parser of the command line.

    Parameters
    ----------
    commands : collection of str, optional
        The subcommands whose options are added, each by importing its module
        (default: all).  The others are listed by name and help only: enough for
        ``--help`` and ``--version`` and to find the chosen command.

    Returns
    -------
    argparse.ArgumentParser

    Examples
    --------
    >>> from spherex_reduce.cli import build_parser
    >>> build_parser(["readout"]).parse_args(["readout", "--skip", "8"]).skip
    8
    """
    parser = _Parser(
        prog="spherex-reduce",
        description="Simulate, reduce and measure the readout noise of H2RG detector arrays.",
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    parser.add_argument("-v", "--verbose", action="store_true", help="log every step")
    parser.add_argument("-q", "--quiet", action="store_true", help="no progress bars")
    parser.add_argument("--debug", action="store_true", help="show tracebacks of errors")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name, text in COMMANDS.items():
        if commands is not None and name not in commands:
            sub.add_parser(name, help=text, add_help=False)
            continue
        module = PACKAGED.get(name, name.replace("-", "_"))
        importlib.import_module(f".{module}", __name__).add_parser(sub)
        if name in READS_FITS:
            _add_fits_options(sub.choices[name])
    return parser


def _add_fits_options(parser):
    """``--ignore-checksum`` and ``--dq-bits`` of a command that reads FITS files."""
    from ..io.readers.flags import DEFAULT_DQ_BITS

    parser.add_argument(
        "--ignore-checksum", action="store_true",
        help="read FITS files whose CHECKSUM/DATASUM do not match (damaged or edited): "
        "warn, and record it in the output (HISTORY, SXRCKBAD) instead of stopping")
    parser.add_argument(
        "--dq-bits", type=_dq_bits, default=DEFAULT_DQ_BITS, metavar="N",
        help="bits of a DQ written by other software (a file without a READOUT table) "
        "that mask a pixel, as a sum of 2**bit, e.g. 0x5 for bits 0 and 2; 0: none "
        f"(default {DEFAULT_DQ_BITS:#x}: every bit; 1 for bit 0 alone, JWST's do-not-use); "
        "our own files keep all their flags")


@contextlib.contextmanager
def _fits_options(args):
    """While a command that reads FITS files runs: its ``--ignore-checksum`` and ``--dq-bits``."""
    if args.command not in READS_FITS:
        yield
        return
    from ..io import checksum_policy, foreign_dq_bits

    with checksum_policy(verify=not args.ignore_checksum), foreign_dq_bits(args.dq_bits):
        yield


def _dq_bits(text):
    """``--dq-bits``: an integer (decimal, 0x hex or 0b binary) that `check_dq_bits` accepts."""
    from ..io.readers.flags import check_dq_bits

    try:
        value = int(text, 0)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not an integer: {text!r}") from None
    try:
        return check_dq_bits(value, "")
    except SpherexReduceError as exc:
        raise argparse.ArgumentTypeError(str(exc).removeprefix(": ")) from None


def main(argv=None):
    """Run the command line; returns the exit code."""
    try:  # the chosen command first: only its module is imported
        chosen = build_parser(commands=()).parse_known_args(argv)[0].command
        parser = build_parser(commands=[chosen] if chosen else ())
        args = parser.parse_args(argv)
    except SystemExit as exc:  # --help and --version exit 0 as argparse does
        if exc.code == 2:
            return 2
        raise
    if args.command is None:
        parser.print_help()
        return 2
    _LogFormat.command = args.command
    handler = logging.StreamHandler()
    handler.setFormatter(_LogFormat("%(levelname)s %(name)s: %(message)s"))
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING,
                        handlers=[handler])
    try:
        with _sigterm_raises(), _one_line_warnings(args.command), _fits_options(args):
            return args.func(args) or 0
    except INPUT_ERRORS as exc:
        if args.debug:
            raise
        print(f"spherex-reduce {args.command}: error: {_message(exc)}", file=sys.stderr)
        return 2
    except OSError as exc:
        if args.debug:
            raise
        if exc.errno not in ENVIRONMENT_ERRNOS:
            return _unexpected(args, exc)
        print(f"spherex-reduce {args.command}: error: {_message(exc)}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        _remove_unfinished()
        print("spherex-reduce: interrupted", file=sys.stderr)
        return 130
    except Terminated:
        _remove_unfinished()
        print("spherex-reduce: terminated", file=sys.stderr)
        return 128 + signal.SIGTERM
    except Exception as exc:
        if args.debug:
            raise
        return _unexpected(args, exc)


def _remove_unfinished():
    """The temporary files of outputs an interrupt cut short (`atomic_output`'s own clean-up
    cannot run where the interrupt arrives as it is entered)."""
    from ..io.atomic import atomic_output

    atomic_output.remove_unfinished()


def _unexpected(args, exc):
    blame = _blame_plugin(exc)
    if blame is not None:  # a plugin's bug (e.g. in a simulator it registers): name it
        print(f"spherex-reduce {args.command}: error: {blame}", file=sys.stderr)
        return 2
    print(f"spherex-reduce {args.command}: unexpected failure: {type(exc).__name__}: {exc} "
          "(run with --debug for the traceback)", file=sys.stderr)
    return 1


def _blame_plugin(exc):
    """The `PluginError` for an installed plugin's code on the traceback of ``exc``, or None."""
    from ..reduce.plugins import Registry, blame_plugin

    try:
        return blame_plugin(exc, Registry())
    except Exception:  # the plugins cannot even be listed: the error stays unexpected
        return None


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
