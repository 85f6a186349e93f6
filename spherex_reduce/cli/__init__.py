"""The ``spherex-reduce`` command line.

Each subcommand lives in its own module exposing ``add_parser(subparsers)``;
:data:`COMMANDS` lists them in the order ``--help`` shows.  Exit codes: 0 ok,
2 usage or input error (one line on stderr, no traceback), 1 unexpected failure.
"""

import argparse
import importlib
import logging
import sys

from .._version import __version__
from ..errors import SpherexReduceError
from ..fits_format import checksum_policy

__all__ = ["COMMANDS", "main"]

COMMANDS = ["demo", "readout", "reduce", "show_config", "plugins", "simulate", "combine",
            "spectrum", "fit_noise", "sweep", "figures"]

#: Commands that read FITS files: they take ``--ignore-checksum``.
READS_FITS = ("reduce", "combine", "spectrum", "fit-noise")

#: Errors caused by the user's input: exit code 2, one line, no traceback.
INPUT_ERRORS = (SpherexReduceError, FileNotFoundError, FileExistsError, IsADirectoryError,
                NotADirectoryError, PermissionError, KeyError)


def build_parser():
    parser = argparse.ArgumentParser(
        prog="spherex-reduce",
        description="Simulate, reduce and measure the readout noise of H2RG detector arrays.",
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    parser.add_argument("-v", "--verbose", action="store_true", help="log every step")
    parser.add_argument("-q", "--quiet", action="store_true", help="no progress bars")
    parser.add_argument("--debug", action="store_true", help="show tracebacks of errors")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in COMMANDS:
        importlib.import_module(f".{name}", __name__).add_parser(sub)
    for name in READS_FITS:
        sub.choices[name].add_argument(
            "--ignore-checksum", action="store_true",
            help="read FITS files whose CHECKSUM/DATASUM do not match (damaged or edited): "
            "warn, and record it in the output (HISTORY, SXRCKBAD) instead of stopping")
    return parser


def main(argv=None):
    """Run the command line; returns the exit code."""
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.command is None:
        parser.print_help()
        return 2
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING,
                        format="%(levelname)s %(name)s: %(message)s")
    try:
        with checksum_policy(verify=not getattr(args, "ignore_checksum", False)):
            return args.func(args) or 0
    except INPUT_ERRORS as exc:
        if args.debug:
            raise
        msg = exc.args[0] if isinstance(exc, KeyError) and exc.args else exc
        print(f"spherex-reduce {args.command}: error: {msg}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("spherex-reduce: interrupted", file=sys.stderr)
        return 130
    except Exception as exc:
        if args.debug:
            raise
        print(f"spherex-reduce {args.command}: unexpected failure: {type(exc).__name__}: {exc} "
              "(run with --debug for the traceback)", file=sys.stderr)
        return 1


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
